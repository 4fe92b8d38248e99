"""Thread count of CasADi's bundled OpenBLAS, which MUMPS (IPOPT's linear solver) calls for its
dense frontal matrices.

OpenBLAS starts one thread per core.  MUMPS's fronts in the ramp MPC are small (a few hundred rows),
and a second thread does not shorten the factorization: on the beltway MPC (4, 8, 16 interchanges,
3 interleaved repetitions on a loaded 2-core machine) the solves took the same wall time with one
thread as with two, while two threads cost 1.0-1.8x the CPU time of one (the second thread spins
whenever the other core is free), and with one thread CPU time equals wall time and repeats within
2 % (benchmarks/mpc_solve.py prints both side by side).  In a batch, where every worker process is
already one run per core, more threads only oversubscribe the cores; and a fixed count makes the
floating-point sums inside the dense kernels the same on every machine.
"""

from __future__ import annotations

import ctypes
import glob
import os
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache

import casadi as ca


@cache
def _openblas() -> ctypes.CDLL | None:
    """CasADi's OpenBLAS (``libcasadi-tp-openblas``), or None when this CasADi build has none."""
    for path in sorted(glob.glob(os.path.join(os.path.dirname(ca.__file__), "libcasadi-tp-openblas.so*"))):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        if hasattr(lib, "openblas_set_num_threads") and hasattr(lib, "openblas_get_num_threads"):
            return lib
    return None


def blas_threads() -> int | None:
    """Threads CasADi's OpenBLAS uses now (None without it)."""
    lib = _openblas()
    return None if lib is None else int(lib.openblas_get_num_threads())


@contextmanager
def casadi_blas_threads(n: int | None) -> Iterator[None]:
    """Run the block with CasADi's OpenBLAS on ``n`` threads (None: leave it), then restore."""
    lib = _openblas()
    if n is None or lib is None:
        yield
        return
    if n < 1:
        raise ValueError(f"BLAS threads must be >= 1, got {n}")
    before = int(lib.openblas_get_num_threads())
    lib.openblas_set_num_threads(int(n))
    try:
        yield
    finally:
        lib.openblas_set_num_threads(before)
