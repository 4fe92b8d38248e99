"""The V2X merging controller's CAM stage of a tick in one compiled call (issue 27, the seventh CPU pass).

``V2XMerging._communicate`` did it in Python on vehicle names: the zone masks, the senders' positions
handed to the channel, the CAM schedule (``traffic.v2x.CamGenerator.due`` over ~25 senders), the listen
pairs and each CAM's receivers built from the crossing order, the send arrays.  Here the same, over node
indices (the channel's), with the same values and the same order:

- *senders* (``near``): connected rows with ``near_lo < d < near_hi`` (d: distance to the conflict point);
  *listeners* (``in_zone``): connected rows with ``zone_lo < d <= zone_hi``;
- the channel's known positions: the roadside unit and the senders (``AddressedChannel.set_positions``);
- the CAM schedule per sender node, ``CamGenerator.due``'s arithmetic (due when ``t + 1e-9 >= next``; the
  next slot on the period grid, skipping missed slots);
- per vehicle of the crossing order that is a receiver, the senders it listens to (the ``depth`` vehicles
  ahead of it in the order, and with ``fifo`` every sender on a conflicting lane not ordered yet, the
  *newcomers*) as sorted ``receiver << 32 | sender`` keys (``NodeTrackPool.fuse_delivered``);
- per due CAM (row order): the roadside unit, then the receivers that listen to its sender, in the order.

What needs a name or a random draw is left to the caller: the kernel changes nothing and returns a
status > 0 when a listener must be attached or detached (``STATUS_LISTENERS``), a sender has no node yet
(``STATUS_NODES``) or a sender has no schedule yet (``STATUS_PHASE``, a phase drawn per new sender, in row
order); the caller does that in Python, in the order the Python stage did it, and calls again.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

STATUS_OK, STATUS_LISTENERS, STATUS_NODES, STATUS_PHASE = 0, 1, 2, 3
DUE_EPS_S = 1e-9  # [s] traffic.v2x's tolerance of the period comparison

@njit("f8(f8[:], i8, i8)", cache=True)
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of ``a[lo:lo + n]`` (a float64 array's ``sum``: 0.0 + its pairwise summation, eight
    accumulators in blocks of up to 128, halved above), the same bits."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    if n <= 128:
        r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
        r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
        i = 8
        while i < n - (n % 8):
            j = lo + i
            r0 += a[j]
            r1 += a[j + 1]
            r2 += a[j + 2]
            r3 += a[j + 3]
            r4 += a[j + 4]
            r5 += a[j + 5]
            r6 += a[j + 6]
            r7 += a[j + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[lo + i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return pairwise_sum(a, lo, n2) + pairwise_sum(a, lo + n2, n - n2)


_RO_I8, _RO_F8 = types.Array(types.int64, 1, "A", readonly=True), types.Array(types.float64, 1, "A", readonly=True)


@njit(types.void(_RO_I8, _RO_F8, types.int64[:]), cache=True)  # read-only: the road frame's (a writable converts)
def lane_leaders_into(lane: np.ndarray, lane_pos: np.ndarray, out: np.ndarray) -> None:
    """``safety_layer.lane_leaders`` written to ``out[:n]``: per row the next row ahead on its lane (-1: none),
    the successor in ``np.lexsort((lane_pos, lane))`` (by lane, then position, then row: two stable sorts)."""
    n = lane.shape[0]
    order = np.argsort(lane_pos, kind="mergesort")
    order = order[np.argsort(lane[order], kind="mergesort")]
    out[:n] = -1
    for i in range(n - 1):
        if lane[order[i]] == lane[order[i + 1]]:
            out[order[i]] = order[i + 1]


def lane_leaders(lane: np.ndarray, lane_pos: np.ndarray) -> np.ndarray:
    """``lane_leaders_into`` as a new array."""
    out = np.empty(len(lane), dtype=np.int64)
    lane_leaders_into(lane, lane_pos, out)
    return out


@njit("i8(i8[:], i8)", cache=True)
def _order_pos(order_node: np.ndarray, node: int) -> int:
    """The position of ``node`` in the crossing order (-1: not ordered)."""
    for p in range(order_node.shape[0]):
        if order_node[p] == node:
            return p
    return -1


def _signature() -> Any:
    i8, f8, b1 = types.int64, types.float64, types.boolean
    vi, vf, vb, mf = types.int64[:], types.float64[:], types.boolean[:], types.float64[:, :]
    pos = types.Array(f8, 2, "A", readonly=True)  # the snapshot's positions are read-only (a writable array converts)
    return types.Tuple((i8, i8, i8, i8, i8, i8, i8, f8, i8))(
        f8, vf, vb, pos, vf, vb, vb, vb, vi,  # t, the rows
        f8, f8, f8, f8, f8, f8,  # near_lo, near_hi, zone_lo, zone_hi, stream_lo, stream_hi
        vi, i8, vf, f8,  # slot_of, n_vehicle_rx, next_s, period
        vb, mf, i8, f8, f8,  # known, chan_pos, rsu, x_rsu, y_rsu
        vi, i8, b1, i8,  # order_node, depth, fifo, r0
        _RO_I8, _RO_F8,  # lane, lane_pos (the road frame's, read-only)
        vi, vi, mf, mf, vi, vi, vi, vi, vi, vi, vf, vi, vi)  # the buffers (see cam_stage_into)


@njit(_signature(), cache=True)
def cam_stage_into(t: float, dist: np.ndarray, connected: np.ndarray, pos: np.ndarray, speed: np.ndarray,
                   ramp: np.ndarray, right: np.ndarray, merged: np.ndarray, row_node: np.ndarray,
                   near_lo: float, near_hi: float, zone_lo: float, zone_hi: float, stream_lo: float,
                   stream_hi: float, slot_of: np.ndarray, n_vehicle_rx: int, next_s: np.ndarray, period: float,
                   known: np.ndarray, chan_pos: np.ndarray, rsu: int, x_rsu: float, y_rsu: float,
                   order_node: np.ndarray, depth: int, fifo: bool, r0: int, lane: np.ndarray, lane_pos: np.ndarray,
                   near: np.ndarray, src: np.ndarray, cam_pos: np.ndarray, val: np.ndarray, ref: np.ndarray,
                   ptr: np.ndarray, dst: np.ndarray, keys: np.ndarray, cand: np.ndarray, leader: np.ndarray,
                   sp: np.ndarray, due: np.ndarray, newcomers: np.ndarray
                   ) -> tuple[int, int, int, int, int, int, int, float, int]:
    """The tick's CAM stage (see the module docstring), written to the caller's buffers (``CamStage``: no
    array is allocated and boxed per call).  Rows: ``dist`` [m], ``connected``, ``pos`` (n, 2|3) [m],
    ``speed`` [m/s], the lane flags ``ramp`` / ``right`` / ``merged``, ``row_node`` (-1: no node).
    ``slot_of``: node -> track slot (-1: not a receiver), ``n_vehicle_rx`` the receivers but the roadside
    unit; ``next_s``: node -> next CAM time [s] (NaN: none yet), advanced in place; ``known`` / ``chan_pos``:
    the channel's node positions, set in place; ``order_node``: the crossing order's nodes (-1: no node).

    Writes the senders' rows (``near``); the tick's sends as ``AddressedChannel.send`` takes them: the
    senders' nodes (``src``), positions (``cam_pos``, [m]), contents (``val``; a CAM: [position on the merge
    axis [m], speed [m/s]]), references (``ref``), ``ptr`` into the receiver nodes ``dst``, with room after
    the due CAMs for the assignments (see below); the sorted listen ``keys``; the rows the roadside unit
    coordinates (``cand``: ``0 < d <= zone_hi`` on a conflicting lane: ``ramp`` or ``right``, not
    ``merged``); each row's lane leader (``leader``, ``lane_leaders``). The room: one entry per connected
    coordinated row, from the roadside unit at (``x_rsu``, ``y_rsu``, 0) with a zero content, the
    references ``r0``, ``r0 + 1``, ... and one receiver each (``ptr`` counts on by one; the caller writes
    the receivers and sends the first ones it uses).

    Returns (status, senders, due CAMs, entries (CAMs and room), the CAMs' receivers, listen keys,
    coordinated rows, the sum of the speeds of the mainline rows (``ramp`` false) with ``stream_lo < d <
    stream_hi`` and their count (the crossing speed: their mean, as ``np.mean``: ``sum / n``, the sum
    ``pairwise_sum``)). With a status > 0 the counts are 0 and nothing was changed."""
    n = dist.shape[0]
    n_slot, n_next = slot_of.shape[0], next_s.shape[0]
    n_near = 0
    n_heard = 0
    for k in range(n):
        if not connected[k]:
            continue
        d = dist[k]
        node = row_node[k]
        if d <= zone_hi and d > zone_lo:  # a listener: must be a receiver already
            if node < 0 or node >= n_slot or slot_of[node] < 0:
                return STATUS_LISTENERS, 0, 0, 0, 0, 0, 0, 0.0, 0
            n_heard += 1
        if d < near_hi and d > near_lo:
            near[n_near] = k
            n_near += 1
    if n_heard != n_vehicle_rx:  # a receiver left the zone (or the scenario)
        return STATUS_LISTENERS, 0, 0, 0, 0, 0, 0, 0.0, 0
    for i in range(n_near):
        if row_node[near[i]] < 0:
            return STATUS_NODES, 0, 0, 0, 0, 0, 0, 0.0, 0
    for i in range(n_near):
        node = row_node[near[i]]
        if node >= n_next or math.isnan(next_s[node]):
            return STATUS_PHASE, 0, 0, 0, 0, 0, 0, 0.0, 0
    # the channel's positions: the roadside unit, then the senders (2-D positions: z = 0)
    known[:] = False
    known[rsu] = True
    chan_pos[rsu, 0], chan_pos[rsu, 1], chan_pos[rsu, 2] = x_rsu, y_rsu, 0.0
    n_col = pos.shape[1]
    for i in range(n_near):
        k = near[i]
        node = row_node[k]
        known[node] = True
        for c in range(3):
            chan_pos[node, c] = pos[k, c] if c < n_col else 0.0
    # the CAM schedule (CamGenerator.due, per sender in row order)
    n_due = 0
    for i in range(n_near):
        k = near[i]
        node = row_node[k]
        nxt = next_s[node]
        if t + DUE_EPS_S >= nxt:
            due[n_due] = k
            n_due += 1
            n_missed = math.floor((t + DUE_EPS_S - nxt) / period)
            next_s[node] = nxt + (n_missed + 1.0) * period
    n_order = order_node.shape[0]
    # fifo's newcomers: senders on a conflicting lane that are not ordered yet (row order)
    n_new = 0
    if fifo:
        for i in range(n_near):
            k = near[i]
            if (ramp[k] or right[k]) and not merged[k] and _order_pos(order_node, row_node[k]) < 0:
                newcomers[n_new] = row_node[k]
                n_new += 1
    # the listen keys: each ordered receiver listens to the vehicles ahead of it, and to the newcomers
    n_keys = 0
    for p in range(n_order):
        node = order_node[p]
        if node < 0 or node >= n_slot or slot_of[node] < 0:
            continue
        rx = node << 32
        for j in range(max(0, p - depth), p):
            if order_node[j] >= 0:
                keys[n_keys] = rx | order_node[j]
                n_keys += 1
        for j in range(n_new):
            keys[n_keys] = rx | newcomers[j]
            n_keys += 1
    keys[:n_keys].sort()
    # the zone's rows on a conflicting lane (the coordinator's candidates), in row order; the connected
    # ones are the most assignments the roadside unit sends in this tick
    n_c = n_a = 0
    for k in range(n):
        if dist[k] > 0.0 and dist[k] <= zone_hi and (ramp[k] or right[k]) and not merged[k]:
            cand[n_c] = k
            n_c += 1
            n_a += connected[k]
    # the sends: the due CAMs (sender, position, content, receivers: the roadside unit, then its listeners
    # in order), then room for n_a assignments (from the roadside unit's position, no content, the
    # references r0, r0 + 1, ..., one receiver each: filled by the caller)
    n_e = n_due + n_a
    ptr[0] = 0
    m = 0
    for e in range(n_due):
        k = due[e]
        node = row_node[k]
        src[e] = node
        cam_pos[e, 0], cam_pos[e, 1], cam_pos[e, 2] = pos[k, 0], pos[k, 1], 0.0
        val[e, 0], val[e, 1] = -dist[k], speed[k]
        ref[e] = -1
        dst[m] = rsu
        m += 1
        ps = _order_pos(order_node, node)
        newcomer = False
        if ps < 0:
            for j in range(n_new):
                if newcomers[j] == node:
                    newcomer = True
                    break
        if ps >= 0:
            for p in range(ps + 1, min(ps + depth + 1, n_order)):
                f = order_node[p]
                if f >= 0 and f < n_slot and slot_of[f] >= 0:
                    dst[m] = f
                    m += 1
        elif newcomer:
            for p in range(n_order):
                f = order_node[p]
                if f >= 0 and f < n_slot and slot_of[f] >= 0:
                    dst[m] = f
                    m += 1
        ptr[e + 1] = m
    for e in range(n_due, n_e):
        src[e] = rsu
        cam_pos[e, 0], cam_pos[e, 1], cam_pos[e, 2] = x_rsu, y_rsu, 0.0
        val[e, 0], val[e, 1] = 0.0, 0.0
        ref[e] = r0 + e - n_due
        ptr[e + 1] = ptr[e] + 1
    # the crossing speed's rows (upstream mainline), in row order, and numpy's sum of their speeds
    n_s = 0
    for k in range(n):
        if not ramp[k] and dist[k] > stream_lo and dist[k] < stream_hi:
            sp[n_s] = speed[k]
            n_s += 1
    lane_leaders_into(lane, lane_pos, leader)
    return STATUS_OK, n_near, n_due, n_e, m, n_keys, n_c, pairwise_sum(sp, 0, n_s), n_s


_RO_B1 = types.Array(types.boolean, 1, "A", readonly=True)
_DERIVE_SIG = types.void(types.float64[:], types.Array(types.int8, 1, "A", readonly=True), _RO_I8, _RO_B1, _RO_I8, _RO_B1,
                         _RO_B1, _RO_B1, types.int64, types.float64, types.float64, types.float64[:], types.boolean[:],
                         types.boolean[:], types.boolean[:], types.boolean[:])


@njit(_DERIVE_SIG, cache=True)
def derive_rows(front_x: np.ndarray, role: np.ndarray, uid: np.ndarray, conn_of: np.ndarray, lane: np.ndarray,
                on_ramp_lane: np.ndarray, joins_lane: np.ndarray, merged_lane: np.ndarray, ramp_code: int,
                x_merge: float, cos_ramp: float, dist: np.ndarray, connected: np.ndarray, ramp: np.ndarray,
                right: np.ndarray, merged: np.ndarray) -> None:
    """``V2XMerging._sense``'s per-row facts from the rows' front-bumper x [m] (``front_x``), their uids and
    lane codes, written to ``dist`` (to the conflict point at ``x_merge``, along the ramp on a ramp lane:
    divided by ``cos_ramp``), ``connected``, ``ramp`` (role ``ramp_code``), ``right`` (a lane ramp vehicles
    join) and ``merged`` (a ramp vehicle on a mainline lane past the nose), as its numpy lines did."""
    for k in range(front_x.shape[0]):
        u, ln = uid[k], lane[k]
        is_ramp = role[u] == ramp_code
        ramp[k] = is_ramp
        merged[k] = is_ramp and merged_lane[ln]
        right[k] = joins_lane[ln]
        connected[k] = conn_of[u]
        d = x_merge - front_x[k]
        if is_ramp and on_ramp_lane[ln]:
            d = d / cos_ramp
        dist[k] = d


def _tick_signature() -> Any:
    i8, f8, b1 = types.int64, types.float64, types.boolean
    vi, vf, vb, mf = types.int64[:], types.float64[:], types.boolean[:], types.float64[:, :]
    pos = types.Array(f8, 2, "A", readonly=True)
    return types.Tuple((i8, i8, i8, i8, i8, i8, i8, f8, i8))(
        f8, vf, types.Array(types.int8, 1, "A", readonly=True), _RO_I8, _RO_B1, _RO_B1, _RO_B1, _RO_B1, i8, f8,  # rows
        vf, vb, vb, vb, vb,  # the derived rows' buffers
        pos, vf, vi,  # pos, speed, row_node
        f8, f8, f8, f8, f8, f8,
        vi, i8, vf, f8,
        vb, mf, i8, f8, f8,
        vi, i8, b1, i8,
        _RO_I8, _RO_F8,
        vi, vi, mf, mf, vi, vi, vi, vi, vi, vi, vf, vi, vi)


@njit(_tick_signature(), cache=True)
def cam_tick_into(t: float, front_x: np.ndarray, role: np.ndarray, uid: np.ndarray, conn_of: np.ndarray,
                  on_ramp_lane: np.ndarray, joins_lane: np.ndarray, merged_lane: np.ndarray, ramp_code: int,
                  cos_ramp: float, dist: np.ndarray, connected: np.ndarray, ramp: np.ndarray, right: np.ndarray,
                  merged: np.ndarray, pos: np.ndarray, speed: np.ndarray, row_node: np.ndarray, near_lo: float,
                  near_hi: float, zone_lo: float, zone_hi: float, stream_lo: float, stream_hi: float,
                  slot_of: np.ndarray, n_vehicle_rx: int, next_s: np.ndarray, period: float, known: np.ndarray,
                  chan_pos: np.ndarray, rsu: int, x_rsu: float, y_rsu: float, order_node: np.ndarray, depth: int,
                  fifo: bool, r0: int, lane: np.ndarray, lane_pos: np.ndarray, near: np.ndarray, src: np.ndarray,
                  cam_pos: np.ndarray, val: np.ndarray, ref: np.ndarray, ptr: np.ndarray, dst: np.ndarray,
                  keys: np.ndarray, cand: np.ndarray, leader: np.ndarray, sp: np.ndarray, due: np.ndarray,
                  newcomers: np.ndarray) -> tuple[int, int, int, int, int, int, int, float, int]:
    """:func:`derive_rows` (the conflict point at ``x_rsu``) and :func:`cam_stage_into` on its rows, in one call."""
    n = front_x.shape[0]
    derive_rows(front_x, role, uid, conn_of, lane, on_ramp_lane, joins_lane, merged_lane, ramp_code, x_rsu,
                cos_ramp, dist, connected, ramp, right, merged)
    return cam_stage_into(t, dist[:n], connected[:n], pos, speed, ramp[:n], right[:n], merged[:n], row_node, near_lo,
                          near_hi, zone_lo, zone_hi, stream_lo, stream_hi, slot_of, n_vehicle_rx, next_s, period,
                          known, chan_pos, rsu, x_rsu, y_rsu, order_node, depth, fifo, r0, lane, lane_pos, near, src,
                          cam_pos, val, ref, ptr, dst, keys, cand, leader, sp, due, newcomers)


_RO_F8_2 = types.Array(types.float64, 2, "A", readonly=True)


def _pose_tick_signature() -> Any:
    sig = _tick_signature()
    args = list(sig.args)
    # front_x (1) and pos (15) give way to the raw poses (ref_xy, back, cos, sin, size) and two buffers
    rest = args[2:15] + args[16:]
    return sig.return_type(args[0], _RO_F8_2, _RO_F8_2, types.float64[:], types.float64[:], _RO_F8_2,
                           types.float64[:], types.float64[:, :], *rest)


@njit(types.void(_RO_F8_2, _RO_F8_2, types.float64[:], types.float64[:], _RO_F8_2, types.float64[:],
                 types.float64[:, :]), cache=True)
def front_and_centre(ref_xy: np.ndarray, back: np.ndarray, cos_yaw: np.ndarray, sin_yaw: np.ndarray,
                     size: np.ndarray, front_x: np.ndarray, pos: np.ndarray) -> None:
    """The rows' centre (``corridor.poses.planar_geometry``: the reference point ``ref_xy`` (n, 2) [m] less
    ``back`` (n, 1) [m] along the yaw whose cosine and sine are given, numpy's) written to ``pos[:n, :2]``,
    and ``V2XMerging._sense``'s front-bumper x (the centre's x plus half the length ``size[:, 0]`` along the
    yaw) to ``front_x[:n]``, with the same operations in the same order (the same bits)."""
    for k in range(ref_xy.shape[0]):
        c = cos_yaw[k]
        b = back[k, 0]
        x = ref_xy[k, 0] - b * c
        pos[k, 0] = x
        pos[k, 1] = ref_xy[k, 1] - b * sin_yaw[k]
        front_x[k] = x + 0.5 * size[k, 0] * c


@njit(_pose_tick_signature(), cache=True)
def cam_pose_tick_into(t: float, ref_xy: np.ndarray, back: np.ndarray, cos_yaw: np.ndarray, sin_yaw: np.ndarray,
                       size: np.ndarray, front_x: np.ndarray, pos: np.ndarray, role: np.ndarray, uid: np.ndarray,
                       conn_of: np.ndarray, on_ramp_lane: np.ndarray, joins_lane: np.ndarray,
                       merged_lane: np.ndarray, ramp_code: int, cos_ramp: float, dist: np.ndarray,
                       connected: np.ndarray, ramp: np.ndarray, right: np.ndarray, merged: np.ndarray,
                       speed: np.ndarray, row_node: np.ndarray, near_lo: float, near_hi: float, zone_lo: float,
                       zone_hi: float, stream_lo: float, stream_hi: float, slot_of: np.ndarray, n_vehicle_rx: int,
                       next_s: np.ndarray, period: float, known: np.ndarray, chan_pos: np.ndarray, rsu: int,
                       x_rsu: float, y_rsu: float, order_node: np.ndarray, depth: int, fifo: bool, r0: int,
                       lane: np.ndarray, lane_pos: np.ndarray, near: np.ndarray, src: np.ndarray,
                       cam_pos: np.ndarray, val: np.ndarray, ref: np.ndarray, ptr: np.ndarray, dst: np.ndarray,
                       keys: np.ndarray, cand: np.ndarray, leader: np.ndarray, sp: np.ndarray, due: np.ndarray,
                       newcomers: np.ndarray) -> tuple[int, int, int, int, int, int, int, float, int]:
    """:func:`front_and_centre` from the raw poses (the snapshot's geometry is not derived: the yaw's cosine
    and sine come from numpy), then :func:`cam_tick_into` on its front x and centres, in one call."""
    n = ref_xy.shape[0]
    front_and_centre(ref_xy, back, cos_yaw, sin_yaw, size, front_x, pos)
    return cam_tick_into(t, front_x[:n], role, uid, conn_of, on_ramp_lane, joins_lane, merged_lane, ramp_code,
                         cos_ramp, dist, connected, ramp, right, merged, pos[:n], speed, row_node, near_lo, near_hi,
                         zone_lo, zone_hi, stream_lo, stream_hi, slot_of, n_vehicle_rx, next_s, period, known,
                         chan_pos, rsu, x_rsu, y_rsu, order_node, depth, fifo, r0, lane, lane_pos, near, src, cam_pos,
                         val, ref, ptr, dst, keys, cand, leader, sp, due, newcomers)


class CamStage:
    """``cam_stage_into`` with its buffers (grown as needed): a call returns (status, the senders' rows, the
    sends' nodes, positions, contents, ptr, receivers (the buffer: the room's receivers after the CAMs'),
    the listen keys, the crossing speed's sum and count, the coordinated rows, the due CAMs, their
    receivers, the references, the lane leaders), views valid until the next call."""

    def __init__(self) -> None:
        self._n = self._n_dst = self._n_keys = -1
        self.dist = np.empty(0)
        self._grow(64, 256, 256)

    def _grow(self, n: int, n_dst: int, n_keys: int) -> None:
        if n > self._n:
            self._n = n
            self.near, self.src, self.ref, self.ptr = (np.empty(n, dtype=np.int64), np.empty(2 * n, dtype=np.int64),
                                                       np.empty(2 * n, dtype=np.int64), np.empty(2 * n + 1, dtype=np.int64))
            self.pos, self.val = np.empty((2 * n, 3)), np.empty((2 * n, 2))
            self.cand, self.leader, self.sp = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n)
            self.due, self.newcomers = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        if n_dst > self._n_dst:
            self._n_dst, self.dst = n_dst, np.empty(n_dst, dtype=np.int64)
        if n_keys > self._n_keys:
            self._n_keys, self.keys = n_keys, np.empty(n_keys, dtype=np.int64)
        if n > len(self.dist):
            self.dist, self.front_x, self.centre = np.empty(n), np.empty(n), np.empty((n, 2))
            self.connected, self.ramp, self.right, self.merged = (np.empty(n, dtype=bool) for _ in range(4))

    def __call__(self, t: float, dist: np.ndarray, *args: Any) -> tuple[Any, ...]:
        """``cam_stage_into`` on the rows' ``dist``, ``connected``, ``pos``, ... (its arguments up to ``lane_pos``)."""
        self._room(dist.shape[0], args[22].shape[0], args[23])
        out = cam_stage_into(t, dist, *args, *self._buffers())
        return self._views(dist.shape[0], out)

    def tick(self, t: float, front_x: np.ndarray, raw: tuple[Any, ...], *args: Any) -> tuple[Any, ...]:
        """``cam_tick_into``: the rows derived from ``front_x`` and ``raw`` (``derive_rows``' role, uid,
        connected-by-uid, the three lane tables, the ramp's role code and its cosine), then the stage on
        them (``pos``, ``speed``, ``row_node``, the bounds, ... as ``__call__`` takes them after ``merged``).
        Returns ``__call__``'s tuple, then the derived dist, connected, ramp, right and merged (views)."""
        n = front_x.shape[0]
        self._room(n, args[18].shape[0], args[19])
        out = cam_tick_into(t, front_x, *raw, self.dist, self.connected, self.ramp, self.right, self.merged, *args,
                            *self._buffers())
        return (*self._views(n, out), self.dist[:n], self.connected[:n], self.ramp[:n], self.right[:n],
                self.merged[:n])

    def pose_tick(self, t: float, poses: tuple[np.ndarray, ...], raw: tuple[Any, ...], *args: Any) -> tuple[Any, ...]:
        """``cam_pose_tick_into``: ``tick`` with the rows' front x and centres derived from ``poses`` (the
        reference points, the distances back to the centre, the yaw's cosine and sine, the sizes) instead of
        given (``args`` as ``tick`` takes them after ``pos``). Returns ``tick``'s tuple, then the centres (n, 2)."""
        return self.pose_views(poses[0].shape[0], cam_pose_tick_into(*self.pose_args(t, poses, raw, *args)))

    def pose_args(self, t: float, poses: tuple[np.ndarray, ...], raw: tuple[Any, ...], *args: Any) -> tuple[Any, ...]:
        """``cam_pose_tick_into``'s arguments for ``pose_tick`` (the buffers grown first; for a caller that makes
        the call itself, then reads ``pose_views``)."""
        n = poses[0].shape[0]
        self._room(n, args[17].shape[0], args[18])
        if self.front_x.shape[0] < n:
            self.front_x, self.centre = np.empty(len(self.dist)), np.empty((len(self.dist), 2))
        return (t, *poses, self.front_x, self.centre, *raw, self.dist, self.connected, self.ramp, self.right,
                self.merged, *args, *self._buffers())

    def pose_views(self, n: int, out: tuple[Any, ...]) -> tuple[Any, ...]:
        """``pose_tick``'s tuple from ``cam_pose_tick_into``'s counts ``out`` on ``n`` rows."""
        return (*self._views(n, out), self.dist[:n], self.connected[:n], self.ramp[:n], self.right[:n],
                self.merged[:n], self.centre[:n])

    def _room(self, n: int, n_order: int, depth: int) -> None:
        need_dst, need_keys = n * (1 + n_order) + n, n_order * (depth + n)
        if n > self._n or need_dst > self._n_dst or need_keys > self._n_keys:
            self._grow(max(n, 2 * self._n), max(need_dst, 2 * self._n_dst), max(need_keys, 2 * self._n_keys))

    def _buffers(self) -> tuple[np.ndarray, ...]:
        return (self.near, self.src, self.pos, self.val, self.ref, self.ptr, self.dst, self.keys, self.cand,
                self.leader, self.sp, self.due, self.newcomers)

    def _views(self, n: int, out: tuple[Any, ...]) -> tuple[Any, ...]:
        status, n_near, n_due, n_e, m, n_keys, n_c, stream_sum, n_s = out
        ok = status == STATUS_OK
        return (status, self.near[:n_near], self.src[:n_e], self.pos[:n_e], self.val[:n_e], self.ptr[: n_e + ok],
                self.dst, self.keys[:n_keys], stream_sum, n_s, self.cand[:n_c], n_due, m, self.ref[:n_e],
                self.leader[: n * ok])
