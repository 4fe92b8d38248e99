"""A tick of ``v2x_wave_damping`` after sensing in one compiled call (issue 27, flow_merge's second CPU pass).

``WaveDamping._communicate`` and ``_decide`` do it in Python: the RSU's measurement, its broadcast's
copies (range, loss, delay, end-of-run and overflow drops), the delivery of the copies due, the newest
message per receiver, then per connected highway vehicle (rear first) the release, the fallback or the
FollowerStopper's speed capped by the safety layer.  :func:`wave_tick` does the same on rows with the
same values in the same order; the names, the membership (attach / detach), the draws, the commands
and the event log stay in Python.  It covers the plain law only: no courtesy stop, no gap creation,
Bernoulli loss, a road ahead of fewer than 8 cells (the caller checks; the rest keeps the Python path).

Bits: ``np.maximum(a, 0.0)``'s choice is the first operand when it is not smaller or NaN; Python's ``min``
/ ``max`` keep the first of equal (or NaN) values; a mean of fewer than 8 values is summed in order from
the first (``downstream_speed_floats``); Python's ``x ** 2`` on a float is the C library's ``pow`` (glibc's
``powf64``, which LLVM does not turn into ``x * x``: ``coord_kernel``); the copies are
``rsu_kernel.broadcast_copies``'.  The messages are kept as rows (their send order: ``msg_t``, the cells'
measured speeds ``msg_cells``), the copies in flight as flat arrays in send order, the newest message of
a receiver as its row (-1: none).  ``tests/controllers/test_ctrl_wave_kernel.py`` checks the controller's
compiled tick against the Python one on random drives, and the law's pieces against their Python.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from corridor.controllers.merging.coord_kernel import HAVE_C_POW, _c_pow
from corridor.controllers.merging.rsu_kernel import broadcast_copies

# cfg: the parameters, in this order
(C_CELL_BASE, C_CELL_M, C_X_RELEASE, C_STALE, C_HORIZON, C_U_MIN, C_U_MAX, C_FREE_ABOVE, C_A_MAX, C_B_COMFORT,
 C_PERIOD, C_DX0_1, C_DX0_2, C_DX0_3, C_D_1, C_D_2, C_D_3, C_TIME_GAP, C_REACTION, C_B_EGO, C_B_LEAD, C_S0,
 C_R2, C_P_LOSS, C_LATENCY, C_JITTER, C_T_LATE, N_CFG) = range(28)
# cnt: the channel's counters and the kernel's cursors
(K_N_PEND, K_SEQ, K_IN_FLIGHT, K_SENT, K_DELIVERED, K_LOST, K_OOR, K_LATE, K_OVERFLOW, K_MAX_IN_FLIGHT,
 N_CNT) = range(11)
ACT_RELEASE, ACT_STALE, ACT_COMMAND = 0, 1, 2  # past the release point; no fresh message; a speed command
T_EPS_S = 1e-9  # [s] the channel's delivery tolerance (corridor.channel._T_EPS_S)


def cfg_array(p: Any, safety: Any, cell_base: float, x_release: float, period: float, channel: Any,
              t_end_s: float) -> np.ndarray:
    """:func:`wave_tick`'s parameters: ``WaveDamping.Params`` ``p``, the deliverable ``safety`` params, the
    first cell's start [m], the release point [m], the tick's period [s], the ``ChannelConfig`` and the
    run's end [s] (inf: none)."""
    cfg = np.empty(N_CFG)
    cfg[C_CELL_BASE], cfg[C_CELL_M], cfg[C_X_RELEASE] = cell_base, p.cell_m, x_release
    cfg[C_STALE], cfg[C_HORIZON], cfg[C_U_MIN], cfg[C_U_MAX] = p.stale_after_s, p.horizon_m, p.u_min_mps, p.u_max_mps
    cfg[C_FREE_ABOVE] = math.nan if p.free_above_mps is None else p.free_above_mps
    cfg[C_A_MAX], cfg[C_B_COMFORT], cfg[C_PERIOD] = p.a_max_mps2, p.b_comfort_mps2, period
    (cfg[C_DX0_1], cfg[C_DX0_2], cfg[C_DX0_3]), (cfg[C_D_1], cfg[C_D_2], cfg[C_D_3]) = p.stopper.dx0_m, p.stopper.d_mps2
    cfg[C_TIME_GAP] = p.stopper.time_gap_s
    cfg[C_REACTION], cfg[C_B_EGO], cfg[C_B_LEAD], cfg[C_S0] = (safety.reaction_s, safety.b_ego_mps2, safety.b_lead_mps2,
                                                              safety.s0_m)
    cfg[C_R2], cfg[C_P_LOSS] = channel.range_m ** 2, float(channel.loss.p)
    cfg[C_LATENCY], cfg[C_JITTER], cfg[C_T_LATE] = channel.latency_s, channel.jitter_s, t_end_s + T_EPS_S
    return cfg


@njit(cache=True)
def safe_accel_c(gap_m: float, v_ego: float, v_lead: float, a_cmd: float, reaction_s: float, b_ego: float,
                 b_lead: float, s0_m: float) -> float:
    """``safety_layer.safe_accel`` (with ``safe_speed``), the same bits."""
    if math.isinf(gap_m):
        return a_cmd
    b = b_lead if b_lead < b_ego else b_ego  # Python's min(b_ego, b_lead)
    tau = reaction_s
    reach_m = gap_m - s0_m + _c_pow(v_lead, 2.0) / (2.0 * b_lead)
    disc = b * b * tau * tau / 4.0 + b * (2.0 * reach_m - v_ego * tau)
    if disc < 0.0:
        v1_max = -math.inf
    else:
        v1_max = -b * tau / 2.0 + math.sqrt(disc)
    if v1_max < 0.0:
        lo = -b_ego
        return lo if lo < a_cmd else a_cmd  # Python's min(a_cmd, -b_ego)
    a_safe = (v1_max - v_ego) / reaction_s
    lo = -b_ego
    a_safe = lo if lo > a_safe else a_safe  # Python's max(a_safe, -b_ego)
    return a_safe if a_safe < a_cmd else a_cmd  # Python's min(a_cmd, ...)


@njit(cache=True)
def follower_stopper_c(gap_m: float, v_mps: float, v_lead_mps: float, u_mps: float, cfg: np.ndarray) -> float:
    """``wave_damping.follower_stopper``, the same bits (its bands from ``cfg``)."""
    closing = v_lead_mps - v_mps
    closing = 0.0 if 0.0 < closing else closing  # Python's min(closing, 0.0)
    tg = cfg[C_TIME_GAP]
    dx1 = cfg[C_DX0_1] + closing * closing / (2.0 * cfg[C_D_1]) + tg * v_mps
    dx2 = cfg[C_DX0_2] + closing * closing / (2.0 * cfg[C_D_2]) + tg * v_mps
    dx3 = cfg[C_DX0_3] + closing * closing / (2.0 * cfg[C_D_3]) + tg * v_mps
    v_ = 0.0 if 0.0 > v_lead_mps else v_lead_mps  # Python's max(v_lead, 0.0)
    v_ = u_mps if u_mps < v_ else v_  # Python's min(v_, u)
    if gap_m <= dx1:
        return 0.0
    if gap_m <= dx2:
        return v_ * (gap_m - dx1) / (dx2 - dx1)
    if gap_m <= dx3:
        return v_ + (u_mps - v_) * (gap_m - dx2) / (dx3 - dx2)
    return u_mps


@njit(cache=True)
def law_speed(cfg: np.ndarray, cells_x: np.ndarray, cells: np.ndarray, x: float, v: float, gap: float,
              v_lead: float) -> float:
    """``WaveDamping._speed`` without courtesy stop and gap creation: the road ahead's speed from the
    message's cells (``cells``; free ones at u_max, NaN skipped), the FollowerStopper, the bounded
    change, the safety layer [m/s]."""
    free, u_max = cfg[C_FREE_ABOVE], cfg[C_U_MAX]
    hi = x + cfg[C_HORIZON]
    total, n = 0.0, 0
    for c in range(cells.shape[0]):
        cv = cells[c]
        if not math.isnan(free) and cv >= free:
            cv = u_max
        if math.isfinite(cv) and x < cells_x[c] and cells_x[c] <= hi:
            total = cv if n == 0 else total + cv
            n += 1
    u = total / n if n else u_max
    lo = cfg[C_U_MIN]
    u = lo if lo > u else u  # Python's max(u, u_min)
    u = u_max if u_max < u else u  # Python's min(u, u_max)
    v_cmd = follower_stopper_c(gap, v, v_lead, u, cfg) if math.isfinite(gap) else u
    period = cfg[C_PERIOD]
    a = (v_cmd - v) / period
    lo = -cfg[C_B_COMFORT]
    a = lo if lo > a else a
    a = cfg[C_A_MAX] if cfg[C_A_MAX] < a else a
    if math.isfinite(gap):
        a = safe_accel_c(gap, v, v_lead, a, cfg[C_REACTION], cfg[C_B_EGO], cfg[C_B_LEAD], cfg[C_S0])
    w = v + a * period
    return w if w > 0.0 else 0.0  # Python's max(0.0, w)


_RF, _RB = types.Array(types.float64, 1, "A", readonly=True), types.Array(types.bool_, 1, "A", readonly=True)
_RF2, _RI = types.Array(types.float64, 2, "A", readonly=True), types.Array(types.int64, 1, "A", readonly=True)
# u and src go on to rsu_kernel.broadcast_copies, whose signature has writable arrays
_SIG = types.int64(types.float64, _RF, _RF, _RF, _RF, _RF, _RB, _RB, _RB, _RF2, types.boolean, types.boolean, _RF, _RF,
                   _RI, _RI,
                   types.float64[:], types.float64[:], _RB, types.int64[:], types.float64[:], types.float64[:, :], types.int64[:], types.float64[:],
                   types.int64[:], types.int64[:], types.int64[:], types.int64[:], types.float64[:])


@njit(cache=True)
def tick(t: float, cfg: np.ndarray, cells_x: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray,
         on_ramp: np.ndarray, ramp: np.ndarray, connected: np.ndarray, pos: np.ndarray, send: bool,
         measure: bool, noise: np.ndarray, cells_in: np.ndarray, member_rows: np.ndarray, member_nodes: np.ndarray,
         u: np.ndarray, src: np.ndarray, attached: np.ndarray, latest: np.ndarray, msg_t: np.ndarray,
         msg_cells: np.ndarray, pend_node: np.ndarray, pend_t: np.ndarray, pend_msg: np.ndarray, cnt: np.ndarray,
         out_row: np.ndarray, out_act: np.ndarray, out_v: np.ndarray) -> int:
    """The RSU's broadcast (``send``: its measurement from ``noise``, or ``cells_in`` when not ``measure``:
    the caller measured, and its copies to ``member_rows`` at
    nodes ``member_nodes`` from the channel's uniforms ``u``), the delivery of the copies due to the
    ``attached`` nodes and the newest message per node (``latest``), then per connected highway vehicle
    rear first: ``out_row``, ``out_act`` (``ACT_*``) and ``out_v`` (the command [m/s]).  Returns how many.
    The caller makes room: ``msg_t`` / ``msg_cells`` for one more message, the copies' arrays for
    ``len(member_rows)`` more."""
    n, m = front.shape[0], member_rows.shape[0]
    if send and m > 0:  # the measurement (WaveDamping._measure: rsu_kernel.road_ahead's cells) and its copies
        q = cnt[K_SEQ]
        n_cells = msg_cells.shape[1]
        if not measure:
            noise = np.zeros(0)  # nothing measured here: the cells are the caller's
            for c in range(n_cells):
                msg_cells[q, c] = cells_in[c]
        total = np.zeros(n_cells)
        count = np.zeros(n_cells, dtype=np.int64)
        base, cell_m = cfg[C_CELL_BASE], cfg[C_CELL_M]
        for i in range(n if measure else 0):
            if not on_ramp[i]:
                vi = speed[i] + noise[i]
                vi = vi if (vi >= 0.0 or math.isnan(vi)) else 0.0
                k = np.int64(math.floor((front[i] - base) / cell_m))
                if k >= 0 and k < n_cells:
                    total[k] += vi
                    count[k] += 1
        for c in range(n_cells if measure else 0):
            msg_cells[q, c] = total[c] / count[c] if count[c] > 0 else np.nan
        msg_t[q] = t
        perm = np.argsort(member_nodes, kind="mergesort")
        pos_m = np.empty((m, 3))
        for i in range(m):
            pos_m[i, 0], pos_m[i, 1], pos_m[i, 2] = pos[member_rows[i], 0], pos[member_rows[i], 1], pos[member_rows[i], 2]
        keep, t_recv, counts = np.empty(m, dtype=np.bool_), np.empty(m), np.empty(4, dtype=np.int64)
        broadcast_copies(pos_m, perm, src, cfg[C_R2], u, cfg[C_P_LOSS], t + cfg[C_LATENCY], cfg[C_JITTER],
                         cfg[C_T_LATE], keep, t_recv, counts)
        cnt[K_SENT] += m
        cnt[K_OOR] += m - counts[0]
        cnt[K_LOST] += counts[1]
        cnt[K_LATE] += counts[2]
        k_keep = counts[3]
        room = cnt[K_MAX_IN_FLIGHT] - cnt[K_IN_FLIGHT]
        room = room if room > 0 else 0
        kept = 0
        p = cnt[K_N_PEND]
        for i in range(m):
            if keep[i]:
                if kept >= room:  # the newest beyond max_in_flight are dropped
                    cnt[K_OVERFLOW] += 1
                    continue
                pend_node[p], pend_t[p], pend_msg[p] = member_nodes[perm[i]], t_recv[i], q
                p += 1
                kept += 1
        cnt[K_N_PEND] = p
        cnt[K_IN_FLIGHT] += k_keep if k_keep < room else room
        cnt[K_SEQ] = q + 1
    # delivery (RsuBroadcast.deliver, newest_per_receiver): the copies due to attached nodes, in send order
    p_all = cnt[K_N_PEND]
    if p_all == 0:
        cnt[K_IN_FLIGHT] = 0
    else:
        t_due = t + T_EPS_S
        best_t = np.full(attached.shape[0], -math.inf)
        best_q = np.full(attached.shape[0], -1, dtype=np.int64)
        p = 0
        for i in range(p_all):
            nd = pend_node[i]
            if not attached[nd]:
                continue  # detached: discarded
            if pend_t[i] <= t_due:
                cnt[K_DELIVERED] += 1
                if best_q[nd] < 0 or pend_t[i] >= best_t[nd]:  # the latest delivery, the later sent on a tie
                    best_t[nd], best_q[nd] = pend_t[i], pend_msg[i]
            else:
                pend_node[p], pend_t[p], pend_msg[p] = nd, pend_t[i], pend_msg[i]
                p += 1
        cnt[K_N_PEND] = p
        cnt[K_IN_FLIGHT] = p
        for nd in range(attached.shape[0]):
            if best_q[nd] >= 0:
                latest[nd] = best_q[nd]
    # decide (WaveDamping._decide): the highway line rear first, its connected non-ramp vehicles
    node_of = np.full(n, -1, dtype=np.int64)
    for i in range(m):
        node_of[member_rows[i]] = member_nodes[i]
    n_line = 0
    for i in range(n):
        if not on_ramp[i]:
            n_line += 1
    line = np.empty(n_line, dtype=np.int64)
    n_line = 0
    for i in range(n):
        if not on_ramp[i]:
            line[n_line] = i
            n_line += 1
    order = line[np.argsort(front[line], kind="mergesort")]
    n_out = 0
    stale, x_release = cfg[C_STALE], cfg[C_X_RELEASE]
    for j in range(n_line):
        k = order[j]
        if not connected[k] or ramp[k]:
            continue
        out_row[n_out] = k
        if front[k] >= x_release:
            out_act[n_out] = ACT_RELEASE
            n_out += 1
            continue
        nd = node_of[k]
        q = latest[nd] if nd >= 0 else -1
        if q < 0 or t - msg_t[q] > stale:
            out_act[n_out] = ACT_STALE
            n_out += 1
            continue
        if j + 1 < n_line:
            lead = order[j + 1]
            gap = front[lead] - length[lead] - front[k]
            v_lead = speed[lead]
        else:
            gap, v_lead = math.inf, cfg[C_U_MAX]
        out_act[n_out] = ACT_COMMAND
        out_v[n_out] = law_speed(cfg, cells_x, msg_cells[q], front[k], speed[k], gap, v_lead)
        n_out += 1
    return n_out


@(njit(_SIG, cache=True) if HAVE_C_POW else njit(cache=True))
def wave_tick(t: float, cfg: np.ndarray, cells_x: np.ndarray, front: np.ndarray, speed: np.ndarray, length: np.ndarray,
              on_ramp: np.ndarray, ramp: np.ndarray, connected: np.ndarray, pos: np.ndarray, send: bool,
              measure: bool, noise: np.ndarray, cells_in: np.ndarray, member_rows: np.ndarray, member_nodes: np.ndarray, u: np.ndarray, src: np.ndarray,
              attached: np.ndarray, latest: np.ndarray, msg_t: np.ndarray, msg_cells: np.ndarray,
              pend_node: np.ndarray, pend_t: np.ndarray, pend_msg: np.ndarray, cnt: np.ndarray, out_row: np.ndarray,
              out_act: np.ndarray, out_v: np.ndarray) -> int:
    """:func:`tick` (the compiled entry point)."""
    return tick(t, cfg, cells_x, front, speed, length, on_ramp, ramp, connected, pos, send, measure, noise, cells_in,
                member_rows, member_nodes, u, src, attached, latest, msg_t, msg_cells, pend_node, pend_t, pend_msg, cnt,
                out_row, out_act, out_v)


__all__ = ["ACT_COMMAND", "ACT_RELEASE", "ACT_STALE", "HAVE_C_POW", "cfg_array", "follower_stopper_c", "law_speed",
           "safe_accel_c", "tick", "wave_tick"]
