"""The roadside unit's coordination of a tick in one compiled call (issue 27, the eighth CPU pass).

``V2XMerging._coordinate`` did it in Python on vehicle names: per vehicle of the control zone the RSU's
track predicted to now (``NodeTrackPool.predict_one``) or its noisy sensor reading, the requested arrival
(``trajectory.time_to_go``), the FCFS key (the arrival expected when it entered the zone), a
``ZoneVehicle``, the crossings since the last tick, then ``Coordinator.assign`` (``fifo`` or ``cps``: the
departed, the new vehicles' ranks, fifo's insertion or cps's branch and bound, the re-timing). Here the
same over integer vehicle keys and arrays, with the same values in the same order:

- :func:`assign_core` is ``Coordinator.assign`` (without a ``SlotCheck``) on the coordinator's state as
  arrays (:class:`ArrayCoordinator`), :func:`_cps_order` its ``_CpsSearch`` as an explicit-stack
  depth-first search (the same candidates, the same bound, the same pruning order and ties);
- :func:`coordinate_into` builds the zone (predictions, sensor readings from pre-drawn standard normals:
  ``Generator.normal(0, s)`` is ``0.0 + s * standard_normal()``, the same stream), the crossings and the
  age-of-information sums, then calls :func:`assign_core`.

Python's ``x ** 2`` on a float is the C library's ``pow`` (which is not ``x * x``'s bits for about one
value in a thousand), and LLVM turns a ``pow(x, 2.0)`` it recognises into ``x * x``: ``time_to_go``'s squares
call the C library's ``pow`` under its other name (glibc's ``powf64``) here. The FCFS key's ties are broken by the
vehicle's id (a string): when two keys would be compared equal the kernel changes nothing about the
coordinator and returns ``STATUS_TIE``; the caller then runs the Python ``Coordinator`` on the same state.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np
from numba import njit, types

from corridor.controllers.merging.coordinator import (
    Coordinator,
    CoordinatorConfig,
    ZoneVehicle,
    _Slot,
    _State,
)

STATUS_OK, STATUS_TIE, STATUS_DRAWS = 0, 1, 2
ROAD_MAIN, ROAD_RAMP = 0, 1
_ROADS = ("main", "ramp")
# int state: slots, departed, ranked, has a tail, the tail's road, max shift seen, AoI samples, and the
# controller's cursor into its pool of sensor draws (coordinate_into)
I_N, I_DONE, I_RANKED, I_HAS_TAIL, I_TAIL_ROAD, I_SHIFT, I_AOI_N, I_DRAW = range(8)
F_TAIL_T, F_AOI_SUM, F_AOI_MAX = range(3)  # float state: the tail's crossing time, AoI sum and max

# the C library's pow under its _Float64 name (glibc: the same function as ``pow``, which Python calls), so
# that LLVM does not recognise it and turn pow(x, 2.0) into x * x
_c_pow = types.ExternalFunction("powf64", types.float64(types.float64, types.float64))
# glibc has it; elsewhere (macOS, musl) the controller keeps the Python coordinator (``HAVE_C_POW`` False)
HAVE_C_POW = hasattr(ctypes.CDLL(None), "powf64")


@njit(cache=True)
def _pymax(a: float, b: float) -> float:
    """Python's ``max(a, b)`` on floats: ``b`` only when ``b > a`` (NaN: the first)."""
    return b if b > a else a


@njit(cache=True)
def time_to_go_c(dist_m: float, v0: float, v_max: float, a_max: float) -> float:
    """``trajectory.time_to_go``, the same bits (its squares by the C library's ``pow``, as Python's)."""
    if dist_m <= 0:
        return 0.0
    v0 = v_max if v_max < v0 else v0  # Python's min(v0, v_max)
    t_acc = (v_max - v0) / a_max
    d_acc = v0 * t_acc + 0.5 * a_max * _c_pow(t_acc, 2.0)
    if d_acc >= dist_m:
        return (-v0 + math.sqrt(_c_pow(v0, 2.0) + 2.0 * a_max * dist_m)) / a_max
    return t_acc + (dist_m - d_acc) / v_max


@njit(cache=True)
def _headway(ra: int, rb: int, h_same: float, h_cross: float) -> float:
    return h_same if ra == rb else h_cross


@njit(cache=True)
def _cost(w: float, d_raw: float, fair: float) -> float:
    d = d_raw if d_raw > 0.0 else 0.0  # Python's max(0.0, d_raw)
    return w * d * (1.0 + d / fair)


@njit(cache=True)
def _candidates(used: np.ndarray, rank: np.ndarray, road: np.ndarray, p: int, k: int, out: np.ndarray) -> int:
    """``_CpsSearch._candidates``: the window indices allowed at global position ``p`` into ``out``."""
    n = used.shape[0]
    heads = np.full(2, -1, dtype=np.int64)
    first_road = -1
    for i in range(n):  # the first free vehicle of each road (the window is in rank order)
        if used[i]:
            continue
        r = road[i]
        if heads[r] < 0 or rank[i] < rank[heads[r]]:
            heads[r] = i
            if first_road < 0:
                first_road = r
    nf = 0
    free = np.empty(2, dtype=np.int64)
    for r in (first_road, 1 - first_road):
        if r >= 0 and heads[r] >= 0:
            free[nf] = heads[r]
            nf += 1
    if nf == 2 and rank[free[1]] < rank[free[0]]:  # sorted by rank
        free[0], free[1] = free[1], free[0]
    for j in range(nf):  # overdue: must go now
        if rank[free[j]] + k <= p:
            out[0] = free[j]
            return 1
    m = 0
    for j in range(nf):
        if abs(p - rank[free[j]]) <= k:
            out[m] = free[j]
            m += 1
    if m == 0:
        out[0] = free[0]
        m = 1
    return m


@njit(cache=True)
def _cps_order(earliest: np.ndarray, rank: np.ndarray, road: np.ndarray, w: np.ndarray, has_prev: bool,
               prev_t: float, prev_road: int, pos0: int, k: int, h_same: float, h_cross: float, fair: float,
               best: np.ndarray) -> None:
    """``_CpsSearch.best_order`` (no ``SlotCheck``) into ``best``: branch and bound, depth first, the
    recursion as an explicit stack (the same candidates in the same order, the same bound and pruning)."""
    n = earliest.shape[0]
    for i in range(n):
        best[i] = i
    if n == 0:
        return
    h_min = h_cross if h_cross < h_same else h_same  # Python's min(h_same, h_cross)
    best_cost = np.inf
    used = np.zeros(n, dtype=np.bool_)
    seq = np.empty(n, dtype=np.int64)
    cand = np.empty((n, 2), dtype=np.int64)
    n_cand = np.empty(n, dtype=np.int64)
    ci = np.zeros(n, dtype=np.int64)
    cost_d, pt_d = np.empty(n), np.empty(n)
    pr_d = np.empty(n, dtype=np.int64)
    ok_d = np.empty(n, dtype=np.bool_)
    depth = 0
    cost_d[0], pt_d[0], pr_d[0], ok_d[0] = 0.0, prev_t, prev_road, has_prev
    n_cand[0] = _candidates(used, rank, road, pos0, k, cand[0])
    while True:
        if ci[depth] >= n_cand[depth]:  # this level is done: back to the one above
            if depth == 0:
                break
            depth -= 1
            used[seq[depth]] = False
            continue
        i = cand[depth, ci[depth]]
        ci[depth] += 1
        if ok_d[depth]:
            t = _pymax(earliest[i], pt_d[depth] + _headway(pr_d[depth], road[i], h_same, h_cross))
        else:
            t = earliest[i]
        c = cost_d[depth] + _cost(w[i], t - earliest[i], fair)
        used[i] = True
        bound = 0.0  # Python's sum() over the unplaced vehicles, in index order
        t_b = t + h_min
        for j in range(n):
            if not used[j]:
                bound += _cost(w[j], t_b - earliest[j], fair)
        if c + bound < best_cost:
            seq[depth] = i
            if depth + 1 == n:
                if c < best_cost - 1e-12:
                    best_cost = c
                    for j in range(n):
                        best[j] = seq[j]
                used[i] = False
            else:
                depth += 1
                cost_d[depth], pt_d[depth], pr_d[depth], ok_d[depth] = c, t, road[i], True
                n_cand[depth] = _candidates(used, rank, road, pos0 + depth, k, cand[depth])
                ci[depth] = 0
        else:
            used[i] = False


@njit(cache=True)
def _n_frozen(st: np.ndarray, n: int, t: float, freeze: float) -> int:
    m = 0
    for j in range(n):
        if math.isnan(st[j]) or st[j] > t + freeze:
            break
        m += 1
    return m


@njit(cache=True)
def _ties(zen: np.ndarray, is_new: np.ndarray, sen: np.ndarray, keep: np.ndarray, n: int) -> bool:
    """Whether a new vehicle's FCFS key equals another new one's or a staying slot's (ids would decide)."""
    nz = zen.shape[0]
    for a in range(nz):
        if not is_new[a]:
            continue
        for b in range(nz):
            if b != a and is_new[b] and zen[b] == zen[a]:
                return True
        for j in range(n):
            if keep[j] and sen[j] == zen[a]:
                return True
    return False


@njit(cache=True)
def assign_core(t: float, zk: np.ndarray, zr: np.ndarray, zd: np.ndarray, zv: np.ndarray, ze: np.ndarray,
                zen: np.ndarray, cross_t: np.ndarray, sk: np.ndarray, sr: np.ndarray, srank: np.ndarray,
                se: np.ndarray, st: np.ndarray, sen: np.ndarray, sd: np.ndarray, sv: np.ndarray, si: np.ndarray,
                sf: np.ndarray, fifo: bool, h_same: float, h_cross: float, freeze: float, repair: float,
                repack: float, max_shift: int, horizon: int, fair: float, w_main: float, w_ramp: float) -> int:
    """``Coordinator.assign`` (no ``SlotCheck``) on the zone's vehicles (keys ``zk``, roads, distances,
    speeds, earliest arrivals, FCFS keys) and the state arrays (room for ``si[I_N] + len(zk)`` slots);
    ``cross_t``: per current slot its measured crossing time (NaN: left without crossing). Returns
    ``STATUS_TIE`` (nothing changed) when the ids would break a tie of the FCFS keys."""
    n, nz = si[I_N], zk.shape[0]
    keep = np.zeros(n, dtype=np.bool_)
    zslot = np.full(nz, -1, dtype=np.int64)  # zone vehicle -> its current slot
    for j in range(n):
        for a in range(nz):
            if zk[a] == sk[j]:
                keep[j] = True
                zslot[a] = j
                break
    is_new = zslot < 0
    if _ties(zen, is_new, sen, keep, n):
        return STATUS_TIE
    # the departed (_drop_departed), and the others' newest picture (_update_earliest)
    m = 0
    for j in range(n):
        if not keep[j]:
            si[I_DONE] += 1
            tc = cross_t[j]
            if not math.isnan(tc) and (si[I_HAS_TAIL] == 0 or tc >= sf[F_TAIL_T]):
                si[I_HAS_TAIL], sf[F_TAIL_T], si[I_TAIL_ROAD] = 1, tc, sr[j]
            continue
        sk[m], sr[m], srank[m], se[m], st[m], sen[m], sd[m], sv[m] = (sk[j], sr[j], srank[j], se[j], st[j], sen[j],
                                                                      sd[j], sv[j])
        m += 1
    n = m
    for j in range(n):
        for a in range(nz):
            if zk[a] == sk[j]:
                se[j], sd[j], sv[j] = ze[a], zd[a], zv[a]
                break
    # the new vehicles by FCFS key (no ties: checked above)
    new = np.flatnonzero(is_new)
    n_new = new.shape[0]
    for x in range(1, n_new):  # insertion sort (a few)
        y = x
        while y > 0 and zen[new[y - 1]] > zen[new[y]]:
            new[y - 1], new[y] = new[y], new[y - 1]
            y -= 1
    for x in range(n_new):
        a = new[x]
        if fifo:  # behind every vehicle expected no later and behind the frozen prefix (_insert_fcfs)
            n_fix = _n_frozen(st, n, t, freeze)
            pos = n
            while pos > n_fix and sen[pos - 1] > zen[a]:
                pos -= 1
            for j in range(n, pos, -1):
                sk[j], sr[j], srank[j], se[j], st[j], sen[j], sd[j], sv[j] = (sk[j - 1], sr[j - 1], srank[j - 1],
                                                                              se[j - 1], st[j - 1], sen[j - 1],
                                                                              sd[j - 1], sv[j - 1])
        else:
            pos = n
        sk[pos], sr[pos], srank[pos], se[pos], st[pos], sen[pos], sd[pos], sv[pos] = (
            zk[a], zr[a], si[I_RANKED], ze[a], np.nan, zen[a], zd[a], zv[a])
        si[I_RANKED] += 1
        n += 1
    si[I_N] = n
    if not fifo:
        repair_needed = False
        for j in range(n):
            if not math.isnan(st[j]) and se[j] > st[j] + repair:
                repair_needed = True
                break
        if n_new > 0 or repair_needed:
            _resequence(t, sk, sr, srank, se, st, sen, sd, sv, si, sf, freeze, max_shift, horizon, h_same, h_cross,
                        fair, w_main, w_ramp)
    # _retime
    has_prev, prev_t, prev_r = si[I_HAS_TAIL] == 1, sf[F_TAIL_T], si[I_TAIL_ROAD]
    for j in range(n):
        t_head = prev_t + _headway(prev_r, sr[j], h_same, h_cross) if has_prev else -np.inf
        t_need = _pymax(se[j], t_head)
        too_close = st[j] < t_head - 1e-9
        missed = se[j] > st[j] + repair
        too_late = st[j] > t_need + repack
        if math.isnan(st[j]) or too_close or missed or too_late:
            st[j] = t_need
        has_prev, prev_t, prev_r = True, st[j], sr[j]
    for j in range(n):  # _track_shift
        s = abs(si[I_DONE] + j - srank[j])
        if s > si[I_SHIFT]:
            si[I_SHIFT] = s
    return STATUS_OK


@njit(cache=True)
def _resequence(t: float, sk: np.ndarray, sr: np.ndarray, srank: np.ndarray, se: np.ndarray, st: np.ndarray,
                sen: np.ndarray, sd: np.ndarray, sv: np.ndarray, si: np.ndarray, sf: np.ndarray, freeze: float,
                max_shift: int, horizon: int, h_same: float, h_cross: float, fair: float, w_main: float,
                w_ramp: float) -> None:
    """``Coordinator._resequence``: the exact CPS search over the next ``horizon`` unfrozen slots."""
    n = si[I_N]
    n_fix = _n_frozen(st, n, t, freeze)
    free = np.arange(n_fix, n)
    nf = free.shape[0]
    for x in range(1, nf):  # by FCFS rank (unique)
        y = x
        while y > 0 and srank[free[y - 1]] > srank[free[y]]:
            free[y - 1], free[y] = free[y], free[y - 1]
            y -= 1
    nw = min(horizon, nf)
    win = free[:nw]
    if n_fix > 0:
        has_prev, prev_t, prev_r = True, st[n_fix - 1], sr[n_fix - 1]
    else:
        has_prev, prev_t, prev_r = si[I_HAS_TAIL] == 1, sf[F_TAIL_T], si[I_TAIL_ROAD]
    w = np.empty(nw)
    for x in range(nw):
        w[x] = w_ramp if sr[win[x]] == ROAD_RAMP else w_main
    order = np.empty(nw, dtype=np.int64)
    _cps_order(se[win], srank[win], sr[win], w, has_prev, prev_t, prev_r, si[I_DONE] + n_fix, max_shift, h_same,
               h_cross, fair, order)
    perm = np.concatenate((win[order], free[nw:]))
    ck, cr, crank, ce = sk[perm], sr[perm], srank[perm], se[perm]
    cen, cd, cv = sen[perm], sd[perm], sv[perm]
    for x in range(nf):
        j = n_fix + x
        sk[j], sr[j], srank[j], se[j], st[j], sen[j], sd[j], sv[j] = ck[x], cr[x], crank[x], ce[x], np.nan, cen[x], cd[x], cv[x]


# compiled at import (or loaded from the cache), not in a run's first tick; without glibc's powf64 never
# compiled (nothing calls it then)
_COORD_SIG = ("UniTuple(i8, 3)(f8, i8[:], b1[:], f8[:], f8[:], b1[:], i8[:], i8[:], i8, i8[:, :], f8[:, :], f8[:], "
              "f8[:], f8, f8[:], i8[:, :], f8[:, :], i8[:], f8[:], f8[:], i8[:], i8[:, :], f8[:, :], i8[:, :])")


@(njit(_COORD_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def coordinate_into(t: float, cand: np.ndarray, connected: np.ndarray, dist: np.ndarray, speed: np.ndarray,
                    ramp: np.ndarray, row_key: np.ndarray, row_node: np.ndarray, rsu_slot: int, row_of: np.ndarray,
                    trk_x: np.ndarray, trk_t: np.ndarray, z_noise: np.ndarray, target: float, entered_of: np.ndarray,
                    s_int: np.ndarray, s_flt: np.ndarray, si: np.ndarray, sf: np.ndarray, cfg: np.ndarray,
                    cfg_int: np.ndarray, z_int: np.ndarray, z_flt: np.ndarray, slot_out: np.ndarray) -> tuple[int, int, int]:
    """``V2XMerging._coordinate``'s zone and ``Coordinator.assign`` in one call (see the module docstring).

    ``cand``: the rows the RSU coordinates (the CAM stage's), ``row_key``: each row's vehicle key,
    ``row_node``: its channel node (-1: none); the RSU's tracks (``NodeTrackPool``: its slot, ``row_of``,
    the states and their times); ``z_noise``: a pool of standard normals from the sensor generator, read
    from ``si[I_DRAW]`` on, two per unconnected candidate (distance, speed, in row order: the values one
    draw per reading gives, as the stream is the same whatever the batch); ``entered_of``: per key the FCFS
    key (NaN: not yet in the zone). Writes the zone (``zk`` ... ``zrow``) and, per slot after the
    assignment, its key, row, connected and on-the-ramp flags (``slot_out``, (slots, 4)). Returns (status,
    the zone's size, the slots); ``STATUS_DRAWS``: the pool is short, nothing done (refill and call again);
    ``STATUS_TIE``: the coordinator is unchanged (its zone, AoI sums and draws are taken).

    Packed (a dispatch costs ~0.1 us an argument): the slots ``s_int`` (key, road, rank) and ``s_flt``
    (earliest, time, FCFS key, distance, speed) as ``ArrayCoordinator`` keeps them; ``cfg`` the
    coordinator's ``params_f`` then the sensor noises [m, m/s] and the comfortable acceleration [m/s²];
    ``cfg_int`` (fifo, max_shift, horizon); the zone ``z_int`` (key, road, row), ``z_flt`` (distance,
    speed, earliest, FCFS key)."""
    sk, sr, srank = s_int[0], s_int[1], s_int[2]
    se, st, sen, sd, sv = s_flt[0], s_flt[1], s_flt[2], s_flt[3], s_flt[4]
    zk, zr, zrow = z_int[0], z_int[1], z_int[2]
    zd, zv, ze, zen = z_flt[0], z_flt[1], z_flt[2], z_flt[3]
    h_same, h_cross, freeze, repair, repack, fair, w_main, w_ramp = (cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5],
                                                                     cfg[6], cfg[7])
    sd_m, sd_mps, comfort = cfg[8], cfg[9], cfg[10]
    fifo, max_shift, horizon = cfg_int[0] != 0, cfg_int[1], cfg_int[2]
    n_unc = 0
    for c in range(cand.shape[0]):
        if not connected[cand[c]]:
            n_unc += 1
    if si[I_DRAW] + 2 * n_unc > z_noise.shape[0]:
        return STATUS_DRAWS, 0, si[I_N]  # the pool of draws is short: nothing done
    nz, j_noise = 0, si[I_DRAW]
    n_nodes = row_of.shape[1]
    for c in range(cand.shape[0]):
        k = cand[c]
        if connected[k]:
            node = row_node[k]
            row = row_of[rsu_slot, node] if 0 <= node < n_nodes else -1
            if row < 0:
                continue  # the RSU has not heard from it (yet): not coordinated
            age = t - trk_t[row]
            age = age if age > 0.0 else 0.0  # Python's max(0.0, age)
            dt = np.rint(age * 1e9) * 1e-9  # predict_one's round(age * 1e9) * 1e-9 (half to even)
            x0, x1 = trk_x[row, 0], trk_x[row, 1]
            d = -(x0 + dt * x1)
            v = _pymax(x1 + 0.0 * x0, 0.1)
            si[I_AOI_N] += 1
            sf[F_AOI_SUM] += age
            sf[F_AOI_MAX] = _pymax(sf[F_AOI_MAX], age)
        else:
            d = dist[k] + (0.0 + sd_m * z_noise[j_noise])  # Generator.normal(0, sd): 0.0 + sd * z
            v = _pymax(speed[k] + (0.0 + sd_mps * z_noise[j_noise + 1]), 0.1)
            j_noise += 2
        v_cap = _pymax(_pymax(v, target), 1.0)  # Python's max(v, target, 1.0)
        earliest = t + time_to_go_c(_pymax(d, 0.0), v, v_cap, comfort)
        key = row_key[k]
        if math.isnan(entered_of[key]):
            entered_of[key] = earliest
        zk[nz], zr[nz], zd[nz], zv[nz], ze[nz], zen[nz], zrow[nz] = (key, ROAD_RAMP if ramp[k] else ROAD_MAIN, d, v,
                                                                      earliest, entered_of[key], k)
        nz += 1
    si[I_DRAW] = j_noise
    # the sequence's vehicles that left the zone: crossed now if still on the road at or past the point
    n = si[I_N]
    cross_t = np.full(n, np.nan)
    for j in range(n):
        inside = False
        for a in range(nz):
            if zk[a] == sk[j]:
                inside = True
                break
        if inside:
            continue
        for k in range(row_key.shape[0]):
            if row_key[k] == sk[j]:
                if dist[k] <= 0.0:
                    cross_t[j] = t
                break
    status = assign_core(t, zk[:nz], zr[:nz], zd[:nz], zv[:nz], ze[:nz], zen[:nz], cross_t, sk, sr, srank, se, st,
                         sen, sd, sv, si, sf, fifo, h_same, h_cross, freeze, repair, repack, max_shift, horizon, fair,
                         w_main, w_ramp)
    if status != STATUS_OK:
        return status, nz, si[I_N]
    for j in range(si[I_N]):
        for a in range(nz):
            if zk[a] == sk[j]:
                k = zrow[a]
                slot_out[j, 0], slot_out[j, 1], slot_out[j, 2], slot_out[j, 3] = sk[j], k, connected[k], ramp[k]
                break
    return status, nz, si[I_N]


class ArrayCoordinator:
    """``Coordinator`` (no ``SlotCheck``) with its state as arrays over integer vehicle keys (the caller's);
    ``assign`` takes the same arguments as ``Coordinator.assign`` (ids mapped to keys here) for tests and
    any caller, :func:`coordinate_into` is the controller's path. The same times and sequences, tie
    breaks by id included (through the Python ``Coordinator`` on the same state)."""

    def __init__(self, policy: str, cfg: CoordinatorConfig | None = None) -> None:
        self._py = Coordinator(policy, cfg)  # type: ignore[arg-type]  # the tie path (and the checks)
        self.policy, self.cfg = self._py.policy, self._py.cfg
        c = self.cfg
        self.params = (self.policy == "fifo", c.headway_same_s, c.headway_cross_s, c.freeze_s, c.repair_tol_s,
                       c.repack_tol_s, c.max_shift, c.horizon, c.fairness_delay_s, c.weight_main, c.weight_ramp)
        # coordinate_into's packed configuration: the floats (the caller appends its three), the ints
        self.params_f = (c.headway_same_s, c.headway_cross_s, c.freeze_s, c.repair_tol_s, c.repack_tol_s,
                         c.fairness_delay_s, c.weight_main, c.weight_ramp)
        self.params_i = np.array([self.policy == "fifo", c.max_shift, c.horizon], dtype=np.int64)
        self.si = np.zeros(8, dtype=np.int64)
        self.sf = np.zeros(4)
        self._cap = 0
        self._grow(32)
        self.key_of: dict[str, int] = {}  # vehicle id -> key (``assign``'s; the controller keeps its own)
        self.id_of: list[str] = []  # key -> vehicle id (the controller's keys: set by the controller)
        self._seq: list[str] | None = []

    def _grow(self, cap: int) -> None:
        n = int(self.si[I_N])
        s_int, s_flt = np.zeros((3, cap), dtype=np.int64), np.full((5, cap), np.nan)
        if self._cap:
            s_int[:, :n], s_flt[:, :n] = self.s_int[:, :n], self.s_flt[:, :n]
        self.s_int, self.s_flt, self._cap = s_int, s_flt, cap

    # the slots' columns (views of the packed state)
    sk = property(lambda self: self.s_int[0])
    sr = property(lambda self: self.s_int[1])
    srank = property(lambda self: self.s_int[2])
    se = property(lambda self: self.s_flt[0])
    st = property(lambda self: self.s_flt[1])
    sen = property(lambda self: self.s_flt[2])
    sd = property(lambda self: self.s_flt[3])
    sv = property(lambda self: self.s_flt[4])

    def room(self, n_zone: int) -> None:
        """Room for the slots and a zone of ``n_zone`` new vehicles."""
        need = int(self.si[I_N]) + n_zone
        if need > self._cap:
            self._grow(max(need, 2 * self._cap))

    def state_arrays(self) -> tuple[np.ndarray, ...]:
        return self.sk, self.sr, self.srank, self.se, self.st, self.sen, self.sd, self.sv, self.si, self.sf

    @property
    def max_shift_seen(self) -> int:
        return int(self.si[I_SHIFT])

    @property
    def sequence(self) -> list[str]:
        """Current crossing order of the vehicles still in the zone (their ids)."""
        if self._seq is None:
            ids = self.id_of
            self._seq = [ids[k] for k in self.sk[: self.si[I_N]].tolist()]
        return self._seq

    def set_sequence(self, seq: list[str]) -> list[str]:
        """The sequence's ids as the caller built them from the slots' keys (the state arrays were written)."""
        self._seq = seq
        return seq

    def changed(self) -> None:
        """The state arrays were written (the sequence is rebuilt on its next read)."""
        self._seq = None

    # -- the tie path: the Python coordinator on the same state -----------------------------------------
    def to_state(self) -> _State:
        n, ids = int(self.si[I_N]), self.id_of
        slots = [_Slot(ids[k], _ROADS[r], rank, e, tt, en, d, v) for k, r, rank, e, tt, en, d, v in zip(
            self.sk[:n].tolist(), self.sr[:n].tolist(), self.srank[:n].tolist(), self.se[:n].tolist(),
            self.st[:n].tolist(), self.sen[:n].tolist(), self.sd[:n].tolist(), self.sv[:n].tolist(), strict=True)]
        tail = (float(self.sf[F_TAIL_T]), _ROADS[int(self.si[I_TAIL_ROAD])]) if self.si[I_HAS_TAIL] else None
        return _State(slots, int(self.si[I_DONE]), int(self.si[I_RANKED]), tail)  # type: ignore[arg-type]

    def from_state(self, state: _State, key_of: dict[str, int], max_shift_seen: int) -> None:
        n = len(state.slots)
        self.room(n - int(self.si[I_N]))
        for j, s in enumerate(state.slots):
            self.sk[j], self.sr[j], self.srank[j] = key_of[s.vid], _ROADS.index(s.road), s.rank
            self.se[j], self.st[j], self.sen[j], self.sd[j], self.sv[j] = (s.earliest_s, s.t_s, s.entered_s, s.dist_m,
                                                                          s.speed_mps)
        self.si[I_N], self.si[I_DONE], self.si[I_RANKED] = n, state.n_done, state.n_ranked
        self.si[I_HAS_TAIL] = state.tail is not None
        if state.tail is not None:
            self.sf[F_TAIL_T], self.si[I_TAIL_ROAD] = state.tail[0], _ROADS.index(state.tail[1])
        self.si[I_SHIFT] = max_shift_seen
        self.changed()

    def assign_py(self, t_s: float, vehicles: list[ZoneVehicle], crossed_s: dict[str, float] | None,
                  key_of: dict[str, int]) -> dict[str, float]:
        """``Coordinator.assign`` in Python on this state (written back)."""
        self._py._st = self.to_state()
        self._py.max_shift_seen = int(self.si[I_SHIFT])
        times = self._py.assign(t_s, vehicles, crossed_s)
        self.from_state(self._py._st, key_of, self._py.max_shift_seen)
        return times

    # -- Coordinator's interface ------------------------------------------------------------------------
    def assign(self, t_s: float, vehicles: list[ZoneVehicle], crossed_s: dict[str, float] | None = None
               ) -> dict[str, float]:
        """``Coordinator.assign``: the same times (and sequence) for the same calls."""
        key_of, ids = self.key_of, self.id_of
        for v in vehicles:
            if v.id not in key_of:
                key_of[v.id] = len(ids)
                ids.append(v.id)
        nz = len(vehicles)
        self.room(nz)
        n = int(self.si[I_N])
        seq = self.sequence
        cross_t = np.array([s_t if crossed_s is None else crossed_s.get(vid, np.nan)
                            for vid, s_t in zip(seq, self.st[:n].tolist(), strict=True)], dtype=float)
        zk = np.array([key_of[v.id] for v in vehicles], dtype=np.int64)
        zr = np.array([_ROADS.index(v.road) for v in vehicles], dtype=np.int64)
        zd, zv, ze, zen = (np.array([getattr(v, a) for v in vehicles], dtype=float)
                           for a in ("dist_to_merge_m", "speed_mps", "earliest_arrival_s", "entered_s"))
        status = assign_core(float(t_s), zk, zr, zd, zv, ze, zen, cross_t, *self.state_arrays(), *self.params)
        if status == STATUS_TIE:
            return self.assign_py(t_s, vehicles, crossed_s, key_of)
        self.changed()
        n = int(self.si[I_N])
        return dict(zip(self.sequence, self.st[:n].tolist(), strict=True))


def tie_zone(zk: np.ndarray, zr: np.ndarray, zd: np.ndarray, zv: np.ndarray, ze: np.ndarray, zen: np.ndarray,
             nz: int, ids: list[str]) -> list[ZoneVehicle]:
    """The kernel's zone as ``ZoneVehicle``s (the tie path)."""
    return [ZoneVehicle(ids[k], _ROADS[r], d, v, e, en)  # type: ignore[arg-type]
            for k, r, d, v, e, en in zip(zk[:nz].tolist(), zr[:nz].tolist(), zd[:nz].tolist(), zv[:nz].tolist(),
                                         ze[:nz].tolist(), zen[:nz].tolist(), strict=True)]
