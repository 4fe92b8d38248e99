"""Thread count of CasADi's bundled OpenBLAS, which MUMPS (IPOPT's linear solver) calls for its
dense frontal matrices.

OpenBLAS starts one thread per core.  MUMPS's fronts in the ramp MPC are small (a few hundred rows),
and a second thread does not shorten the factorization: on the beltway MPC (4, 8, 16 interchanges,
3 interleaved repetitions on a loaded 2-core machine) the solves took the same wall time with one
thread as with two, while two threads cost 1.0-1.8x the CPU time of one (the second thread spins
whenever the other core is free; benchmarks/mpc_solve.py prints both side by side).  In a batch,
where every worker process is already one run per core, more threads only oversubscribe the cores;
and a fixed count makes the floating-point sums inside the dense kernels the same on every machine.
The ramp MPC sets the count before each solve (``MPCConfig.blas_threads``); it holds for the rest
of the process, for every CasADi solver in it.
"""

from __future__ import annotations

import ctypes
import glob
import os
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


def set_casadi_blas_threads(n: int | None) -> None:
    """Let CasADi's OpenBLAS use ``n`` threads from now on, process-wide (None: leave it as it is).

    Not restored after a solve on purpose: switching back to more threads between solves wakes the
    idle worker, which then spins through the next solve (measured at 16 interchanges: 0.146 s CPU
    per IPOPT iteration when switched per solve, 0.121 s when set once).
    """
    lib = _openblas()
    if n is None or lib is None:
        return
    if n < 1:
        raise ValueError(f"BLAS threads must be >= 1, got {n}")
    if int(lib.openblas_get_num_threads()) != n:
        lib.openblas_set_num_threads(int(n))
