"""The 1-D constant-velocity Kalman fuse of :func:`~corridor.vehicles.tracks.stack.cv_fuse` compiled
(numba): every message of a tick in one call, with the same floating-point operations as numpy's
stacked ``matmul`` / ``linalg.inv`` on 2 x 2 matrices, so the states are the same bits.

What numpy computes, measured against it (``tests/vehicles/test_veh_cv_kernel.py`` checks it on
random stacks; the track-pool test checks the whole filter against filterpy bit for bit):

- a matrix product (BLAS ``dgemm``) ``c_ij = fma(a_i1, b_1j, a_i0 * b_0j)``;
- a matrix-vector product (BLAS ``dgemv``) ``y_i = fma(a_i0, x_0, a_i1 * x_1)``;
- the inverse (LAPACK ``dgesv`` against the identity: LU with partial pivoting, the reciprocal of
  each pivot multiplied in, the back substitution fused) as in :func:`_inv2`.

These are the kernels of the OpenBLAS that numpy ships (DYNAMIC_ARCH, picked by the CPU); on a CPU
where OpenBLAS picks kernels that round differently, numpy's results would differ from these (and
from numpy's on this machine) in the last bits. The compiled filter is the same on every CPU.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic


@intrinsic
def _fma(typingctx, a, b, c):  # type: ignore[no-untyped-def]  # numba's intrinsic signature
    """a * b + c with one rounding (LLVM's ``llvm.fma.f64``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.fma(*args)

    return sig, codegen


@njit(cache=True, inline="always")
def _mm(a00: float, a01: float, a10: float, a11: float, b00: float, b01: float, b10: float, b11: float
        ) -> tuple[float, float, float, float]:
    """A @ B of 2 x 2 matrices as BLAS dgemm rounds it."""
    return (_fma(a01, b10, a00 * b00), _fma(a01, b11, a00 * b01),
            _fma(a11, b10, a10 * b00), _fma(a11, b11, a10 * b01))


@njit(cache=True, inline="always")
def _mv(a00: float, a01: float, a10: float, a11: float, x0: float, x1: float) -> tuple[float, float]:
    """A @ x of a 2 x 2 matrix and a 2-vector as BLAS dgemv rounds it."""
    return _fma(a00, x0, a01 * x1), _fma(a10, x0, a11 * x1)


@njit(cache=True, inline="always")
def _inv2(a00: float, a01: float, a10: float, a11: float) -> tuple[float, float, float, float]:
    """S^-1 as LAPACK dgesv(S, I) computes it (OpenBLAS: getf2 then trsm)."""
    swap = abs(a10) > abs(a00)
    if swap:
        a00, a01, a10, a11 = a10, a11, a00, a01
    r0 = 1.0 / a00
    lo = a10 * r0
    ru = 1.0 / (a11 - lo * a01)
    # the columns of P I: (1, 0) and (0, 1), swapped with the rows
    x1a = (0.0 - lo * 1.0) * ru  # y = (1, -l)
    x0a = _fma(-a01, x1a, 1.0) * r0
    x1b = (1.0 - lo * 0.0) * ru  # y = (0, 1)
    x0b = _fma(-a01, x1b, 0.0) * r0
    if swap:
        return x0b, x0a, x1b, x1a
    return x0a, x0b, x1a, x1b


@njit(cache=True, inline="always")
def fuse_one(x: np.ndarray, p: np.ndarray, i: int, predict: bool, d: float, q11: float, q12: float, q22: float,
             z0: float, z1: float, r00: float, r01: float, r10: float, r11: float) -> None:
    """One message on row ``i`` of ``x`` (k, 2), ``p`` (k, 2, 2), in place: if ``predict``, predict over
    ``d`` with Q = [[q11, q12], [q12, q22]]; then update with z = (z0, z1) and R (Joseph form)."""
    x0, x1 = x[i, 0], x[i, 1]
    p00, p01, p10, p11 = p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1]
    if predict:
        x0, x1 = _mv(1.0, d, 0.0, 1.0, x0, x1)
        a00, a01, a10, a11 = _mm(1.0, d, 0.0, 1.0, p00, p01, p10, p11)
        b00, b01, b10, b11 = _mm(a00, a01, a10, a11, 1.0, 0.0, d, 1.0)
        p00, p01, p10, p11 = b00 + q11, b01 + q12, b10 + q12, b11 + q22
    s00, s01, s10, s11 = _inv2(p00 + r00, p01 + r01, p10 + r10, p11 + r11)
    k00, k01, k10, k11 = _mm(p00, p01, p10, p11, s00, s01, s10, s11)
    y0, y1 = _mv(k00, k01, k10, k11, z0 - x0, z1 - x1)
    x[i, 0], x[i, 1] = x0 + y0, x1 + y1
    i00, i01, i10, i11 = 1.0 - k00, 0.0 - k01, 0.0 - k10, 1.0 - k11
    a00, a01, a10, a11 = _mm(i00, i01, i10, i11, p00, p01, p10, p11)
    a00, a01, a10, a11 = _mm(a00, a01, a10, a11, i00, i10, i01, i11)
    b00, b01, b10, b11 = _mm(k00, k01, k10, k11, r00, r01, r10, r11)
    b00, b01, b10, b11 = _mm(b00, b01, b10, b11, k00, k10, k01, k11)
    p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1] = a00 + b00, a01 + b01, a10 + b10, a11 + b11


_SIG = "void(f8[:, :], f8[:, :, :], b1[:], f8[:], f8[:], f8[:], f8[:], f8[:, :], f8[:, :])"


@njit(_SIG, cache=True)  # compiled at import (or loaded from numba's cache), not inside a run's ticks
def cv_fuse_1d(x: np.ndarray, p: np.ndarray, ahead: np.ndarray, dt: np.ndarray, q11: np.ndarray,
               q12: np.ndarray, q22: np.ndarray, z: np.ndarray, r: np.ndarray) -> None:
    """In place, message by message: predict ``x`` (k, 2), ``p`` (k, 2, 2) where ``ahead`` (k,) with
    the next F = [[1, dt], [0, 1]] and Q = [[q11, q12], [q12, q22]] (m,) (m: the count of ``ahead``;
    ``stack.cv_terms``), then update with ``z`` (k, 2) and covariance ``r`` (2, 2) (Joseph form):
    :func:`~corridor.vehicles.tracks.stack.cv_fuse` for ``dim=1``."""
    r00, r01, r10, r11 = r[0, 0], r[0, 1], r[1, 0], r[1, 1]
    j = 0
    for i in range(x.shape[0]):
        if ahead[i]:
            fuse_one(x, p, i, True, dt[j], q11[j], q12[j], q22[j], z[i, 0], z[i, 1], r00, r01, r10, r11)
            j += 1
        else:
            fuse_one(x, p, i, False, 0.0, 0.0, 0.0, 0.0, z[i, 0], z[i, 1], r00, r01, r10, r11)
