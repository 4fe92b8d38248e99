"""The :class:`~corridor.channel.Channel` of addressed messages, as arrays keyed by
node index and handled in compiled code: what ``Channel.send_many`` does when every receiver is named
(unicasts and multicasts), its in-flight queue and ``deliver_indexed``, without a Python object per
message or per copy.

A V2X merging tick sends a few dozen CAMs to the roadside unit and to the few vehicles behind each
sender, and a few crossing-time assignments; the per-copy Python of the general channel (the copies
found one by one, a batch object per message, the copies cut out of batches on delivery) was the
largest part of that controller's CPU (docs/performance.md, "V2X merging: the floor").

The model is the general channel's, copy for copy (module docstring of :mod:`corridor.channel`):
the same copies in the same order (a receiver that is the sender, unknown or detached gets none; a
receiver or sender without a known position, or a NaN position, is not range checked; the squared
distance summed x, y, z in that order), one ``rng.random`` call per send for its ``n`` copies with the
general channel's uniforms in its order (Bernoulli: per copy its loss, then its delay uniform, as
``send_many``; Gilbert-Elliott: the same, then in range its link's transition uniform, as one ``send``
per copy), the same loss, delay, end-of-run and overflow
drops, the same send order (an entry with copies takes one), the copies delivered in send order and
within a message in the listed order, a copy for a receiver detached meanwhile discarded, and the
same statistics (:class:`~corridor.channel.ChannelStats`; no age of information: a consumer measures
its own). ``tests/corridor/test_kernel_addressed_channel.py`` checks it against ``Channel`` on random
sequences of sends, loss, positions, attach/detach and deliveries.

A message's payload is two floats (``val``) and an integer reference (``ref``) that the channel carries
unread; a consumer keeps whatever the reference stands for.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from corridor.channel import _T_EPS_S, BernoulliLoss, ChannelConfig, ChannelStats

_COPIES_SIG = "UniTuple(i8, 2)(i8[:], f8[:, :], i8[:], i8[:], b1[:], b1[:], f8[:, :], f8, i8[:], i8[:], b1[:], i8[:])"


@njit(_COPIES_SIG, cache=True)
def _find_copies(src: np.ndarray, src_pos: np.ndarray, ptr: np.ndarray, dst: np.ndarray, attached: np.ndarray,
                 known: np.ndarray, pos: np.ndarray, r2: float, entry_of: np.ndarray, dst_out: np.ndarray,
                 near_out: np.ndarray, counts: np.ndarray) -> tuple[int, int]:
    """The copies of entries ``src`` (M,) at ``src_pos`` (M, 3) [m] to ``dst[ptr[e]:ptr[e + 1]]`` (node
    indices, -1: unknown): per copy its entry, receiver and range flag (written from index 0); per
    entry its count. Returns the number of copies and of those in range (``Channel._send_addressed``'s loop)."""
    n = n_near = 0
    n_nodes = attached.shape[0]
    for e in range(src.shape[0]):
        si = src[e]
        sx, sy, sz = src_pos[e, 0], src_pos[e, 1], src_pos[e, 2]
        c = 0
        for k in range(ptr[e], ptr[e + 1]):
            j = dst[k]
            if j < 0 or j >= n_nodes or j == si or not attached[j]:
                continue
            if known[j]:
                dx, dy, dz = pos[j, 0] - sx, pos[j, 1] - sy, pos[j, 2] - sz
                d2 = dx * dx + dy * dy + dz * dz
                near = d2 != d2 or d2 <= r2  # NaN: not range checked
            else:
                near = True  # unknown position: not range checked
            entry_of[n] = e
            dst_out[n] = j
            near_out[n] = near
            n_near += near
            n += 1
            c += 1
        counts[e] = c
    return n, n_near


_ENQUEUE_SIG = ("UniTuple(i8, 5)(f8, f8, f8, f8[:], b1[:, :], f8, i8, i8, i8, i8[:], i8[:], i8[:], b1[:], f8[:], "
                "i8[:], f8[:, :], i8[:], i8[:], i8[:], i8[:], f8[:], f8[:], f8[:, :], i8[:])")


@njit(_ENQUEUE_SIG, cache=True)
def _draw_and_enqueue(t_s: float, t_base: float, jitter_s: float, loss: np.ndarray, ge_bad: np.ndarray,
                      t_last: float, room: int, seq0: int, n_fl: int, src: np.ndarray, entry_of: np.ndarray,
                      dst: np.ndarray, near: np.ndarray, u: np.ndarray, counts: np.ndarray, val: np.ndarray,
                      ref: np.ndarray, q_seq: np.ndarray, q_src: np.ndarray, q_dst: np.ndarray, q_t_sent: np.ndarray,
                      q_t_recv: np.ndarray, q_val: np.ndarray, q_ref: np.ndarray) -> tuple[int, int, int, int, int]:
    """Loss and delay of the ``len(entry_of)`` copies from the uniforms ``u``, the end-of-run (``t_last``
    [s]) and overflow (``room`` copies) drops, and the kept copies appended to the in-flight queue ``q_*``
    at ``n_fl`` in send order (``seq0`` the next send order).

    ``loss``: ``[p]`` (Bernoulli: per copy a loss and a delay uniform), or ``[p_good_to_bad,
    p_bad_to_good, loss_good, loss_bad]`` (Gilbert-Elliott, the link states ``ge_bad[src, dst]``: per copy
    a loss and a delay uniform, then, in range, the transition uniform: ``Channel.send`` per copy).
    Returns (copies in flight, next send order, lost, dropped after the end, dropped by overflow)."""
    n_lost = n_late = n_over = 0
    ge = loss.shape[0] == 4
    k = 0  # the next uniform
    n = entry_of.shape[0]
    seq_of = np.empty(counts.shape[0], dtype=np.int64)
    seq = seq0
    for e in range(counts.shape[0]):  # an entry with copies takes a send order
        seq_of[e] = seq
        if counts[e] > 0:
            seq += 1
    for i in range(n):
        u_loss, u_delay = u[k], u[k + 1]
        k += 2
        if not near[i]:
            continue
        p_loss = loss[0]
        if ge:
            e = entry_of[i]
            bad = ge_bad[src[e], dst[i]]
            bad = u[k] >= loss[1] if bad else u[k] < loss[0]
            k += 1
            ge_bad[src[e], dst[i]] = bad
            p_loss = loss[3] if bad else loss[2]
        if u_loss < p_loss:
            n_lost += 1
            continue
        t_recv = t_base + jitter_s * u_delay
        if t_recv > t_last:
            n_late += 1
            continue
        if room <= 0:
            n_over += 1
            continue
        room -= 1
        e = entry_of[i]
        q_seq[n_fl], q_src[n_fl], q_dst[n_fl] = seq_of[e], src[e], dst[i]
        q_t_sent[n_fl], q_t_recv[n_fl] = t_s, t_recv
        q_val[n_fl, 0], q_val[n_fl, 1], q_ref[n_fl] = val[e, 0], val[e, 1], ref[e]
        n_fl += 1
    return n_fl, seq, n_lost, n_late, n_over


_DELIVER_SIG = ("i8(f8, b1[:], i8, i8[:], i8[:], i8[:], f8[:], f8[:], f8[:, :], i8[:], i8[:], i8[:], i8[:], f8[:], "
                "f8[:], f8[:, :], i8[:])")


@njit(_DELIVER_SIG, cache=True)
def _pop_due(t_due: float, attached: np.ndarray, n_fl: int, q_seq: np.ndarray, q_src: np.ndarray,
             q_dst: np.ndarray, q_t_sent: np.ndarray, q_t_recv: np.ndarray, q_val: np.ndarray, q_ref: np.ndarray,
             o_seq: np.ndarray, o_src: np.ndarray, o_dst: np.ndarray, o_t_sent: np.ndarray, o_t_recv: np.ndarray,
             o_val: np.ndarray, o_ref: np.ndarray) -> int:
    """Move the due copies (``t_recv <= t_due``, the receiver attached) to ``o_*`` and compact the queue
    to the copies still in flight (receiver attached, not due), both in their order; the others are
    dropped. Returns the number of due copies (the queue's count is written to ``o_seq[-1]``)."""
    k = n_due = 0
    for i in range(n_fl):
        if not attached[q_dst[i]]:
            continue
        if q_t_recv[i] <= t_due:
            o_seq[n_due], o_src[n_due], o_dst[n_due] = q_seq[i], q_src[i], q_dst[i]
            o_t_sent[n_due], o_t_recv[n_due] = q_t_sent[i], q_t_recv[i]
            o_val[n_due, 0], o_val[n_due, 1], o_ref[n_due] = q_val[i, 0], q_val[i, 1], q_ref[i]
            n_due += 1
            continue
        if k != i:
            q_seq[k], q_src[k], q_dst[k] = q_seq[i], q_src[i], q_dst[i]
            q_t_sent[k], q_t_recv[k] = q_t_sent[i], q_t_recv[i]
            q_val[k, 0], q_val[k, 1], q_ref[k] = q_val[i, 0], q_val[i, 1], q_ref[i]
        k += 1
    o_seq[o_seq.shape[0] - 1] = k
    return n_due


pop_due = _pop_due  # for a compiled consumer (AddressedChannel.delivery_buffers)
find_copies, draw_and_enqueue = _find_copies, _draw_and_enqueue  # for a compiled sender (AddressedChannel.send_buffers)


class Delivered:
    """The copies of one delivery, in delivery order (struct of arrays, one row per copy)."""

    __slots__ = ("seq", "src", "dst", "t_sent_s", "t_recv_s", "val", "ref")

    def __init__(self, seq: np.ndarray, src: np.ndarray, dst: np.ndarray, t_sent_s: np.ndarray,
                 t_recv_s: np.ndarray, val: np.ndarray, ref: np.ndarray) -> None:
        self.seq, self.src, self.dst = seq, src, dst  # send order, sender and receiver node indices
        self.t_sent_s, self.t_recv_s = t_sent_s, t_recv_s  # [s]
        self.val, self.ref = val, ref  # the payload: (k, 2) floats, (k,) reference

    def __len__(self) -> int:
        return int(self.seq.shape[0])


class AddressedChannel:
    """Addressed sends, the in-flight queue and deliveries of a channel by node index
    (see the module docstring)."""

    def __init__(self, cfg: ChannelConfig, rng: np.random.Generator, t_end_s: float | None = None) -> None:
        self.cfg = cfg
        self._rng = rng
        lm = cfg.loss
        self._loss = (np.array([lm.p]) if isinstance(lm, BernoulliLoss) else
                      np.array([lm.p_good_to_bad, lm.p_bad_to_good, lm.loss_good, lm.loss_bad]))
        self._ge_bad = np.zeros((16 if self._loss.size == 4 else 0,) * 2, dtype=bool)  # [src, dst] bad state
        self._r2 = cfg.range_m ** 2
        self._t_last = (math.inf if t_end_s is None else float(t_end_s)) + _T_EPS_S
        self.index: dict[str, int] = {}  # node name -> node index
        self.names: list[str] = []
        self._attached = np.zeros(16, dtype=bool)
        self._known = np.zeros(16, dtype=bool)  # position set by the latest set_positions
        self._pos = np.zeros((16, 3))  # [m]
        self._seq = 0
        self._n = 0  # copies in flight: the first _n rows of the queue
        self._q = _queue(64)
        self._out = _queue(64)  # the latest delivery (and, last, the queue's count after it)
        # a send's copies (entry, receiver, in range) and per entry its count (see send)
        self._copies = (np.empty(256, dtype=np.int64), np.empty(256, dtype=np.int64), np.empty(256, dtype=bool),
                        np.empty(64, dtype=np.int64))
        self._n_sent = self._n_delivered = self._n_lost = self._n_oor = self._n_late = self._n_overflow = 0
        # the generator's uniforms, drawn ahead in batches and read in order: the values one rng.random call per
        # send gives (a float64 uniform is one draw of the bit generator, whatever the batch), see send_buffers
        self._pool, self._pool_at = np.zeros(0), 0

    # -- nodes, membership, positions ----------------------------------------------------------
    def node(self, name: str) -> int:
        """The node index of ``name`` (registered on first use)."""
        i = self.index.get(name)
        if i is None:
            i = self.index[name] = len(self.names)
            self.names.append(name)
            if i >= self._attached.shape[0]:
                self._grow_nodes(2 * self._attached.shape[0])
        return i

    def attach(self, name: str) -> None:
        """Make ``name`` receive the copies addressed to it (idempotent)."""
        i = self.node(name)  # first: registering may grow the arrays
        self._attached[i] = True

    def detach(self, name: str) -> None:
        """Stop delivering to ``name`` (its copies in flight are discarded at the next delivery)."""
        i = self.index.get(name)
        if i is not None:
            self._attached[i] = False

    def set_positions(self, nodes: np.ndarray, pos_m: np.ndarray) -> None:
        """Positions (k, 3) [m] of ``nodes`` for the range checks of the following sends (the others
        unknown: not range checked), as ``Channel.set_positions_arrays``."""
        self._known[:] = False
        self._known[nodes] = True
        self._pos[nodes] = pos_m

    def position_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The per-node (known, position (cap, 3) [m]) arrays that ``set_positions`` writes, for a compiled
        caller that sets them in place the same way (valid until a new node is registered)."""
        return self._known, self._pos

    # -- sending and delivery -----------------------------------------------------------------
    def send(self, t_s: float, src: np.ndarray, src_pos: np.ndarray, ptr: np.ndarray, dst: np.ndarray,
             val: np.ndarray, ref: np.ndarray) -> None:
        """Send entry ``e`` from node ``src[e]`` at ``src_pos[e]`` (3,) [m] to the nodes
        ``dst[ptr[e]:ptr[e + 1]]`` (-1: a name the channel does not know) with payload ``val[e]`` (2,),
        ``ref[e]``: ``Channel.send_many`` with every receiver named (one unicast per listed receiver, the
        kept copies of an entry one sent message)."""
        m = src.shape[0]
        if ptr[m] == 0:  # nothing listed: send_many draws nothing
            return
        c = int(ptr[m])
        if c > self._copies[0].shape[0] or m > self._copies[3].shape[0]:  # buffers kept from send to send
            c2, m2 = max(c, 2 * self._copies[0].shape[0]), max(m, 2 * self._copies[3].shape[0])
            self._copies = (np.empty(c2, dtype=np.int64), np.empty(c2, dtype=np.int64), np.empty(c2, dtype=bool),
                            np.empty(m2, dtype=np.int64))
        entry_of, dst_c, near, counts = self._copies
        counts = counts[:m]
        n, n_near = _find_copies(src, src_pos, ptr, dst, self._attached, self._known, self._pos, self._r2,
                                 entry_of, dst_c, near, counts)
        u = self._uniforms(2 * n + (n_near if self._loss.size == 4 else 0))
        if self._n + n > self._q[0].shape[0]:
            self._q = _queue(2 * (self._n + n), self._q, self._n)
        room = max(self.cfg.max_in_flight - self._n, 0)
        t_base = t_s + self.cfg.latency_s
        self._n, self._seq, lost, late, over = _draw_and_enqueue(
            float(t_s), t_base, self.cfg.jitter_s, self._loss, self._ge_bad, self._t_last, room, self._seq,
            self._n, src, entry_of[:n], dst_c[:n], near[:n], u, counts, val, ref, *self._q)
        self._n_sent += n
        self._n_oor += n - n_near
        self._n_lost += lost
        self._n_late += late
        self._n_overflow += over

    def _uniforms(self, k: int) -> np.ndarray:
        """The next ``k`` uniforms of the pool (refilled from the generator when short)."""
        self._fill(k)
        at = self._pool_at
        self._pool_at = at + k
        return self._pool[at:at + k]

    def _fill(self, k: int) -> None:
        if self._pool_at + k > self._pool.shape[0]:
            self._pool = np.concatenate([self._pool[self._pool_at:], self._rng.random(max(k, 4096))])
            self._pool_at = 0

    def send_buffers(self, max_copies: int, max_entries: int) -> tuple[Any, ...]:
        """For a compiled sender that makes ``send``'s calls itself (``find_copies``, then ``draw_and_enqueue`` on
        the next uniforms of the pool, in the same call as its own work), with room for ``max_copies`` copies of
        ``max_entries`` entries (after a delivery: the copies in flight at most as now): the range check's
        arrays (attached, known, positions, the squared range), the copies' buffers (entry, receiver, in
        range, per entry its count), the loss model and Gilbert-Elliott states, the end of the run, the queue's
        room, the latency and jitter [s], the next send order, the pool and its cursor, the queue's seven
        arrays; then ``commit_send`` with the call's counts."""
        if max_copies > self._copies[0].shape[0] or max_entries > self._copies[3].shape[0]:
            c2, m2 = max(max_copies, 2 * self._copies[0].shape[0]), max(max_entries, 2 * self._copies[3].shape[0])
            self._copies = (np.empty(c2, dtype=np.int64), np.empty(c2, dtype=np.int64), np.empty(c2, dtype=bool),
                            np.empty(m2, dtype=np.int64))
        if self._n + max_copies > self._q[0].shape[0]:
            self._q = _queue(2 * (self._n + max_copies), self._q, self._n)
        self._fill(3 * max_copies)  # per copy a loss and a delay uniform, and a link transition's
        return (self._attached, self._known, self._pos, self._r2, *self._copies, self._loss, self._ge_bad,
                self._t_last, self.cfg.max_in_flight, self.cfg.latency_s, self.cfg.jitter_s, self._seq, self._pool,
                self._pool_at, *self._q)

    def commit_send(self, n_fl: int, seq: int, n: int, n_near: int, lost: int, late: int, over: int, n_u: int) -> None:
        """After a compiled send on ``send_buffers``: the copies in flight and the next send order, the
        statistics of its ``n`` copies (``n_near`` in range), the ``n_u`` uniforms it read."""
        self._n, self._seq = n_fl, seq
        self._n_sent += n
        self._n_oor += n - n_near
        self._n_lost += lost
        self._n_late += late
        self._n_overflow += over
        self._pool_at += n_u

    def deliver(self, t_s: float) -> Delivered:
        """Pop every copy with ``t_recv <= t_s`` (1e-9 s tolerance) to an attached receiver, in send
        order (a message's copies in their listed order); copies to detached receivers are dropped.
        The arrays are views of the channel's buffers, valid until the next ``deliver``."""
        n = self._n
        if n + 1 > self._out[0].shape[0]:
            self._out = _queue(2 * (n + 1))
        out = self._out
        n_due = _pop_due(t_s + _T_EPS_S, self._attached, n, *self._q, *out) if n else 0
        self._n = int(out[0][-1]) if n else 0
        self._n_delivered += n_due
        return Delivered(*(a[:n_due] for a in out))

    def delivery_buffers(self, t_s: float) -> tuple[Any, ...]:
        """``deliver`` for a compiled consumer that pops the due copies itself, in the same call as its own
        work: the arguments of :func:`pop_due` (the due time, the attached flags, the copies in flight, the
        queue's seven arrays and the output's seven); then :meth:`commit_delivery` with its count."""
        n = self._n
        if n + 1 > self._out[0].shape[0]:
            self._out = _queue(2 * (n + 1))
        return (t_s + _T_EPS_S, self._attached, n, *self._q, *self._out)

    def commit_delivery(self, n_due: int) -> Delivered:
        """After :func:`pop_due` on :meth:`delivery_buffers`: the queue's count, the statistics, and the
        delivered copies (views, valid until the next delivery), as ``deliver`` returns them."""
        self.commit_count(n_due)
        return Delivered(*(a[:n_due] for a in self._out))

    def commit_count(self, n_due: int) -> None:
        """``commit_delivery`` without the copies (the consumer read them from :meth:`delivery_buffers`' output
        arrays: seq, src, dst, t_sent, t_recv, val, ref, their first ``n_due`` rows)."""
        self._n = int(self._out[0][-1])
        self._n_delivered += n_due

    @property
    def in_flight(self) -> int:
        """Copies sent but not yet delivered."""
        return self._n

    def stats(self) -> ChannelStats:
        """The counters of ``Channel.stats`` (age of information: NaN, not kept)."""
        return ChannelStats.counted(self._n_sent, self._n_delivered, self._n_lost, self._n_oor, self._n_late,
                                    self._n_overflow)

    def _grow_nodes(self, cap: int) -> None:
        n = self._attached.shape[0]
        attached, known, pos = np.zeros(cap, dtype=bool), np.zeros(cap, dtype=bool), np.zeros((cap, 3))
        attached[:n], known[:n], pos[:n] = self._attached, self._known, self._pos
        self._attached, self._known, self._pos = attached, known, pos
        if self._ge_bad.size:
            ge = np.zeros((cap, cap), dtype=bool)
            ge[:n, :n] = self._ge_bad
            self._ge_bad = ge


_Queue = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _queue(cap: int, old: _Queue | None = None, n: int = 0) -> _Queue:
    """In-flight copies (send order, sender, receiver, send and arrival times [s], payload floats and
    reference) with room for ``cap``, the first ``n`` taken from ``old``."""
    q = (np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64),
         np.empty(cap), np.empty(cap), np.empty((cap, 2)), np.empty(cap, dtype=np.int64))
    if old is not None:
        for a, b in zip(q, old, strict=True):
            a[:n] = b[:n]
    return q
