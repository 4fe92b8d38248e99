"""V2X merging's per-vehicle decisions of a tick in one compiled call (issue 27, the thirteenth CPU pass).

``V2XMerging._decide``'s loop over the vehicles holding an assignment, for the ticks' common case: the vehicle's
automaton quiet (no guard fires), its virtual gaps, the gap-opening and energy-optimal accelerations, the
safety layer against the virtual and the physical leader and the commanded speed, with the same floats in the
same order as the Python path (``components.py``: ``_virtual_gap``, ``QuietMerge``, ``_pre_opening_accel``,
``merge_accel``, ``_gap_opening_accel``, ``safe_accel``, the inline cap and command). The kernel changes nothing:
per vehicle it returns what to do (``OUT_*``) and the values (the commanded speed, the g values the quiet update
keeps, the virtual gap seen); the caller applies them in order, and leaves to the Python path every vehicle the
kernel returns ``OUT_PYTHON`` for (a guard fires: the jump and its event log; no automaton yet; an automaton
``QuietMerge`` does not serve).

Bits: Python's ``max(a, b)`` / ``min(a, b)`` (the first unless the second is strictly larger / smaller) as
``_pymax`` / ``_pymin``; Python's ``x ** 2`` is the C library's ``pow`` (``coord_kernel._c_pow``); numpy's
``T ** 3`` (the energy-optimal start acceleration's, ``trajectory.start_accel``) is not the C library's on every
machine, so the caller passes it per vehicle (numpy on a contiguous array: the same loop, the same bits, as on
the 0-d array the Python path uses).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from corridor.controllers.merging.coord_kernel import _c_pow
from corridor.controllers.merging.safety_layer import SafetyParams
from corridor.controllers.merging.switching import QuietMerge
from corridor.controllers.merging.trajectory import MotionLimits

# per vehicle, what the caller does (in the order of the vehicles)
OUT_SKIP = 0  # no row, or past the conflict point: nothing
OUT_LEAVE = 1  # out of the conflict (left lane, or a ramp vehicle that moved over): release, forget
OUT_STALE = 2  # the RSU went quiet: the fallback (before the automaton)
OUT_RELEASE = 3  # a mainline vehicle that follows its own leader: released if commanded (g kept)
OUT_FALLBACK = 4  # near the merge without a fresh track of its predecessor: the fallback (g kept)
OUT_COMMAND = 5  # a commanded speed (g kept)
OUT_PYTHON = 6  # the Python path decides this vehicle (nothing kept)
OUT_COMMAND_GAP = 7  # a commanded speed behind a virtual leader: its gap counts for the smallest (g kept)

# leaf modes of merge_automaton (switching.py) by code; -1: none, or one the kernel does not serve
MODE_CODES = {"approach": 0, "behind": 1, "ahead": 2, "free": 3, "early": 4, "open": 5, "pass": 6}
# the boundaries QuietMerge keeps per leaf mode (its g_now's keys, in its order)
G_NAMES = (("merge_enter",), ("gap_reject",), ("gap_accept",), ("yield_enter", "open_ahead"), ("yield_enter",),
           ("yield_exit", "yield_pass"), ("yield_exit", "yield_hold"))

# the per-vehicle input columns (one float array, the integers exact)
I_ROW, I_RX, I_MODE, I_PRED, I_PRED_ROW, I_PRED_ROAD, I_AHEAD, I_AHEAD_ROW, I_HAS_AHEAD = range(9)
I_T_SENT, I_T_CROSS = 9, 10
N_IN = 11
ROAD_MAIN, ROAD_RAMP = 0, 1  # I_PRED_ROAD (-1: no predecessor)

# the configuration's entries (V2XMerging._decide_cfg)
(C_PERIOD, C_STALE, C_A_MIN, C_A_MAX, C_V_MAX, C_A_DOWN, C_S0, C_H, C_TAU, C_B_EGO, C_B_LEAD, C_SAFE_S0,
 C_MERGE_ENTER, C_YIELD_ENTER, C_YIELD_EXIT, C_OPEN_AHEAD, C_GAP_REJECT, C_GAP_ACCEPT, C_YIELD_PASS,
 C_YIELD_HOLD) = range(20)
N_CFG = 20


def decide_config(period_s: float, stale_after_s: float, limits: MotionLimits, gap_s0_m: float, time_gap_s: float,
                  safety: SafetyParams, bounds: QuietMerge) -> np.ndarray:
    """``decide_into``'s configuration (``C_*``): the period [s], the staleness limit [s], the motion limits,
    the gap rule's standstill gap [m] and time gap [s], the safety layer and the boundaries' parameters."""
    cfg = np.zeros(N_CFG)
    for j, v in ((C_PERIOD, period_s), (C_STALE, stale_after_s), (C_A_MIN, limits.a_min_mps2),
                 (C_A_MAX, limits.a_max_mps2), (C_V_MAX, limits.v_max_mps), (C_A_DOWN, limits.a_min_mps2 * period_s),
                 (C_S0, gap_s0_m), (C_H, time_gap_s), (C_TAU, safety.reaction_s), (C_B_EGO, safety.b_ego_mps2),
                 (C_B_LEAD, safety.b_lead_mps2), (C_SAFE_S0, safety.s0_m), (C_MERGE_ENTER, bounds.merge_enter),
                 (C_YIELD_ENTER, bounds.yield_enter), (C_YIELD_EXIT, bounds.yield_exit),
                 (C_OPEN_AHEAD, bounds.open_ahead), (C_GAP_REJECT, bounds.gap_reject),
                 (C_GAP_ACCEPT, bounds.gap_accept), (C_YIELD_PASS, bounds.yield_pass),
                 (C_YIELD_HOLD, bounds.yield_hold)):
        cfg[j] = v
    return cfg


@njit(cache=True)
def _pymax(a: float, b: float) -> float:
    return b if b > a else a


@njit(cache=True)
def _pymin(a: float, b: float) -> float:
    return b if b < a else a


@njit(cache=True)
def _safe_accel(gap_m: float, v_ego: float, v_lead: float, a_cmd: float, cfg: np.ndarray) -> float:
    """``safety_layer.safe_accel`` (with ``safe_speed``)."""
    if math.isinf(gap_m):
        return a_cmd
    b_ego, b_lead, tau = cfg[C_B_EGO], cfg[C_B_LEAD], cfg[C_TAU]
    b = _pymin(b_ego, b_lead)
    reach_m = gap_m - cfg[C_SAFE_S0] + _c_pow(v_lead, 2.0) / (2.0 * b_lead)
    disc = b * b * tau * tau / 4.0 + b * (2.0 * reach_m - v_ego * tau)
    v1_max = -math.inf if disc < 0.0 else -b * tau / 2.0 + math.sqrt(disc)
    if v1_max < 0.0:
        return _pymin(a_cmd, -b_ego)
    a_safe = (v1_max - v_ego) / tau
    return _pymin(a_cmd, _pymax(a_safe, -b_ego))


@njit(cache=True)
def _merge_gap_accel(gap_m: float, v: float, v_lead: float, cfg: np.ndarray) -> float:
    """``V2XMerging._merge_gap_accel``."""
    g_des = cfg[C_S0] + v * cfg[C_H]
    return 0.23 * (gap_m - g_des) + 0.07 * 10.0 * (v_lead - v)


@njit(cache=True)
def _virtual_gap(t: float, rx: int, src: int, pred_row: int, d: float, length: np.ndarray, slot_of: np.ndarray,
                 row_of: np.ndarray, trk_x: np.ndarray, trk_t: np.ndarray, stale_after: float,
                 gap: np.ndarray) -> bool:
    """``V2XMerging._virtual_gap`` (``NodeTrackPool.predict_one``): known, and ``gap`` = (gap [m], the predecessor's
    speed [m/s], age [s], length [m]); ``rx`` / ``src`` the nodes (-1: none)."""
    if rx < 0 or src < 0 or rx >= slot_of.shape[0]:
        return False
    s = slot_of[rx]
    if s < 0 or src >= row_of.shape[1]:
        return False
    row = row_of[s, src]
    if row < 0:
        return False
    age = _pymax(0.0, t - trk_t[row])
    dt = np.rint(age * 1e9) * 1e-9  # Python's round (half to even), then the int times 1e-9
    x0, x1 = trk_x[row, 0], trk_x[row, 1]
    pos_lead, vel_lead = x0 + dt * x1, x1 + 0.0 * x0
    if age > stale_after:
        return False
    lead_len = length[pred_row] if pred_row >= 0 else 5.0
    gap[0], gap[1], gap[2], gap[3] = d + pos_lead - lead_len, vel_lead, age, lead_len
    return True


@njit(cache=True)
def _pre_opening(known: bool, gap: np.ndarray, v: float, cfg: np.ndarray) -> float:
    """``V2XMerging._pre_opening_accel``: NaN for None."""
    if not known:
        return math.nan
    a = _pymax(_merge_gap_accel(gap[0], v, _pymax(gap[1], 0.0), cfg), cfg[C_A_MIN])
    return a if a < 0.0 else math.nan


@njit(cache=True)
def _merge_accel(x0: float, v0: float, t0: float, tf: float, vf: float, t3: float, cfg: np.ndarray) -> float:
    """``trajectory.merge_accel(x0, v0, t0, tf, 0.0, vf, limits)`` with ``start_accel``; ``t3``: numpy's (tf - t0) ** 3."""
    a_min, a_max = cfg[C_A_MIN], cfg[C_A_MAX]
    if tf - t0 < 0.3 or x0 >= 0.0:
        return _pymin(_pymax((vf - v0) / 0.3, a_min), a_max)
    vf = _pymin(vf, _pymax(2.0 * (0.0 - x0) / (tf - t0) - v0, 0.0))
    t = tf - t0
    dx = (0.0 - x0) - v0 * t
    a = (6.0 * (vf - v0) * t - 12.0 * dx) / t3
    b = (vf - v0 - a * (t * t) / 2.0) / t
    return _pymin(_pymax(b, a_min), a_max)


@njit(cache=True)
def decide_into(t: float, target: float, inp: np.ndarray, cfg: np.ndarray, dist: np.ndarray, speed: np.ndarray,
                ramp: np.ndarray, right: np.ndarray, merged: np.ndarray, length: np.ndarray, lane_pos: np.ndarray,
                leader: np.ndarray, slot_of: np.ndarray, row_of: np.ndarray, trk_x: np.ndarray, trk_t: np.ndarray,
                t3: np.ndarray, code: np.ndarray, out: np.ndarray) -> int:
    """The tick's decisions of the ``inp.shape[0]`` vehicles (rows of ``inp``, columns ``I_*``; ``t3``: numpy's
    (``I_T_CROSS`` - t) ** 3 per vehicle): per vehicle its ``OUT_*`` code and ``out`` = (commanded speed [m/s], the
    kept g values (NaN: none), the virtual gap [m] whose minimum the controller keeps). Returns how many vehicles
    the Python path decides."""
    period, stale_after = cfg[C_PERIOD], cfg[C_STALE]
    gap = np.empty(4)
    n_py = 0
    for i in range(inp.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = math.nan, math.nan, math.nan, math.nan
        k = int(inp[i, I_ROW])
        if k < 0:
            code[i] = OUT_SKIP
            continue
        d = dist[k]
        if d < 0:
            code[i] = OUT_SKIP
            continue
        ramp_k = ramp[k]
        if not (ramp_k or right[k]) or merged[k]:
            code[i] = OUT_LEAVE
            continue
        if t - inp[i, I_T_SENT] > stale_after:
            code[i] = OUT_STALE
            continue
        mode = int(inp[i, I_MODE])
        if mode < 0:
            code[i] = OUT_PYTHON
            n_py += 1
            continue
        road = ROAD_RAMP if ramp_k else ROAD_MAIN
        pred_road = int(inp[i, I_PRED_ROAD])
        cross_pred = pred_road >= 0 and pred_road != road
        cross_ahead = inp[i, I_HAS_AHEAD] != 0.0 and not cross_pred
        rx = int(inp[i, I_RX])
        known = cross_pred and _virtual_gap(t, rx, int(inp[i, I_PRED]), int(inp[i, I_PRED_ROW]), d, length, slot_of,
                                            row_of, trk_x, trk_t, stale_after, gap)
        keep = math.nan  # QuietMerge._keep's gap + lag * length (NaN without a known gap)
        # QuietMerge: the g values, and whether a guard fires
        fires = False
        g1, g2 = math.nan, math.nan
        if mode == 0:  # approach
            g1 = cfg[C_MERGE_ENTER] - d
            fires = g1 >= 0.0
        elif mode == 3:  # free
            g1, g2 = cfg[C_YIELD_ENTER] - d, cfg[C_OPEN_AHEAD] - d
            fires = (g1 >= 0.0 and cross_pred) or (g2 > 0.0 and cross_ahead and not cross_pred)
        elif mode == 1:  # behind
            if known:
                keep = gap[0] + cfg[C_GAP_REJECT] * gap[3]
            g1 = -keep
            fires = g1 >= 0.0
        elif mode == 2:  # ahead
            if known:
                keep = gap[0] + cfg[C_GAP_ACCEPT] * gap[3]
            g1 = keep
            fires = g1 > 0.0
        elif mode == 5:  # open
            g1 = d - cfg[C_YIELD_EXIT]
            if known:
                keep = gap[0] + cfg[C_YIELD_PASS] * gap[3]
            g2 = -keep
            fires = g1 > 0.0 or not cross_pred or g2 >= 0.0
        elif mode == 6:  # pass
            g1 = d - cfg[C_YIELD_EXIT]
            if known:
                keep = gap[0] + cfg[C_YIELD_HOLD] * gap[3]
            g2 = keep
            fires = g1 > 0.0 or not cross_pred or g2 > 0.0
        else:  # early
            g1 = cfg[C_YIELD_ENTER] - d
            fires = (g1 >= 0.0 and cross_pred) or not cross_ahead or cross_pred
        if fires:
            code[i] = OUT_PYTHON
            n_py += 1
            continue
        out[i, 1], out[i, 2] = g1, g2
        near_merge = mode == 1 or mode == 2 or mode == 5 or mode == 6
        keeps_gap = mode == 1 or mode == 5
        v_k = speed[k]
        pre_open = _pre_opening(known, gap, v_k, cfg) if cross_pred and not near_merge else math.nan
        if mode == 4:  # early: open early to the ramp vehicle ahead of the mainline predecessor
            ahead = np.empty(4)
            got = _virtual_gap(t, rx, int(inp[i, I_AHEAD]), int(inp[i, I_AHEAD_ROW]), d, length, slot_of, row_of,
                               trk_x, trk_t, stale_after, ahead)
            pre_open = _pre_opening(got, ahead, v_k, cfg)
        if road == ROAD_MAIN and not near_merge and math.isnan(pre_open):
            code[i] = OUT_RELEASE
            continue
        if near_merge:
            acc = _pymin(_pymax(target - v_k, cfg[C_A_MIN]), cfg[C_A_MAX])
        elif road == ROAD_MAIN:
            acc = pre_open
        else:
            acc = _merge_accel(-d, v_k, t, inp[i, I_T_CROSS], target, t3[i], cfg)
            if not math.isnan(pre_open):
                acc = _pymin(acc, pre_open)
        if near_merge and cross_pred:
            if not known:
                code[i] = OUT_FALLBACK
                continue
            if keeps_gap:
                g_m, v_lead, age = gap[0], _pymax(gap[1], 0.0), gap[2]
                out[i, 3] = g_m
                if age > period:  # safety_layer.worst_case_leader from the last heard state
                    b_lead = cfg[C_B_LEAD]
                    x_last = g_m - v_lead * age
                    t_stop = v_lead / b_lead
                    tw = _pymin(_pymax(age, 0.0), t_stop)
                    g_m, v_lead = x_last + v_lead * tw - 0.5 * b_lead * tw * tw, v_lead - b_lead * tw
                    v_lead = _pymax(v_lead, 0.0)
                a_gap = _pymax(_merge_gap_accel(g_m, v_k, v_lead, cfg), cfg[C_A_MIN])
                acc = _safe_accel(g_m, v_k, v_lead, _pymin(acc, a_gap), cfg)
        j = leader[k]
        if j >= 0:  # the physical leader's cap
            acc = _safe_accel(lane_pos[j] - length[j] - lane_pos[k], v_k, speed[j], acc, cfg)
        out[i, 0] = _pymin(_pymax(v_k + acc * period, 0.0), _pymax(cfg[C_V_MAX], v_k + cfg[C_A_DOWN]))
        code[i] = OUT_COMMAND_GAP if near_merge and cross_pred and keeps_gap else OUT_COMMAND
    return n_py
