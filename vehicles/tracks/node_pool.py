"""1-D constant-velocity Kalman tracks keyed by (receiver, source) node indices, fed straight from the
copies an :class:`~corridor.addressed_channel.AddressedChannel` delivers: the filter of
:class:`~corridor.vehicles.tracks.pool.TrackPool` (``dim=1``) without a Python step per message.

The copies a tick delivers are filtered (the receiver keeps tracks; the roadside unit tracks every
sender, a vehicle only the senders it listens to), ordered by (arrival, send order) (a message's copies
in their order), and fused message by message in that order, as ``TrackPool.fuse`` applies them: a
pair's first message starts its track (state = the measurement, covariance = R), a later one older than
the track is rejected, the others predict by their interval and update (Joseph form). The arithmetic is
:func:`~corridor.vehicles.tracks.cv_kernel.cv_fuse_1d`'s, and the process-noise terms come from
:func:`~corridor.vehicles.tracks.stack.cv_terms` in numpy as there, so every track holds the same bits
(``tests/vehicles/test_veh_node_pool.py`` checks it against ``TrackPool`` on recorded and random
deliveries). Receivers are given slots; the tracks live in one struct of arrays (rows recycled).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from corridor.addressed_channel import AddressedChannel, Delivered, pop_due
from corridor.vehicles.tracks.cv_kernel import fuse_one
from corridor.vehicles.tracks.stack import cv_terms

_ROWS_SIG = ("UniTuple(i8, 2)(i8[:], i8[:], f8[:], f8[:], f8[:, :], i8[:], i8, i8[:], i8[:], i8, i8[:, :], "
             "f8[:, :], f8[:, :], f8[:, :, :], f8[:], i8[:], i8[:], i8[:], i8[:], f8[:, :], f8[:], b1[:])")


@njit(_ROWS_SIG, cache=True)
def _select_rows(src: np.ndarray, dst: np.ndarray, t_sent: np.ndarray, t_recv: np.ndarray, z: np.ndarray,
                 ref: np.ndarray, rsu: int, slot_of: np.ndarray, listen_keys: np.ndarray, n_free: int,
                 row_of: np.ndarray, r: np.ndarray, x: np.ndarray, p: np.ndarray, t_row: np.ndarray,
                 row_slot: np.ndarray, row_src: np.ndarray, free: np.ndarray, upd_row: np.ndarray,
                 upd_z: np.ndarray, upd_dt: np.ndarray, ahead: np.ndarray) -> tuple[int, int]:
    """The delivered copies that are measurements (``ref < 0``) for a receiver with a slot (the roadside
    unit ``rsu`` tracks every sender, a vehicle only where ``dst << 32 | src`` is in the sorted
    ``listen_keys``), stably ordered by arrival (the copies come in send order), then per copy in that
    order: start the pair's track (state = the measurement, covariance ``r``), or list it as an update
    (its row, measurement and interval ``upd_dt`` [s]; ``ahead``: > 0) when not older than the track,
    moving the track's time on (``TrackPool.fuse``). ``free[:n_free]``: the free rows, taken from the end
    (enough for every new pair). Returns (updates, free rows left)."""
    n_nodes = slot_of.shape[0]
    sel = np.empty(src.shape[0], dtype=np.int64)
    n = 0
    for i in range(src.shape[0]):
        d = dst[i]
        if ref[i] >= 0 or d >= n_nodes or slot_of[d] < 0:
            continue
        if d != rsu:
            key = (d << 32) | src[i]
            k = np.searchsorted(listen_keys, key)
            if k >= listen_keys.shape[0] or listen_keys[k] != key:
                continue
        sel[n] = i
        n += 1
    sel = sel[:n]
    if n > 1:
        sel = sel[np.argsort(t_recv[sel], kind="mergesort")]  # stable: ties keep the send order
    m = 0
    for i in sel:
        s = slot_of[dst[i]]
        row = row_of[s, src[i]]
        t = t_sent[i]
        if row < 0:
            n_free -= 1
            row = free[n_free]
            row_of[s, src[i]] = row
            row_slot[row], row_src[row] = s, src[i]
            x[row, 0], x[row, 1] = z[i, 0], z[i, 1]
            p[row, 0, 0], p[row, 0, 1], p[row, 1, 0], p[row, 1, 1] = r[0, 0], r[0, 1], r[1, 0], r[1, 1]
            t_row[row] = t
            continue
        if t < t_row[row]:
            continue  # older than the track: rejected
        dt = t - t_row[row]
        upd_row[m], upd_dt[m], ahead[m] = row, dt, dt > 0.0
        upd_z[m, 0], upd_z[m, 1] = z[i, 0], z[i, 1]
        t_row[row] = t
        m += 1
    return m, n_free


_FUSE_SIG = "void(i8[:], f8[:, :], f8[:, :, :], b1[:], f8[:], f8[:], f8[:], f8[:], f8[:, :], f8[:, :])"


@njit(_FUSE_SIG, cache=True)
def _fuse_rows(rows: np.ndarray, x: np.ndarray, p: np.ndarray, ahead: np.ndarray, dt: np.ndarray,
               q11: np.ndarray, q12: np.ndarray, q22: np.ndarray, z: np.ndarray, r: np.ndarray) -> None:
    """:func:`~corridor.vehicles.tracks.cv_kernel.cv_fuse_1d` in place on the pool's rows ``rows`` (a
    row may repeat: its messages in order)."""
    r00, r01, r10, r11 = r[0, 0], r[0, 1], r[1, 0], r[1, 1]
    j = 0
    for m in range(rows.shape[0]):
        if ahead[m]:
            fuse_one(x, p, rows[m], True, dt[j], q11[j], q12[j], q22[j], z[m, 0], z[m, 1], r00, r01, r10, r11)
            j += 1
        else:
            fuse_one(x, p, rows[m], False, 0.0, 0.0, 0.0, 0.0, z[m, 0], z[m, 1], r00, r01, r10, r11)


_DROP_SIG = "i8(f8, f8, i8, i8[:], i8[:], i8[:], i8[:, :], f8[:], i8[:])"


@njit(_DROP_SIG, cache=True)
def _drop_rows(t_s: float, stale_after_s: float, n_free: int, free: np.ndarray, row_slot: np.ndarray,
               row_src: np.ndarray, row_of: np.ndarray, t_row: np.ndarray, only_slot: np.ndarray) -> int:
    """Free the live rows older than ``stale_after_s`` at ``t_s`` (``only_slot`` empty), or every row of
    the slot ``only_slot[0]``. Returns the free count."""
    for row in range(row_slot.shape[0]):
        s = row_slot[row]
        if s < 0:
            continue
        if only_slot.shape[0] > 0:
            if s != only_slot[0]:
                continue
        elif not t_s - t_row[row] > stale_after_s:
            continue
        row_of[s, row_src[row]] = -1
        row_slot[row] = -1
        free[n_free] = row
        n_free += 1
    return n_free


_APPLY_SIG = ("i8(i8, i8[:], f8[:, :], f8[:, :, :], b1[:], f8[:], f8[:, :], f8[:, :], f8[:], f8[:], f8[:], f8[:], "
              "i8[:], f8[:])")


@njit(_APPLY_SIG, cache=True)
def _apply_table(m: int, rows: np.ndarray, x: np.ndarray, p: np.ndarray, ahead: np.ndarray, dt: np.ndarray,
                 z: np.ndarray, r: np.ndarray, q_dt: np.ndarray, q11: np.ndarray, q12: np.ndarray, q22: np.ndarray,
                 at: np.ndarray, missing: np.ndarray) -> int:
    """:func:`_fuse_rows` on the first ``m`` updates, with each interval's process-noise terms read from
    the table ``q_dt`` (sorted intervals, rounded to the nanosecond as ``cv_terms`` rounds them) ->
    ``q11``, ``q12``, ``q22`` (numpy's bits, see ``NodeTrackPool._add_terms``).  An interval not in the
    table: nothing is fused, the missing intervals are written to ``missing``; returns their count."""
    n_miss = 0
    for u in range(m):
        if ahead[u]:
            d = np.rint(dt[u] * 1e9) * 1e-9  # cv_terms' np.round(dt * 1e9) * 1e-9
            j = np.searchsorted(q_dt, d)
            if j < q_dt.shape[0] and q_dt[j] == d:
                at[u] = j
            else:
                missing[n_miss] = d
                n_miss += 1
    if n_miss:
        return n_miss
    r00, r01, r10, r11 = r[0, 0], r[0, 1], r[1, 0], r[1, 1]
    for u in range(m):
        if ahead[u]:
            j = at[u]
            fuse_one(x, p, rows[u], True, q_dt[j], q11[j], q12[j], q22[j], z[u, 0], z[u, 1], r00, r01, r10, r11)
        else:
            fuse_one(x, p, rows[u], False, 0.0, 0.0, 0.0, 0.0, z[u, 0], z[u, 1], r00, r01, r10, r11)
    return 0


_TICK_SIG = ("UniTuple(i8, 3)(f8, f8, i8[:], i8[:], f8[:], f8[:], f8[:, :], i8[:], i8, i8[:], i8[:], i8, i8[:, :], "
             "f8[:, :], f8[:, :], f8[:, :, :], f8[:], i8[:], i8[:], i8[:], i8[:], f8[:, :], f8[:], b1[:], "
             "f8[:], f8[:], f8[:], f8[:], i8[:], f8[:])")


@njit(_TICK_SIG, cache=True)
def _fuse_tick(t_s: float, stale_after_s: float, src: np.ndarray, dst: np.ndarray, t_sent: np.ndarray,
               t_recv: np.ndarray, z: np.ndarray, ref: np.ndarray, rsu: int, slot_of: np.ndarray,
               listen_keys: np.ndarray, n_free: int, row_of: np.ndarray, r: np.ndarray, x: np.ndarray,
               p: np.ndarray, t_row: np.ndarray, row_slot: np.ndarray, row_src: np.ndarray, free: np.ndarray,
               upd_row: np.ndarray, upd_z: np.ndarray, upd_dt: np.ndarray, ahead: np.ndarray, q_dt: np.ndarray,
               q11: np.ndarray, q12: np.ndarray, q22: np.ndarray, at: np.ndarray, missing: np.ndarray
               ) -> tuple[int, int, int]:
    """A tick's fuse and drop in one call: :func:`_select_rows`, :func:`_apply_table`, then (when nothing
    was missing from the table) :func:`_drop_rows` at ``t_s``.  Returns (updates, free rows, intervals
    missing from the table: the updates are listed and not fused, the stale rows not dropped)."""
    m = 0
    if src.shape[0]:
        m, n_free = _select_rows(src, dst, t_sent, t_recv, z, ref, rsu, slot_of, listen_keys, n_free, row_of, r,
                                 x, p, t_row, row_slot, row_src, free, upd_row, upd_z, upd_dt, ahead)
    n_miss = _apply_table(m, upd_row, x, p, ahead, upd_dt, upd_z, r, q_dt, q11, q12, q22, at, missing)
    if n_miss:
        return m, n_free, n_miss
    n_free = _drop_rows(t_s, stale_after_s, n_free, free, row_slot, row_src, row_of, t_row, np.zeros(0, dtype=np.int64))
    return m, n_free, 0


_DELIVER_SIG = ("UniTuple(i8, 4)(f8, b1[:], i8, i8[:], i8[:], i8[:], f8[:], f8[:], f8[:, :], i8[:], i8[:], i8[:], "
                "i8[:], f8[:], f8[:], f8[:, :], i8[:], "  # the channel's delivery (pop_due's arguments)
                "f8, f8, i8, i8[:], i8[:], i8, i8[:, :], f8[:, :], f8[:, :], f8[:, :, :], f8[:], i8[:], i8[:], i8[:], "
                "i8[:], f8[:, :], f8[:], b1[:], f8[:], f8[:], f8[:], f8[:], i8[:], f8[:])")


@njit(_DELIVER_SIG, cache=True)
def _deliver_fuse_tick(t_due: float, attached: np.ndarray, n_fl: int, q_seq: np.ndarray, q_src: np.ndarray,
                       q_dst: np.ndarray, q_t_sent: np.ndarray, q_t_recv: np.ndarray, q_val: np.ndarray,
                       q_ref: np.ndarray, o_seq: np.ndarray, o_src: np.ndarray, o_dst: np.ndarray,
                       o_t_sent: np.ndarray, o_t_recv: np.ndarray, o_val: np.ndarray, o_ref: np.ndarray,
                       t_s: float, stale_after_s: float, rsu: int, slot_of: np.ndarray, listen_keys: np.ndarray,
                       n_free: int, row_of: np.ndarray, r: np.ndarray, x: np.ndarray, p: np.ndarray,
                       t_row: np.ndarray, row_slot: np.ndarray, row_src: np.ndarray, free: np.ndarray,
                       upd_row: np.ndarray, upd_z: np.ndarray, upd_dt: np.ndarray, ahead: np.ndarray,
                       q_dt: np.ndarray, q11: np.ndarray, q12: np.ndarray, q22: np.ndarray, at: np.ndarray,
                       missing: np.ndarray) -> tuple[int, int, int, int]:
    """The channel's delivery (:func:`~corridor.addressed_channel.pop_due`) and :func:`_fuse_tick` on the
    delivered copies, in one call. Returns (delivered copies, updates, free rows, missing intervals)."""
    n_due = pop_due(t_due, attached, n_fl, q_seq, q_src, q_dst, q_t_sent, q_t_recv, q_val, q_ref, o_seq, o_src,
                    o_dst, o_t_sent, o_t_recv, o_val, o_ref)
    m, n_free, n_miss = _fuse_tick(t_s, stale_after_s, o_src[:n_due], o_dst[:n_due], o_t_sent[:n_due],
                                   o_t_recv[:n_due], o_val[:n_due], o_ref[:n_due], rsu, slot_of, listen_keys, n_free,
                                   row_of, r, x, p, t_row, row_slot, row_src, free, upd_row, upd_z, upd_dt, ahead,
                                   q_dt, q11, q12, q22, at, missing)
    return n_due, m, n_free, n_miss


@njit("i8(f8[:], i8[:], i8[:], i8[:], i8, f8[:], i8[:, :])", cache=True)
def referenced_in_order(t_recv: np.ndarray, seq: np.ndarray, dst: np.ndarray, ref: np.ndarray, n: int,
                        out_t: np.ndarray, out_dr: np.ndarray) -> int:
    """The first ``n`` delivered copies that carry a reference (``ref >= 0``) in the order (arrival, send
    order), ties kept in delivery order (Python's stable ``sorted`` on that key): their arrival times [s] to
    ``out_t`` and (receiver, reference) to ``out_dr``. Returns their number."""
    idx = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(n):  # insertion sort, stable: a copy goes after every copy not greater
        if ref[i] < 0:
            continue
        tr, sq = t_recv[i], seq[i]
        j = k
        while j > 0 and (t_recv[idx[j - 1]] > tr or (t_recv[idx[j - 1]] == tr and seq[idx[j - 1]] > sq)):
            idx[j] = idx[j - 1]
            j -= 1
        idx[j] = i
        k += 1
    for j in range(k):
        i = idx[j]
        out_t[j] = t_recv[i]
        out_dr[j, 0], out_dr[j, 1] = dst[i], ref[i]
    return k


_NO_KEYS = np.zeros(0, dtype=np.int64)


class NodeTrackPool:
    """1-D CV tracks of receiver nodes on source nodes (see the module docstring).

    ``index``: node name -> node index (the channel's, read as nodes appear); ``process_noise``
    [m^2/s^3]; ``meas_noise`` [m] / ``vel_noise`` [m/s] measurement std; ``stale_after_s`` [s]."""

    def __init__(self, index: dict[str, int], process_noise: float, meas_noise: float, vel_noise: float,
                 stale_after_s: float) -> None:
        self.index = index
        self.q = float(process_noise)
        self.stale_after_s = float(stale_after_s)
        self._r = np.diag([float(meas_noise) ** 2, float(vel_noise) ** 2])
        self._slots: dict[str, int] = {}  # receiver name -> slot (insertion order: ``receivers``)
        self._free_slots: list[int] = []
        self._slot_of = np.full(16, -1, dtype=np.int64)  # node -> slot (-1: not a receiver)
        self._row_of = np.full((8, 16), -1, dtype=np.int64)  # [slot, source node] -> row
        self._cap = 0
        self.x = np.zeros((0, 2))
        self.P = np.zeros((0, 2, 2))
        self.t_s = np.zeros(0)  # [s] time of each row's state (= its newest measurement)
        self._row_slot = np.zeros(0, dtype=np.int64)  # -1: a free row
        self._row_src = np.zeros(0, dtype=np.int64)
        self._free = np.zeros(0, dtype=np.int64)
        self._n_free = 0
        self._grow_rows(64)
        # per fuse: the updates (row, measurement, interval [s], interval > 0), in order
        self._upd_row, self._upd_z = np.empty(64, dtype=np.int64), np.empty((64, 2))
        self._upd_dt, self._ahead = np.empty(64), np.empty(64, dtype=bool)
        self._at, self._missing = np.empty(64, dtype=np.int64), np.empty(64)  # see fuse_and_drop
        self._ref_t, self._ref_dr = np.empty(64), np.empty((64, 2), dtype=np.int64)  # see deliver_fuse_and_drop_refs
        # the process-noise terms per interval seen (sorted, rounded to the nanosecond): (dt, q11, q12, q22)
        self._q_table: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0),) * 4

    # -- receivers ------------------------------------------------------------------------------
    def add_receiver(self, rx: str) -> None:
        if rx in self._slots:
            return
        node = self.index[rx]
        s = self._free_slots.pop() if self._free_slots else len(self._slots)
        self._slots[rx] = s
        if node >= self._slot_of.shape[0]:
            self._slot_of = _grown(self._slot_of, 2 * node + 2, -1)
        self._slot_of[node] = s
        if s >= self._row_of.shape[0]:
            self._row_of = _grown2(self._row_of, 2 * s + 2, self._row_of.shape[1])

    def remove_receiver(self, rx: str) -> None:
        """Forget a receiver and its tracks."""
        s = self._slots.pop(rx, None)
        if s is None:
            return
        self._n_free = _drop_rows(0.0, 0.0, self._n_free, self._free, self._row_slot, self._row_src,
                                  self._row_of, self.t_s, np.array([s], dtype=np.int64))
        self._slot_of[self.index[rx]] = -1
        self._free_slots.append(s)

    def __len__(self) -> int:
        """The receivers."""
        return len(self._slots)

    @property
    def slot_of(self) -> np.ndarray:
        """Node -> receiver slot (-1: not a receiver; nodes beyond its length neither)."""
        return self._slot_of

    def __contains__(self, rx: object) -> bool:
        return rx in self._slots

    @property
    def receivers(self) -> list[str]:
        return list(self._slots)

    def _row(self, rx: str, src: str) -> int:
        s, j = self._slots.get(rx), self.index.get(src)
        if s is None or j is None or j >= self._row_of.shape[1]:
            return -1
        return int(self._row_of[s, j])

    def slot_of_receiver(self, rx: str) -> int:
        """``rx``'s slot (the row of ``receiver_arrays``' table)."""
        return self._slots[rx]

    def receiver_arrays(self, rx: str) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """``rx``'s slot, the [slot, source node] -> row table, the rows' states (x, v) and their times [s]
        (what ``predict_one`` reads; valid until the next fuse or receiver change)."""
        return self._slots[rx], self._row_of, self.x, self.t_s

    def has_track(self, rx: str, src: str) -> bool:
        return self._row(rx, src) >= 0

    def last_update_s(self, rx: str, src: str) -> float:
        """Time [s] of the newest measurement of ``src`` fused by ``rx`` (KeyError if none)."""
        row = self._row(rx, src)
        if row < 0:
            raise KeyError((rx, src))
        return float(self.t_s[row])

    def state(self, rx: str, src: str) -> tuple[np.ndarray, np.ndarray]:
        """The fused state [position, velocity] and covariance of ``rx``'s track of ``src`` (views;
        KeyError if none)."""
        row = self._row(rx, src)
        if row < 0:
            raise KeyError((rx, src))
        return self.x[row], self.P[row]

    # -- updates --------------------------------------------------------------------------------
    def fuse_delivered(self, src: np.ndarray, dst: np.ndarray, t_sent_s: np.ndarray, t_recv_s: np.ndarray,
                       z: np.ndarray, ref: np.ndarray, rsu: int, listen_keys: np.ndarray) -> None:
        """Fuse the delivered copies (node indices ``src`` -> ``dst``, measurements ``z`` (k, 2) taken at
        ``t_sent_s``, arriving at ``t_recv_s``, in send order) that are measurements (``ref < 0``) the
        receiver tracks (see :func:`_select_rows`), in the order (arrival, send order)."""
        k = src.shape[0]
        if k == 0:
            return
        self._room(k)
        m, self._n_free = _select_rows(src, dst, t_sent_s, t_recv_s, z, ref, rsu, self._slot_of, listen_keys,
                                       self._n_free, self._row_of, self._r, self.x, self.P, self.t_s, self._row_slot,
                                       self._row_src, self._free, self._upd_row, self._upd_z, self._upd_dt,
                                       self._ahead)
        if m == 0:
            return
        ahead = self._ahead[:m]
        d, q11, q12, q22 = cv_terms(self._upd_dt[:m][ahead], self.q)  # numpy, as TrackPool's cv_fuse computes them
        _fuse_rows(self._upd_row[:m], self.x, self.P, ahead, d, q11, q12, q22, self._upd_z[:m], self._r)

    def fuse_and_drop(self, t_s: float, src: np.ndarray, dst: np.ndarray, t_sent_s: np.ndarray,
                      t_recv_s: np.ndarray, z: np.ndarray, ref: np.ndarray, rsu: int, listen_keys: np.ndarray) -> None:
        """``fuse_delivered`` and then ``drop_stale(t_s)``, the same bits, in one compiled call: the
        process-noise terms of each interval come from a table of the intervals seen so far, filled by
        ``cv_terms``' numpy arithmetic when a new one appears (then a second call)."""
        self._room(src.shape[0])
        m, self._n_free, n_miss = _fuse_tick(
            float(t_s), self.stale_after_s, src, dst, t_sent_s, t_recv_s, z, ref, rsu, *self._fuse_args(listen_keys))
        self._finish(t_s, m, n_miss)

    def deliver_fuse_and_drop(self, channel: AddressedChannel, t_s: float, rsu: int,
                              listen_keys: np.ndarray) -> Delivered:
        """``channel.deliver(t_s)`` and ``fuse_and_drop`` of what it delivered, in one compiled call;
        returns the delivered copies (as ``deliver``)."""
        args = channel.delivery_buffers(t_s)
        self._room(args[2])  # at most the copies in flight are delivered
        n_due, m, self._n_free, n_miss = _deliver_fuse_tick(*args, float(t_s), self.stale_after_s, rsu,
                                                            *self._fuse_args(listen_keys))
        self._finish(t_s, m, n_miss)
        return channel.commit_delivery(n_due)

    def deliver_fuse_and_drop_refs(self, channel: AddressedChannel, t_s: float, rsu: int,
                                   listen_keys: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
        """``deliver_fuse_and_drop`` for a consumer that reads only the delivered references: returns their
        number ``k`` and (views valid until the next call) their arrival times [s] and (receiver node,
        reference) pairs, in the order (arrival, send order) (see :func:`referenced_in_order`)."""
        args = channel.delivery_buffers(t_s)
        self._room(args[2])
        n_due, m, self._n_free, n_miss = _deliver_fuse_tick(*args, float(t_s), self.stale_after_s, rsu,
                                                            *self._fuse_args(listen_keys))
        self._finish(t_s, m, n_miss)
        channel.commit_count(n_due)
        if not n_due:
            return 0, self._ref_t, self._ref_dr
        if self._ref_t.shape[0] < n_due:
            self._ref_t, self._ref_dr = np.empty(2 * n_due), np.empty((2 * n_due, 2), dtype=np.int64)
        out = args[3:]  # the queue (7), then the delivery's seven arrays
        k = referenced_in_order(out[11], out[7], out[9], out[13], n_due, self._ref_t, self._ref_dr)
        return k, self._ref_t, self._ref_dr

    def fused_args(self, channel: AddressedChannel, t_s: float) -> tuple[tuple[Any, ...], np.ndarray, np.ndarray]:
        """For a compiled caller that makes ``deliver_fuse_and_drop_refs``' calls itself (in one call with its
        own work): ``_deliver_fuse_tick``'s arguments but the time, the roadside unit's node, ``slot_of`` and the
        listen keys (the caller's), and the references' buffers; then ``fused_done`` with the call's counts."""
        args = channel.delivery_buffers(t_s)
        self._room(args[2])
        if self._ref_t.shape[0] < args[2]:
            self._ref_t, self._ref_dr = np.empty(2 * args[2]), np.empty((2 * args[2], 2), dtype=np.int64)
        return (*args, self.stale_after_s, *self._fuse_args(_NO_KEYS)[2:]), self._ref_t, self._ref_dr

    def fused_done(self, channel: AddressedChannel, t_s: float, counts: tuple[int, int, int, int]) -> None:
        """After ``_deliver_fuse_tick`` on ``fused_args``: the free rows, the fuse completed when intervals were
        missing from the table, the channel's counts."""
        n_due, m, self._n_free, n_miss = counts
        self._finish(t_s, m, n_miss)
        channel.commit_count(n_due)

    def _room(self, k: int) -> None:
        """Room for ``k`` delivered copies: a column per node, free rows, update buffers."""
        if self._row_of.shape[1] < len(self.index):  # a column per node the channel knows
            self._row_of = _grown2(self._row_of, self._row_of.shape[0], 2 * len(self.index))
        if self._n_free < k:
            self._grow_rows(max(2 * self._cap, self._cap + k))
        if self._upd_row.shape[0] < k:
            self._upd_row, self._upd_z = np.empty(2 * k, dtype=np.int64), np.empty((2 * k, 2))
            self._upd_dt, self._ahead = np.empty(2 * k), np.empty(2 * k, dtype=bool)
        if self._at.shape[0] < self._upd_row.shape[0]:
            self._at, self._missing = np.empty(self._upd_row.shape[0], dtype=np.int64), np.empty(self._upd_row.shape[0])

    def _fuse_args(self, listen_keys: np.ndarray) -> tuple[Any, ...]:
        return (self._slot_of, listen_keys, self._n_free, self._row_of, self._r, self.x, self.P, self.t_s,
                self._row_slot, self._row_src, self._free, self._upd_row, self._upd_z, self._upd_dt, self._ahead,
                *self._q_table, self._at, self._missing)

    def _finish(self, t_s: float, m: int, n_miss: int) -> None:
        """After a call that found intervals missing from the table: add them, fuse, drop."""
        if n_miss:
            self._add_terms(self._missing[:n_miss])
            n = _apply_table(m, self._upd_row, self.x, self.P, self._ahead, self._upd_dt, self._upd_z, self._r,
                             *self._q_table, self._at, self._missing)
            assert n == 0
            self.drop_stale(t_s)

    def _add_terms(self, d: np.ndarray) -> None:
        """Add the intervals ``d`` [s] (rounded to the nanosecond) to the table of process-noise terms, with
        ``cv_terms``' arithmetic on them (numpy's ``d ** 3`` is not ``math.pow``'s, nor ``d * d * d``)."""
        q_dt = np.unique(np.concatenate([self._q_table[0], d]))
        q = self.q
        self._q_table = (q_dt, q * q_dt**3 / 3.0, q * q_dt**2 / 2.0, q * q_dt)

    def drop_stale(self, t_s: float) -> None:
        """Forget every track whose newest measurement is older than ``stale_after_s``."""
        self._n_free = _drop_rows(float(t_s), self.stale_after_s, self._n_free, self._free, self._row_slot,
                                  self._row_src, self._row_of, self.t_s, np.zeros(0, dtype=np.int64))

    # -- queries --------------------------------------------------------------------------------
    def predict_one(self, rx: str, src: str, t_s: float) -> tuple[float, float, float] | None:
        """``TrackPool.predict_one``: (position [m], velocity [m/s], age [s]) of ``rx``'s track of
        ``src`` extrapolated to ``t_s`` (never backwards), None if untracked."""
        row = self._row(rx, src)
        if row < 0:
            return None
        age = max(0.0, t_s - float(self.t_s[row]))
        dt = round(age * 1e9) * 1e-9  # cv_terms' rounding (half to even, as np.round)
        x0, x1 = float(self.x[row, 0]), float(self.x[row, 1])
        return x0 + dt * x1, x1 + 0.0 * x0, age

    # -- storage --------------------------------------------------------------------------------
    def _grow_rows(self, cap: int) -> None:
        n = self._cap
        self.x = np.concatenate([self.x, np.zeros((cap - n, 2))])
        self.P = np.concatenate([self.P, np.zeros((cap - n, 2, 2))])
        self.t_s = np.concatenate([self.t_s, np.zeros(cap - n)])
        self._row_slot = np.concatenate([self._row_slot, np.full(cap - n, -1, dtype=np.int64)])
        self._row_src = np.concatenate([self._row_src, np.zeros(cap - n, dtype=np.int64)])
        free = np.empty(cap, dtype=np.int64)
        free[: self._n_free] = self._free[: self._n_free]
        free[self._n_free : self._n_free + cap - n] = np.arange(cap - 1, n - 1, -1)
        self._free, self._n_free, self._cap = free, self._n_free + cap - n, cap


def _grown(a: np.ndarray, n: int, fill: int) -> np.ndarray:
    out = np.full(n, fill, dtype=a.dtype)
    out[: a.shape[0]] = a
    return out


def _grown2(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    out = np.full((rows, cols), -1, dtype=a.dtype)
    out[: a.shape[0], : a.shape[1]] = a
    return out
