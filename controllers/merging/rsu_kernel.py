"""The roadside unit's measurement of ``v2x_wave_damping`` in one compiled call: mean noisy speed per
cell of the highway line and the ramp vehicles' arrival times at the merge, with the bits of the numpy
code it replaces (``WaveDamping._measure_numpy``): ``np.maximum``'s choice (the first operand when it
is not smaller, or NaN), ``np.floor`` then the cast to an integer, ``np.bincount``'s sums in index
order from 0.0, an empty cell NaN.  ``tests/controllers/test_ctrl_wave_floats.py`` checks it against
the numpy code on random inputs."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_SIG = "void(f8[:], f8[:], b1[:], f8, f8, f8, f8, f8, f8[:], f8[:])"


@njit(_SIG, cache=True)
def road_ahead(front: np.ndarray, v: np.ndarray, on_ramp: np.ndarray, base_m: float, cell_m: float,
               merge_x: float, cos_ramp: float, t: float, cell_speed: np.ndarray, eta: np.ndarray) -> None:
    """``cell_speed`` (n_cells,): the mean of ``v`` [m/s] over the highway vehicles (not ``on_ramp``)
    whose ``front`` [m] lies in each cell of ``cell_m`` from ``base_m`` (NaN: none); ``eta`` (one per
    ramp vehicle, in order): ``t`` + the distance to ``merge_x`` along the ramp / max(v, 1) [s]."""
    n_cells = cell_speed.shape[0]
    total = np.zeros(n_cells)
    count = np.zeros(n_cells, dtype=np.int64)
    r = 0
    for i in range(front.shape[0]):
        if on_ramp[i]:
            dist = (merge_x - front[i]) / cos_ramp
            d = dist if (dist >= 0.0 or math.isnan(dist)) else 0.0
            vi = v[i]
            w = vi if (vi >= 1.0 or math.isnan(vi)) else 1.0
            eta[r] = t + d / w
            r += 1
        else:
            k = np.int64(math.floor((front[i] - base_m) / cell_m))
            if k >= 0 and k < n_cells:
                total[k] += v[i]
                count[k] += 1
    for c in range(n_cells):
        cell_speed[c] = total[c] / count[c] if count[c] > 0 else np.nan


_COPIES_SIG = "void(f8[:, :], i8[:], f8[:], f8, f8[:], f8, f8, f8, f8, b1[:], f8[:], i8[:])"


@njit(_COPIES_SIG, cache=True)
def broadcast_copies(pos: np.ndarray, perm: np.ndarray, src: np.ndarray, r2: float, u: np.ndarray, p_loss: float,
                     t_lat: float, jitter: float, t_late: float, keep: np.ndarray, t_recv: np.ndarray,
                     counts: np.ndarray) -> None:
    """The copies of one broadcast (``RsuBroadcast.send``'s numpy code, bit for bit): receiver ``i`` at
    ``pos[perm[i]]`` [m]; in range when the squared distance to ``src`` (x, y, z summed in that order)
    is not above ``r2`` or NaN; lost when in range and ``u[i] < p_loss``; delivered at ``t_lat`` +
    ``jitter`` * ``u[n + i]`` [s], dropped when later than ``t_late``.  Writes ``keep``, ``t_recv`` and
    ``counts`` = (in range, lost, late, kept)."""
    n = perm.shape[0]
    n_near = n_lost = n_late = n_keep = 0
    for i in range(n):
        j = perm[i]
        dx, dy, dz = pos[j, 0] - src[0], pos[j, 1] - src[1], pos[j, 2] - src[2]
        d2 = dx * dx + dy * dy + dz * dz
        near = not d2 > r2
        tr = t_lat + jitter * u[n + i]
        t_recv[i] = tr
        k = False
        if near:
            n_near += 1
            if u[i] < p_loss:
                n_lost += 1
            elif tr > t_late:
                n_late += 1
            else:
                k = True
                n_keep += 1
        keep[i] = k
    counts[0], counts[1], counts[2], counts[3] = n_near, n_lost, n_late, n_keep
