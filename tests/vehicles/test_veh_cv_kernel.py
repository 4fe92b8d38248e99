"""The compiled 1-D constant-velocity fuse (``cv_kernel``) against numpy's stacked products: the
same bits, on covariances that pivot the inverse and on stacks with and without a prediction step."""

from __future__ import annotations

import numpy as np

from corridor.vehicles.tracks.stack import cv_fuse, cv_fuse_stacked

Q = 1.0
R = np.diag([0.5**2, 0.3**2])


def _case(rng: np.random.Generator, k: int, general: bool) -> tuple[np.ndarray, ...]:
    x = np.column_stack([rng.normal(0.0, 300.0, k), rng.normal(15.0, 10.0, k)])
    a = rng.normal(size=(k, 2, 2)) * np.exp(rng.normal(0.0, 2.0, (k, 1, 1)))
    # a covariance, or any matrix (its inverse pivots when |p10| > |p00 + r00|)
    p = a if general else a @ a.transpose(0, 2, 1)
    dt = np.where(rng.random(k) < 0.2, 0.0, rng.choice([0.1, 0.2, 0.5, 0.3 + 1e-10], k) * rng.integers(1, 4, k))
    z = x + rng.normal(0.0, 2.0, (k, 2))
    return x, p, dt, z


def test_compiled_fuse_is_numpys_stacked_fuse_bit_for_bit() -> None:
    rng = np.random.default_rng(11)
    pivots = 0
    for trial in range(400):
        x, p, dt, z = _case(rng, int(rng.integers(1, 60)), general=trial % 2 == 1)
        pivots += int(np.sum(np.abs(p[:, 1, 0] + R[1, 0]) > np.abs(p[:, 0, 0] + R[0, 0])))
        xc, pc = cv_fuse(x.copy(), p.copy(), dt, z, R, 1, Q)
        xn, pn = cv_fuse_stacked(x.copy(), p.copy(), dt, z, R, 1, Q)
        assert np.array_equal(xc, xn) and np.array_equal(pc, pn)
    assert pivots > 100  # both branches of the inverse were exercised


def test_compiled_fuse_without_fused_multiply_adds_would_differ() -> None:
    """The check above can fail: numpy's products are not the naive a*b + c*d (fused multiply-adds)."""
    rng = np.random.default_rng(3)
    x, p, dt, z = _case(rng, 2000, general=False)
    _, pn = cv_fuse_stacked(x.copy(), p.copy(), dt, z, R, 1, Q)
    naive = np.einsum("kij,kjl->kil", p, np.linalg.inv(p + R))  # numpy's einsum: plain sums of products
    blas = p @ np.linalg.inv(p + R)
    assert not np.array_equal(naive, blas)
    assert np.isfinite(pn).all()
