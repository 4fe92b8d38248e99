"""The roadside unit's pairing and slot planning of ``v2x_merge_gaps`` in one compiled call (issue 27).

``GapMerging._slots_py`` and ``_pair_py`` do it in Python on vehicle names, every step: the RSU's noisy
view (projected positions, speeds), the arrival times at the junction, the earliest arrivals of the
connected ramp vehicles (``trajectory.time_to_go``), the pairs kept, a partner for every other connected
ramp vehicle, then every pair's slot.  :func:`plan_slots` does the same on row indices with the same
values in the same order; the names, the draws and the event log stay in Python:

- the noise arrays are drawn by the caller from the same generators in the same order;
- Python's ``sorted`` (stable, by key) is ``np.argsort(kind="mergesort")`` (stable): the ramp vehicles
  by distance, the highway candidates by arrival, their row order breaking ties (a NaN key, which the
  RSU's finite readings never give, would sort otherwise);
- the highway vehicle ahead (``GapMerging._lead_of``) is the first of the highway line, sorted stably
  by front, whose front is greater than the vehicle's front + 0.1 m (``np.searchsorted``'s side right);
- Python's ``max`` keeps the first of equal (or NaN) values; ``np.maximum(a, 0.0)``'s choice is the first
  operand when it is not smaller or NaN;
- ``x ** 2`` on floats (Python's and numpy's scalar power) is the C library's ``pow``, not ``x * x``:
  called as glibc's ``powf64`` (``coord_kernel``), which LLVM does not turn into a multiplication.

:func:`gap_tick` runs the RSU's message (:func:`measure_plan`) and ``wave_kernel.tick`` (the broadcast, the
delivery, the highway law) in one call: ``v2x_merge_gaps``' compiled tick.

``tests/controllers/test_ctrl_gap_kernel.py`` checks the controller's compiled planning against the Python
one on random ticks, bit for bit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from corridor.controllers.merging.coord_kernel import HAVE_C_POW, _c_pow, time_to_go_c
from corridor.controllers.merging.wave_kernel import safe_accel_c, tick

# cfg: the parameters, in this order
(C_MERGE_X, C_CROSS_X, C_COS_RAMP, C_OPEN_GAP, C_RAMP_GAP, C_PAIR_ZONE, C_PARTNER_MIN, C_RESTART_PARTNER,
 C_HUMAN_MARGIN, C_RESTART_GAP, C_MIN_RUN, C_COMMIT, C_B_COMFORT, C_PLAN_ACCEL, C_CELL_BASE, C_CELL_M, C_CROSS_SPEED,
 C_U_MAX, C_HEAD_ONLY, C_LEAD_ON, C_LEAD_GAP, C_LEAD_RAMP_GAP, C_A_MAX, C_HOLD, C_NOISE_K, C_FOLLOW_TAU, C_FOLLOW_GAP,
 C_SX, C_SV, N_CFG) = range(30)
# out_pair columns: ramp row, partner row, status, lead row (-1: none)
P_RAMP, P_PARTNER, P_STATUS, P_LEAD = range(4)
ST_SLOT, ST_DROPPED, ST_GONE = 0, 1, 2  # a slot given; dropped in the slot phase; not kept by the pairing
# out_slot columns: the slot's times, then the partner's (x, v, length) and the ramp vehicle's
S_T_RAMP, S_T_PARTNER, S_LEAD_X, S_LEAD_V, S_LEAD_LEN, S_PX, S_PV, S_PLEN, S_RX, S_RV, S_RLEN = range(11)
# [m/s] the least crossing speed planned: every cell before the merge at 0 m/s (a standstill) would give 0, and
# the arrival times (``time_to_go``'s cruise at it) would divide by it; as the RSU's arrival times' 1 m/s floor
MIN_CROSS_SPEED_MPS = 1.0


def cfg_array(p: Any, merge_x: float, cross_x: float, cos_ramp: float, cell_base: float = math.nan) -> np.ndarray:
    """:func:`plan_slots`'s (and :func:`measure_plan`'s) parameters from ``GapMerging.Params`` ``p``, the
    network's geometry and the first cell's start [m]."""
    cfg = np.empty(N_CFG)
    cfg[C_CELL_BASE], cfg[C_CELL_M], cfg[C_CROSS_SPEED], cfg[C_U_MAX] = cell_base, p.cell_m, p.cross_speed_mps, p.u_max_mps
    cfg[C_MERGE_X], cfg[C_CROSS_X], cfg[C_COS_RAMP] = merge_x, cross_x, cos_ramp
    cfg[C_OPEN_GAP], cfg[C_RAMP_GAP], cfg[C_PAIR_ZONE] = p.open_time_gap_s, p.ramp_time_gap_s, p.pair_zone_m
    cfg[C_PARTNER_MIN], cfg[C_RESTART_PARTNER] = p.partner_min_speed_mps, p.restart_partner_speed_mps
    cfg[C_HUMAN_MARGIN], cfg[C_RESTART_GAP], cfg[C_MIN_RUN] = p.human_margin_s, p.restart_gap_s, p.min_run_speed_mps
    cfg[C_COMMIT], cfg[C_B_COMFORT], cfg[C_PLAN_ACCEL] = p.commit_m, p.b_comfort_mps2, p.plan_accel_mps2
    cfg[C_HEAD_ONLY] = 1.0 if p.pair_queue_head_only else 0.0
    cfg[C_LEAD_ON] = 1.0 if p.lead_close_up else 0.0
    cfg[C_LEAD_GAP], cfg[C_LEAD_RAMP_GAP], cfg[C_A_MAX] = p.lead_time_gap_s, p.lead_ramp_gap_s, p.a_max_mps2
    cfg[C_HOLD] = 1.0 if p.lead_close_up and p.lead_hold else 0.0
    cfg[C_NOISE_K], cfg[C_FOLLOW_TAU], cfg[C_FOLLOW_GAP] = p.lead_noise_k, p.lead_follow_tau_s, p.lead_follow_gap_m
    cfg[C_SX], cfg[C_SV] = p.ramp_sensor_noise_m, p.sensor_noise_mps
    return cfg


@njit(cache=True)
def _lead(order: np.ndarray, front_sorted: np.ndarray, x: float) -> int:
    """The first of ``order`` whose front (``front_sorted``) is > ``x`` (-1: none): searchsorted right."""
    lo, hi = 0, front_sorted.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if x < front_sorted[mid]:
            hi = mid
        else:
            lo = mid + 1
    return order[lo] if lo < order.shape[0] else -1


@njit(cache=True)
def _follow_gap(cfg: np.ndarray, v: float, dist: float, v_cross: float) -> float:
    """``GapMerging._follow_gap`` (``v_cross``: this broadcast's crossing speed)."""
    if v < cfg[C_MIN_RUN] and dist <= cfg[C_COMMIT]:
        return cfg[C_RESTART_GAP]
    if cfg[C_HOLD] != 0.0:
        w = v_cross if v_cross >= MIN_CROSS_SPEED_MPS else MIN_CROSS_SPEED_MPS  # Python's max(v_cross, MIN)
        return cfg[C_FOLLOW_TAU] + cfg[C_FOLLOW_GAP] / w
    return cfg[C_OPEN_GAP]


@njit(cache=True)
def _noise_margin(cfg: np.ndarray, j: int, lead: int, dist: np.ndarray, v: np.ndarray) -> float:
    """``GapMerging._noise_margin`` (``lead`` -1: none)."""
    if cfg[C_HOLD] == 0.0:
        return 0.0
    sx, sv = cfg[C_SX], cfg[C_SV]
    var = 0.0
    for q in range(2):
        k = j if q == 0 else lead
        if k < 0:
            break
        vk = v[k] if v[k] >= 1.0 else 1.0  # Python's max(v, 1.0)
        var += _c_pow(sx / vk, 2.0) + _c_pow(dist[k] * sv / (vk * vk), 2.0)
    return cfg[C_NOISE_K] * math.sqrt(var)


@njit(cache=True)
def _running(cfg: np.ndarray, v: float, dist: float, b2: float) -> bool:
    """``GapMerging._slots``'s test of a ramp vehicle on its run to the junction (``v ** 2``: C's pow)."""
    return v >= cfg[C_MIN_RUN] and dist <= _c_pow(v, 2.0) / b2 + cfg[C_COMMIT]


@njit(cache=True)
def _fits_at(cfg: np.ndarray, connected: bool, x_j: float, eta_j: float, t: float, t_ramp: float, h2: float) -> bool:
    """``GapMerging._fits_at``."""
    if connected and cfg[C_HOLD] == 0.0:
        v_min = cfg[C_PARTNER_MIN] if h2 <= cfg[C_OPEN_GAP] else cfg[C_RESTART_PARTNER]
        return t + (cfg[C_MERGE_X] - x_j) / v_min >= t_ramp + h2
    return h2 <= cfg[C_OPEN_GAP] and eta_j >= t_ramp + h2 + cfg[C_HUMAN_MARGIN]


@njit(cache=True)
def _lead_term(cfg: np.ndarray, t: float, j: int, order: np.ndarray, front_sorted: np.ndarray, front: np.ndarray,
               connected: np.ndarray, eta: np.ndarray, dist: np.ndarray, v: np.ndarray) -> float:
    """``GapMerging._lead_term``: the earliest slot [s] behind highway vehicle ``j``."""
    if cfg[C_LEAD_ON] == 0.0 or not connected[j]:
        return eta[j] + cfg[C_RAMP_GAP]
    t_plan = t + time_to_go_c(dist[j], v[j], cfg[C_U_MAX], cfg[C_A_MAX])
    j2 = _lead(order, front_sorted, front[j] + 0.1)
    if j2 >= 0:
        b = eta[j2] + cfg[C_LEAD_GAP]
        if b > t_plan:  # Python's max(t_plan, b)
            t_plan = b
    a = eta[j]
    if t_plan < a:  # Python's min(eta, t_plan)
        a = t_plan
    return a + cfg[C_LEAD_RAMP_GAP]


@njit(cache=True)
def _plan(t: float, v_cross: float, cfg: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray,
          x_noise: np.ndarray, v_noise: np.ndarray, connected: np.ndarray, ramp: np.ndarray, on_ramp: np.ndarray,
          pairs: np.ndarray, t_slot_of: np.ndarray, has_slot: np.ndarray, x: np.ndarray, v: np.ndarray,
          out_pair: np.ndarray, out_slot: np.ndarray, held: np.ndarray) -> int:
    """``GapMerging._slots`` (with ``_pair``) on rows (``held``: per pair, whether its slot holds (``lead_hold``):
    read for the ``m`` kept pairs, written for the new ones).  ``pairs`` (m, 2): the pairs (ramp row, partner row;
    -1: gone from the road) in the controller's order, ``t_slot_of`` / ``has_slot`` their slots so far.
    Writes the noisy view ``x``, ``v`` and per pair, the kept ones in order then the new ones in pairing
    order, ``out_pair`` (ramp row, partner row, status, lead row) and ``out_slot`` (the slot's floats).
    Returns the number of ``out_pair`` rows (the new pairs are those past the kept ones: status
    ``ST_GONE`` rows included, ``m`` rows come first)."""
    n = front.shape[0]
    merge_x, cross_x, cos_ramp = cfg[C_MERGE_X], cfg[C_CROSS_X], cfg[C_COS_RAMP]
    eta, earliest, dist = np.empty(n), np.full(n, np.nan), np.empty(n)
    for i in range(n):
        xi = front[i]
        if on_ramp[i]:
            xi = merge_x - (merge_x - xi) / cos_ramp
        xi = xi + x_noise[i]
        vi = speed[i] + v_noise[i]
        vi = vi if (vi >= 0.0 or math.isnan(vi)) else 0.0
        x[i], v[i] = xi, vi
        d = merge_x - xi
        d = d if (d >= 0.0 or math.isnan(d)) else 0.0
        w = vi if (vi >= 1.0 or math.isnan(vi)) else 1.0
        eta[i] = t + d / w
        dist[i] = d
    for i in range(n):
        if connected[i] and ramp[i]:
            d = merge_x - x[i]
            d = 0.0 if 0.0 > d else d  # Python's max(d, 0.0)
            earliest[i] = t + time_to_go_c(d, v[i], v_cross, cfg[C_PLAN_ACCEL])
    # the highway line (not on the ramp, not a ramp vehicle) sorted by front, for the vehicle ahead
    n_line = 0
    for i in range(n):
        if not on_ramp[i] and not ramp[i]:
            n_line += 1
    line = np.empty(n_line, dtype=np.int64)
    n_line = 0
    for i in range(n):
        if not on_ramp[i] and not ramp[i]:
            line[n_line] = i
            n_line += 1
    order = line[np.argsort(front[line], kind="mergesort")]
    front_sorted = front[order]
    # _pair: the pairs kept, the partners taken, the last slot
    m = pairs.shape[0]
    in_pair = np.zeros(n, dtype=np.bool_)
    taken = np.zeros(n, dtype=np.bool_)
    t_prev = -math.inf
    first = True
    for q in range(m):
        r, c = pairs[q, 0], pairs[q, 1]
        out_pair[q, P_RAMP], out_pair[q, P_PARTNER], out_pair[q, P_LEAD] = r, c, -1
        if r >= 0 and c >= 0 and front[r] < cross_x and front[c] < merge_x:
            out_pair[q, P_STATUS] = ST_SLOT
            in_pair[r] = True
            taken[c] = True
            ts = t_slot_of[q] if has_slot[q] else -math.inf
            if first:
                t_prev, first = ts, False
            elif ts > t_prev:
                t_prev = ts
        else:
            out_pair[q, P_STATUS] = ST_GONE
    n_out = m
    # pair_queue_head_only: no connected ramp vehicle behind an unconnected vehicle on the ramp
    behind = np.zeros(n, dtype=np.bool_)
    if cfg[C_HEAD_ONLY] != 0.0:
        for h in range(n):
            if on_ramp[h] and not connected[h]:
                for i in range(n):
                    if front[h] > front[i]:
                        behind[i] = True
    n_ramp = 0
    for i in range(n):
        if connected[i] and ramp[i] and on_ramp[i] and not in_pair[i] and not behind[i]:
            n_ramp += 1
    if n_ramp:
        cand = np.empty(n_ramp, dtype=np.int64)
        n_ramp = 0
        for i in range(n):
            if connected[i] and ramp[i] and on_ramp[i] and not in_pair[i] and not behind[i]:
                cand[n_ramp] = i
                n_ramp += 1
        cand = cand[np.argsort(dist[cand], kind="mergesort")]
        lo_x, hi_x = merge_x - 10.0, merge_x - cfg[C_PAIR_ZONE]
        n_hw = 0
        for i in range(n):
            if not ramp[i] and not on_ramp[i] and front[i] < lo_x and front[i] > hi_x:
                n_hw += 1
        hw = np.empty(n_hw, dtype=np.int64)
        n_hw = 0
        for i in range(n):
            if not ramp[i] and not on_ramp[i] and front[i] < lo_x and front[i] > hi_x:
                hw[n_hw] = i
                n_hw += 1
        hw = hw[np.argsort(eta[hw], kind="mergesort")]
        hold = cfg[C_HOLD] != 0.0
        for k in cand:
            h2 = _follow_gap(cfg, speed[k], dist[k], v_cross)
            best, t_best, is_held = -1, 0.0, False
            # lead_close_up: first behind a connected leader, the follower at its own speed (nobody slowing)
            if cfg[C_LEAD_ON] != 0.0 and h2 <= (cfg[C_RESTART_GAP] - 1e-9 if hold else cfg[C_OPEN_GAP]):
                for j in hw:
                    if taken[j]:
                        continue
                    lead = _lead(order, front_sorted, front[j] + 0.1)
                    if lead < 0 or not connected[lead]:
                        continue
                    t_ramp = earliest[k]  # Python's max(earliest, t_prev + open, _lead_term)
                    b = t_prev + cfg[C_OPEN_GAP]
                    if b > t_ramp:
                        t_ramp = b
                    b = _lead_term(cfg, t, lead, order, front_sorted, front, connected, eta, dist, v)
                    if b > t_ramp:
                        t_ramp = b
                    if hold:
                        fit = eta[j] >= t_ramp + h2 + cfg[C_HUMAN_MARGIN] + _noise_margin(cfg, j, lead, dist, v)
                    else:
                        fit = eta[j] >= t_ramp + h2 + cfg[C_HUMAN_MARGIN]
                    if fit:
                        best, t_best, is_held = j, t_ramp, hold
                        break
            if hold and best < 0:  # no partner slows: a natural gap, any follower at its own speed
                for j in hw:
                    if taken[j]:
                        continue
                    lead = _lead(order, front_sorted, front[j] + 0.1)
                    t_ramp = earliest[k]
                    b = t_prev + cfg[C_OPEN_GAP]
                    if b > t_ramp:
                        t_ramp = b
                    b = (_lead_term(cfg, t, lead, order, front_sorted, front, connected, eta, dist, v) if lead >= 0
                         else -math.inf)
                    if b > t_ramp:
                        t_ramp = b
                    if (h2 < cfg[C_RESTART_GAP] - 1e-9 and eta[j] >= t_ramp + h2 + cfg[C_HUMAN_MARGIN]
                            + _noise_margin(cfg, j, lead, dist, v)):
                        best, t_best = j, t_ramp
                        break
            if best < 0 and not hold:  # the partner-slows pairing
                for j in hw:
                    if taken[j]:
                        continue
                    lead = _lead(order, front_sorted, front[j] + 0.1)
                    t_ramp = earliest[k]  # Python's max(earliest, t_prev + open, _lead_term or -inf)
                    b = t_prev + cfg[C_OPEN_GAP]
                    if b > t_ramp:
                        t_ramp = b
                    b = (_lead_term(cfg, t, lead, order, front_sorted, front, connected, eta, dist, v) if lead >= 0
                         else -math.inf)
                    if b > t_ramp:
                        t_ramp = b
                    if _fits_at(cfg, connected[j], front[j], eta[j], t, t_ramp, h2):
                        best, t_best = j, t_ramp
                        break
            if best < 0:
                continue
            out_pair[n_out, P_RAMP], out_pair[n_out, P_PARTNER], out_pair[n_out, P_STATUS] = k, best, ST_SLOT
            out_pair[n_out, P_LEAD] = -1
            out_slot[n_out, S_T_RAMP] = t_best  # the new pair's slot so far
            held[n_out] = is_held
            taken[best] = True
            t_prev = t_best
            n_out += 1
    # _slots: every pair's slot (the kept ones in order, then the new ones)
    b2 = 2.0 * cfg[C_B_COMFORT]  # as Python's 2.0 * b_comfort
    for q in range(n_out):
        if out_pair[q, P_STATUS] != ST_SLOT:
            continue
        kr, kc = out_pair[q, P_RAMP], out_pair[q, P_PARTNER]
        if q < m:
            t_slot = t_slot_of[q] if has_slot[q] else earliest[kr]
        else:
            t_slot = out_slot[q, S_T_RAMP]
        running = _running(cfg, v[kr], dist[kr], b2)
        if earliest[kr] > t_slot + cfg[C_RAMP_GAP] and not running:
            out_pair[q, P_STATUS] = ST_DROPPED
            continue
        j = _lead(order, front_sorted, front[kc] + 0.1)
        out_pair[q, P_LEAD] = j
        if j >= 0:
            if not held[q]:  # lead_hold: a held slot is not moved with the leader's re-plan
                b = _lead_term(cfg, t, j, order, front_sorted, front, connected, eta, dist, v)
                if b > t_slot:  # Python's max(t_slot, _lead_term)
                    t_slot = b
            out_slot[q, S_LEAD_X], out_slot[q, S_LEAD_V], out_slot[q, S_LEAD_LEN] = x[j], v[j], length[j]
        h2 = _follow_gap(cfg, v[kr], dist[kr], v_cross)
        if not running and not held[q] and not _fits_at(cfg, connected[kc], x[kc], eta[kc], t, t_slot, h2):
            out_pair[q, P_STATUS] = ST_DROPPED
            continue
        out_slot[q, S_T_RAMP], out_slot[q, S_T_PARTNER] = t_slot, t_slot + h2
        out_slot[q, S_PX], out_slot[q, S_PV], out_slot[q, S_PLEN] = x[kc], v[kc], length[kc]
        out_slot[q, S_RX], out_slot[q, S_RV], out_slot[q, S_RLEN] = x[kr], v[kr], length[kr]
    return n_out



# the state's columns may be read-only views (the snapshot's): read-only array types (writable ones convert)
_RF, _RB = types.Array(types.float64, 1, "A", readonly=True), types.Array(types.bool_, 1, "A", readonly=True)
_RI = types.Array(types.int64, 1, "A", readonly=True)
_SIG = types.int64(types.float64, types.float64, _RF, _RF, _RF, _RF, _RF, _RF, _RB, _RB, _RB, types.int64[:, :],
                   types.float64[:], types.bool_[:], types.float64[:], types.float64[:], types.int64[:, :],
                   types.float64[:, :], types.bool_[:])


@(njit(_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def plan_slots(t: float, v_cross: float, cfg: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray,
               x_noise: np.ndarray, v_noise: np.ndarray, connected: np.ndarray, ramp: np.ndarray, on_ramp: np.ndarray,
               pairs: np.ndarray, t_slot_of: np.ndarray, has_slot: np.ndarray, x: np.ndarray, v: np.ndarray,
               out_pair: np.ndarray, out_slot: np.ndarray, held: np.ndarray) -> int:
    """``GapMerging._slots`` (see :func:`_plan`)."""
    return _plan(t, v_cross, cfg, front, speed, length, x_noise, v_noise, connected, ramp, on_ramp, pairs, t_slot_of,
                 has_slot, x, v, out_pair, out_slot, held)


_MEASURE_SIG = types.int64(types.float64, types.float64[:], _RF, _RF, _RF, _RF, _RF, _RF, _RB, _RB, _RB,
                           types.int64[:, :], types.float64[:], types.bool_[:], types.float64[:], types.float64[:],
                           types.int64[:, :], types.float64[:, :], _RI, types.float64[:], types.float64[:],
                           types.float64[:])


@njit(cache=True)
def _measure_plan(t: float, cfg: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray, noise: np.ndarray,
                 x_noise: np.ndarray, v_noise: np.ndarray, connected: np.ndarray, ramp: np.ndarray, on_ramp: np.ndarray,
                 pairs: np.ndarray, t_slot_of: np.ndarray, has_slot: np.ndarray, x: np.ndarray, v: np.ndarray,
                 out_pair: np.ndarray, out_slot: np.ndarray, near: np.ndarray, cell_speed: np.ndarray, eta_ramp: np.ndarray,
                 v_cross_out: np.ndarray) -> int:
    """``GapMerging._measure`` in one call: the RSU's cells and ramp arrival times (``rsu_kernel.road_ahead``'s
    loop, inline on ``max(speed + noise, 0)``: its signature takes writable arrays and a separate call would
    cost a buffer and 10-16 us inside a run; into ``cell_speed`` and ``eta_ramp``), the crossing speed (the mean of the
    finite ``near`` cells, fewer than 8: summed in order; u_max when none; at least ``MIN_CROSS_SPEED_MPS``,
    at most ``cross_speed``: into ``v_cross_out[0]``), then :func:`plan_slots`."""
    n, n_cells = front.shape[0], cell_speed.shape[0]
    merge_x, cos_ramp, base, cell_m = cfg[C_MERGE_X], cfg[C_COS_RAMP], cfg[C_CELL_BASE], cfg[C_CELL_M]
    total = np.zeros(n_cells)
    count = np.zeros(n_cells, dtype=np.int64)
    r = 0
    for i in range(n):
        vi = speed[i] + noise[i]
        vi = vi if (vi >= 0.0 or math.isnan(vi)) else 0.0  # np.maximum(v, 0.0)
        if on_ramp[i]:
            dist = (merge_x - front[i]) / cos_ramp
            d = dist if (dist >= 0.0 or math.isnan(dist)) else 0.0
            w = vi if (vi >= 1.0 or math.isnan(vi)) else 1.0
            eta_ramp[r] = t + d / w
            r += 1
        else:
            k = np.int64(math.floor((front[i] - base) / cell_m))
            if k >= 0 and k < n_cells:
                total[k] += vi
                count[k] += 1
    for c in range(n_cells):
        cell_speed[c] = total[c] / count[c] if count[c] > 0 else np.nan
    acc, m = 0.0, 0
    for c in near:
        cv = cell_speed[c]
        if math.isfinite(cv):
            acc = cv if m == 0 else acc + cv
            m += 1
    v_merge = acc / m if m else cfg[C_U_MAX]
    if MIN_CROSS_SPEED_MPS > v_merge:  # Python's max(v_merge, MIN_CROSS_SPEED_MPS)
        v_merge = MIN_CROSS_SPEED_MPS
    v_cross = cfg[C_CROSS_SPEED] if cfg[C_CROSS_SPEED] < v_merge else v_merge  # Python's min(v_merge, cross)
    v_cross_out[0] = v_cross
    held = np.zeros(out_pair.shape[0], dtype=np.bool_)  # no lead_hold on the fused path (its planning: plan_slots)
    return _plan(t, v_cross, cfg, front, speed, length, x_noise, v_noise, connected, ramp, on_ramp, pairs, t_slot_of,
                 has_slot, x, v, out_pair, out_slot, held)


@(njit(_MEASURE_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def measure_plan(t: float, cfg: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray, noise: np.ndarray,
                 x_noise: np.ndarray, v_noise: np.ndarray, connected: np.ndarray, ramp: np.ndarray, on_ramp: np.ndarray,
                 pairs: np.ndarray, t_slot_of: np.ndarray, has_slot: np.ndarray, x: np.ndarray, v: np.ndarray,
                 out_pair: np.ndarray, out_slot: np.ndarray, near: np.ndarray, cell_speed: np.ndarray, eta_ramp: np.ndarray,
                 v_cross_out: np.ndarray) -> int:
    """:func:`_measure_plan` (the compiled entry point)."""
    return _measure_plan(t, cfg, front, speed, length, noise, x_noise, v_noise, connected, ramp, on_ramp, pairs,
                         t_slot_of, has_slot, x, v, out_pair, out_slot, near, cell_speed, eta_ramp, v_cross_out)


_TICK_SIG = types.int64(
    types.float64, types.float64[:], types.float64[:], _RF, _RF, _RF, _RF, _RF, _RF, _RB, _RB, _RB,
    types.Array(types.float64, 2, "A", readonly=True),
    types.boolean, _RI, _RI, types.float64[:], types.float64[:], _RB, types.int64[:], types.float64[:],
    types.float64[:, :], types.int64[:], types.float64[:], types.int64[:], types.int64[:], types.int64[:],
    types.int64[:], types.float64[:],
    types.float64[:], types.int64[:, :], types.float64[:], types.bool_[:], types.float64[:], types.float64[:],
    types.int64[:, :], types.float64[:, :], _RI, types.float64[:], types.float64[:], types.float64[:], types.int64[:])


@(njit(_TICK_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def gap_tick(t: float, wave_cfg: np.ndarray, cells_x: np.ndarray, front: np.ndarray, speed: np.ndarray,
             length: np.ndarray, noise: np.ndarray, x_noise: np.ndarray, v_noise: np.ndarray, on_ramp: np.ndarray,
             ramp: np.ndarray, connected: np.ndarray, pos: np.ndarray, send: bool, member_rows: np.ndarray,
             member_nodes: np.ndarray, u: np.ndarray, src: np.ndarray, attached: np.ndarray, latest: np.ndarray,
             msg_t: np.ndarray, msg_cells: np.ndarray, pend_node: np.ndarray, pend_t: np.ndarray, pend_msg: np.ndarray,
             cnt: np.ndarray, out_row: np.ndarray, out_act: np.ndarray, out_v: np.ndarray,
             plan_cfg: np.ndarray, pairs: np.ndarray, t_slot_of: np.ndarray, has_slot: np.ndarray, x: np.ndarray,
             v: np.ndarray, out_pair: np.ndarray, out_slot: np.ndarray, near: np.ndarray, cell_speed: np.ndarray,
             eta_ramp: np.ndarray, v_cross_out: np.ndarray, n_plan_out: np.ndarray) -> int:
    """``v2x_merge_gaps``' compiled tick in one call: when ``send``, the RSU's message (:func:`measure_plan` on
    ``noise``, ``x_noise`` and ``v_noise``: its cells, ramp arrival times, crossing speed and pairs and slots;
    their count into ``n_plan_out[0]``), then ``wave_kernel.tick`` with those cells (its broadcast's copies, the
    delivery, the law).  Returns ``wave_kernel.tick``'s count of commands."""
    if send:
        n_plan_out[0] = _measure_plan(t, plan_cfg, front, speed, length, noise, x_noise, v_noise, connected, ramp,
                                      on_ramp, pairs, t_slot_of, has_slot, x, v, out_pair, out_slot, near, cell_speed,
                                      eta_ramp, v_cross_out)
    return tick(t, wave_cfg, cells_x, front, speed, length, on_ramp, ramp, connected, pos, send, False, noise,
                cell_speed, member_rows, member_nodes, u, src, attached, latest, msg_t, msg_cells, pend_node, pend_t,
                pend_msg, cnt, out_row, out_act, out_v)


_ROWS_SIG = types.UniTuple(types.int64, 3)(_RB, _RB, _RB, _RF, types.float64, types.float64, types.float64, types.int64[:],
                        types.int64[:], types.int64[:], types.int64[:])


@(njit(_ROWS_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def tick_rows(connected: np.ndarray, ramp: np.ndarray, on_ramp: np.ndarray, front: np.ndarray, lo: float, hi: float,
              cross_x: float, partner_rows: np.ndarray, recv: np.ndarray, cramp: np.ndarray, onramp: np.ndarray
              ) -> tuple[int, int, int]:
    """A tick's rows in one pass (``GapMerging._receivers``' and ``_decide_more``'s numpy masks): into ``recv``
    the receivers (connected highway vehicles with ``lo`` < front < ``hi``, connected ramp vehicles with front
    < ``cross_x``, the rows in ``partner_rows``), into ``cramp`` the connected ramp vehicles, into ``onramp``
    the vehicles on the ramp, each in row order (``np.flatnonzero``'s).  Returns the three counts."""
    n = front.shape[0]
    mark = np.zeros(n, dtype=np.bool_)
    for q in range(partner_rows.shape[0]):
        mark[partner_rows[q]] = True
    n_recv = n_cramp = n_on = 0
    for i in range(n):
        c, r, f = connected[i], ramp[i], front[i]
        if (c and not r and f > lo and f < hi) or (c and r and f < cross_x) or mark[i]:
            recv[n_recv] = i
            n_recv += 1
        if c and r:
            cramp[n_cramp] = i
            n_cramp += 1
        if on_ramp[i]:
            onramp[n_on] = i
            n_on += 1
    return n_recv, n_cramp, n_on


# ramp_cfg: ramp_command's parameters, in this order
(R_MERGE_X, R_B_COMFORT, R_A_MAX, R_PLAN_ACCEL, R_WAIT_SPEED, R_COMMIT, R_PERIOD, R_REACTION, R_B_EGO, R_B_LEAD, R_S0,
 R_K_SPEED, R_PARTNER_MIN, R_RESTART_PARTNER, R_OPEN_GAP, N_RAMP_CFG) = range(16)


def ramp_cfg_array(p: Any, safety: Any, merge_x: float, period: float, k_speed: float) -> np.ndarray:
    """:func:`ramp_command`'s parameters from ``GapMerging.Params`` ``p``, the safety layer's, the junction's
    x [m], the step [s] and the speed hold's gain [1/s]."""
    cfg = np.empty(N_RAMP_CFG)
    cfg[R_MERGE_X], cfg[R_B_COMFORT], cfg[R_A_MAX], cfg[R_PLAN_ACCEL] = merge_x, p.b_comfort_mps2, p.a_max_mps2, \
        p.plan_accel_mps2
    cfg[R_WAIT_SPEED], cfg[R_COMMIT], cfg[R_PERIOD], cfg[R_K_SPEED] = p.wait_speed_mps, p.commit_m, period, k_speed
    cfg[R_REACTION], cfg[R_B_EGO], cfg[R_B_LEAD], cfg[R_S0] = (safety.reaction_s, safety.b_ego_mps2, safety.b_lead_mps2,
                                                               safety.s0_m)
    cfg[R_PARTNER_MIN], cfg[R_RESTART_PARTNER], cfg[R_OPEN_GAP] = (p.partner_min_speed_mps, p.restart_partner_speed_mps,
                                                                   p.open_time_gap_s)
    return cfg


@njit(cache=True)
def _arrival_accel(k: float, dist_m: float, v_mps: float, time_s: float, v_cross: float, accel: float,
                   brake: float) -> float:
    """``gap_components.arrival_accel`` (gain ``k``), the same bits."""
    if time_s <= 0.5 or dist_m <= 0:
        return k * (v_cross - v_mps)
    if time_to_go_c(dist_m, v_mps, v_cross, accel) >= time_s:
        return accel
    a_, b_, c_ = 1.0 / (2.0 * accel), time_s - v_cross / accel, v_cross * v_cross / (2.0 * accel) - dist_m
    disc = b_ * b_ - 4.0 * a_ * c_
    if disc < 0:
        return -brake
    v_c = (-b_ + math.sqrt(disc)) / (2.0 * a_)
    lo = v_cross - accel * time_s
    lo = 0.0 if 0.0 > lo else lo  # Python's max(lo, 0.0)
    if v_c < lo or v_c > v_cross:
        return -brake
    return k * (v_c - v_mps)


_RAMP_SIG = types.UniTuple(types.float64, 3)(
    types.float64[:], types.float64, types.float64, types.float64, types.boolean, types.boolean, types.float64,
    types.boolean, types.float64, types.float64, types.float64, types.float64, types.float64, types.float64,
    types.float64, types.float64, types.float64, types.float64)


@(njit(_RAMP_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def ramp_command(cfg: np.ndarray, t: float, t_sent: float, v_cross: float, committed: bool, has_slot: bool,
                 t_ramp: float, has_lead: bool, lead_x: float, lead_v: float, lead_len: float, partner_x: float,
                 partner_v: float, ramp_len: float, x: float, v: float, gap: float, v_lead: float
                 ) -> tuple[float, float, float]:
    """``GapMerging._ramp_command``'s values for a ramp vehicle at projected ``x`` [m], ``v`` [m/s] (physical
    leader ``gap`` [m], ``v_lead`` [m/s]) on a message sent at ``t_sent`` with crossing speed ``v_cross``
    and, ``has_slot``, its slot (``t_ramp``; the virtual leader ``lead_*`` when ``has_lead``, the partner's
    x and v, its own length as measured), ``committed`` or not: (the next speed [m/s], 1.0 when it commits
    now else 0.0, 1.0 when its virtual leader is fine else 0.0).  The caller keeps the committed set, the
    counters and the events."""
    b_comfort, reaction, b_ego, b_lead, s0 = cfg[R_B_COMFORT], cfg[R_REACTION], cfg[R_B_EGO], cfg[R_B_LEAD], cfg[R_S0]
    k = cfg[R_K_SPEED]
    dist = cfg[R_MERGE_X] - x
    dist = 0.0 if 0.0 > dist else dist  # Python's max(dist, 0.0)
    age = t - t_sent
    if committed:
        a = k * (v_cross - v)
    elif not has_slot:
        run_up = _c_pow(v_cross, 2.0) / (2.0 * cfg[R_PLAN_ACCEL]) + cfg[R_COMMIT]
        room = dist - run_up
        room = 0.0 if 0.0 > room else room
        w = math.sqrt(2.0 * b_comfort * room)
        ws = cfg[R_WAIT_SPEED]
        ws = w if w < ws else ws  # Python's min(wait_speed, w)
        a = k * (ws - v)
    else:
        a = _arrival_accel(k, dist, v, t_ramp - t, v_cross, cfg[R_PLAN_ACCEL], b_comfort)
    lo = -b_comfort
    a = lo if lo > a else a  # Python's max(a, -b_comfort)
    a = cfg[R_A_MAX] if cfg[R_A_MAX] < a else a  # Python's min(a, a_max)
    lead_ok = True
    if has_slot and has_lead:
        g = lead_x + lead_v * age - lead_len - x
        if g > 0.0:
            a = safe_accel_c(g, v, lead_v, a, reaction, b_ego, b_lead, s0)
        lead_ok = g > 0.0 and a > -b_comfort
    if math.isfinite(gap):
        a = safe_accel_c(gap, v, v_lead, a, reaction, b_ego, b_lead, s0)
    v_next = v + a * cfg[R_PERIOD]
    v_next = v_next if v_next > 0.0 else 0.0  # Python's max(0.0, v_next)
    commit = 0.0
    if not committed and has_slot and lead_ok:
        g = x - ramp_len - (partner_x + partner_v * age)  # _partner_ok
        if g > 0.0 and safe_accel_c(g, partner_v, v, 0.0, reaction, b_ego, b_lead, s0) > -b_comfort:
            if dist <= v * v / (2.0 * b_comfort) + cfg[R_COMMIT]:
                commit = 1.0
    return v_next, commit, 1.0 if lead_ok else 0.0


_CAP_SIG = types.float64(types.float64[:], types.float64, types.float64, types.float64, types.float64, types.float64,
                         types.float64, types.float64, types.float64, types.float64, types.float64)


@(njit(_CAP_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def partner_cap(cfg: np.ndarray, t: float, t_sent: float, t_partner: float, t_ramp: float, ramp_x: float,
                ramp_v: float, ramp_len: float, x: float, v: float, v_cmd: float) -> float:
    """``GapMerging._partner_cap``'s value for a partner at ``x`` [m], ``v`` [m/s] whose law gives ``v_cmd``
    [m/s], on its slot (``t_partner``, ``t_ramp``; the ramp vehicle as measured) in a message sent at ``t_sent``."""
    v_floor = cfg[R_PARTNER_MIN] if t_partner - t_ramp <= cfg[R_OPEN_GAP] else cfg[R_RESTART_PARTNER]
    d = t_partner - t
    d = 1e-3 if 1e-3 > d else d  # Python's max(d, 1e-3)
    q = (cfg[R_MERGE_X] - x) / d
    m = v if v < v_floor else v_floor  # Python's min(v_floor, v)
    v_cap = m if m > q else q  # Python's max(q, m)
    a = (v_cap - v) / cfg[R_PERIOD]
    lo = -cfg[R_B_COMFORT]
    a = lo if lo > a else a  # Python's max(a, -b_comfort)
    g = ramp_x + ramp_v * (t - t_sent) - ramp_len - x
    if g > 0 and ramp_v > cfg[R_WAIT_SPEED]:
        a = safe_accel_c(g, v, ramp_v, a, cfg[R_REACTION], cfg[R_B_EGO], cfg[R_B_LEAD], cfg[R_S0])
    y = v + a * cfg[R_PERIOD]
    y = y if y < v_cmd else v_cmd  # Python's min(v_cmd, y)
    return y if y > 0.0 else 0.0  # Python's max(0.0, y)


__all__ = ["HAVE_C_POW", "MIN_CROSS_SPEED_MPS", "ST_SLOT", "cfg_array", "gap_tick", "measure_plan", "partner_cap", "plan_slots", "ramp_cfg_array", "ramp_command",
           "tick_rows"]
