"""Thread count of CasADi's bundled OpenBLAS, which MUMPS (IPOPT's linear solver) calls for its
dense frontal matrices.

OpenBLAS starts one thread per core.  MUMPS's fronts in the ramp MPC are small (a few hundred rows),
and a second thread does not shorten the factorization: on the beltway MPC (4, 8, 16 interchanges,
3 interleaved repetitions on a loaded 2-core machine) the solves took the same wall time with one
thread as with two, while two threads cost 1.0-1.8x the CPU time of one (the second thread spins
whenever the other core is free; benchmarks/mpc_solve.py prints both side by side).  In a batch,
where every worker process is already one run per core, more threads only oversubscribe the cores;
and a fixed count makes the floating-point sums inside the dense kernels the same on every machine.
The ramp MPC sets the count when it is built and before each solve (``MPCConfig.blas_threads``);
it holds for the rest of the process, for every CasADi solver in it.
"""

from __future__ import annotations

import ctypes
import glob
import os

import casadi as ca

_LIB_GLOB = "libcasadi-tp-openblas.so*"
_SONAME = "libcasadi-tp-openblas.so.0"
_LOADED: list[ctypes.CDLL | None] = []  # the library once looked up (a process loads it once anyway)


def _load(start_threads: int | None) -> ctypes.CDLL | None:
    """CasADi's OpenBLAS (``libcasadi-tp-openblas``), or None when this CasADi build has none.

    OpenBLAS creates its thread pool when it is loaded, from ``OPENBLAS_NUM_THREADS``; a pool thread
    created then kept spinning through later solves even after ``openblas_set_num_threads(1)``
    (CPU 1.7-2.0 x wall at 4 and 8 interchanges).  So when CasADi has not loaded it yet (its IPOPT
    plugin loads it at the first ``nlpsol``), it is loaded here with the variable set to
    ``start_threads`` for that moment only: the process's environment is left as it was.
    """
    # the file named like the SONAME that CasADi's plugins ask for first: dlopen by another path of
    # an identical copy (pip installs copies, not links) would map a second, unused library
    paths = sorted(glob.glob(os.path.join(os.path.dirname(ca.__file__), _LIB_GLOB)),
                   key=lambda p: (not p.endswith(_SONAME), p))
    before = os.environ.get("OPENBLAS_NUM_THREADS")
    if start_threads is not None:
        os.environ["OPENBLAS_NUM_THREADS"] = str(start_threads)
    try:
        for path in paths:
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            if hasattr(lib, "openblas_set_num_threads") and hasattr(lib, "openblas_get_num_threads"):
                return lib
        return None
    finally:
        if start_threads is not None:
            if before is None:
                os.environ.pop("OPENBLAS_NUM_THREADS", None)
            else:
                os.environ["OPENBLAS_NUM_THREADS"] = before


def _lib(start_threads: int | None = None) -> ctypes.CDLL | None:
    """The library, looked up once (with ``start_threads`` in its pool if this loads it)."""
    if not _LOADED:
        _LOADED.append(_load(start_threads))
    return _LOADED[0]


def blas_threads() -> int | None:
    """Threads CasADi's OpenBLAS uses now (None without it)."""
    lib = _lib()
    return None if lib is None else int(lib.openblas_get_num_threads())


def set_casadi_blas_threads(n: int | None) -> None:
    """Let CasADi's OpenBLAS use ``n`` threads from now on, process-wide (None: leave it as it is).

    Call it before the first ``nlpsol`` so the library starts with ``n`` threads (see ``_load``).
    Not restored after a solve on purpose: switching back to more threads between solves wakes the
    idle worker, which then spins through the next solve (measured at 16 interchanges: 0.146 s CPU
    per IPOPT iteration when switched per solve, 0.121 s when set once).
    """
    if n is None:
        return
    if n < 1:
        raise ValueError(f"BLAS threads must be >= 1, got {n}")
    lib = _lib(n)
    if lib is not None and int(lib.openblas_get_num_threads()) != n:
        lib.openblas_set_num_threads(int(n))
