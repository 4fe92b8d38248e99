"""A roadside unit's broadcasts over the scenario's channel, lean: what
``Channel.send(t, rsu, payload, src_pos)`` (a broadcast from one sender) and ``Channel.deliver_indexed``
do, copy for copy, without the general channel's per-call bookkeeping (node table lookups of every
position, a sender that may be any node, age of information).

The model is the general channel's (module docstring of :mod:`corridor.channel`), for one sender that is
never a receiver and Bernoulli loss: the receivers are the attached ones in the order they were first
attached (the general channel's node order), every one gets a copy; a receiver without a known position
or with a NaN one is not range checked (the squared distance summed x, y, z in that order, as numpy's
row sum of three); per send ``rng.random(n)`` loss uniforms then ``rng.random(n)`` delay uniforms; the
same loss, delay, end-of-run and overflow drops; a send with copies takes a send order, one without
receivers draws nothing; a copy for a receiver detached by the time it is due is discarded; the same
statistics (:class:`~corridor.channel.ChannelStats`, no age of information).  A send's copies (range,
loss, delay, end-of-run drop) are found in one compiled call (``rsu_kernel.broadcast_copies``).
``tests/controllers/test_rsu_broadcast.py`` checks it against ``Channel`` on random sequences.

Used by the wave-damping controllers (``v2x_wave_damping``, ``v2x_merge_gaps``): their RSU broadcasts
every road step to the few connected vehicles in its zone, and the general channel's per-call work was
most of what they cost (docs/performance.md, "flow_merge's cooperative variants").
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from corridor.channel import _T_EPS_S, BernoulliLoss, Channel, ChannelConfig, ChannelStats
from corridor.controllers.merging.rsu_kernel import broadcast_copies


class Due(NamedTuple):
    """The copies of one broadcast delivered in one ``deliver`` call (the general channel's
    ``IndexedBatch`` of one sender): receivers as node indices (``names``) and their delivery times."""

    seq: int  # send order
    payload: Any
    dst_idx: np.ndarray  # node indices of the receivers (one copy each)
    t_recv_s: np.ndarray  # [s]


class RsuBroadcast:
    """One sender's broadcasts to the attached receivers (see the module docstring); Bernoulli loss."""

    def __init__(self, cfg: ChannelConfig, rng: np.random.Generator, t_end_s: float | None = None) -> None:
        if not isinstance(cfg.loss, BernoulliLoss):
            raise ValueError(f"RsuBroadcast: Bernoulli loss only, not {cfg.loss.model!r} (use Channel)")
        self.cfg = cfg
        self._rng = rng
        self._p_loss = float(cfg.loss.p)
        self._r2 = cfg.range_m ** 2
        self._t_end_s = math.inf if t_end_s is None else float(t_end_s)
        self.index: dict[str, int] = {}  # receiver -> node index (first attach order)
        self.names: list[str] = []  # node index -> receiver
        self._attached = np.zeros(16, dtype=bool)  # by node index
        self._n_attached = 0
        self._pending: list[Due] = []  # in send order
        self._seq = 0
        self._n_in_flight = 0
        self._n_sent = self._n_delivered = self._n_lost = self._n_oor = self._n_late = self._n_overflow = 0
        self._counts = np.zeros(4, dtype=np.int64)  # the kernel's counts of one send

    # -- membership -----------------------------------------------------------------------------
    def attach(self, name: str) -> None:
        """Make ``name`` receive the broadcasts (idempotent)."""
        i = self.index.get(name)
        if i is None:
            i = self.index[name] = len(self.names)
            self.names.append(name)
            if i >= len(self._attached):
                self._attached = np.concatenate([self._attached, np.zeros(len(self._attached), dtype=bool)])
        if not self._attached[i]:
            self._attached[i] = True
            self._n_attached += 1

    def detach(self, name: str) -> None:
        """Stop delivering to ``name`` (its copies in flight are discarded when due)."""
        i = self.index.get(name)
        if i is not None and self._attached[i]:
            self._attached[i] = False
            self._n_attached -= 1

    # -- sending --------------------------------------------------------------------------------
    def send(self, t_s: float, payload: Any, src_pos: np.ndarray, receivers: list[str], pos_m: np.ndarray) -> int:
        """Broadcast ``payload`` from ``src_pos`` (3,) [m] at ``t_s`` to the attached receivers: exactly
        ``receivers`` (any order), at ``pos_m`` (n, 3) [m] (a NaN row: not range checked).  Returns the
        copies put in flight."""
        n = len(receivers)
        if n != self._n_attached:
            raise ValueError(f"RsuBroadcast.send: {n} receivers given, {self._n_attached} attached")
        if n == 0:
            return 0
        index = self.index
        nodes = np.array([index[r] for r in receivers], dtype=np.int64)
        perm = np.argsort(nodes)  # node order (distinct indices)
        u = self._rng.random(2 * n)  # the general channel's random(n) for loss, then random(n) for delay
        keep, t_recv, counts = np.empty(n, dtype=bool), np.empty(n), self._counts
        broadcast_copies(pos_m, perm, src_pos, self._r2, u, self._p_loss, t_s + self.cfg.latency_s, self.cfg.jitter_s,
                         self._t_end_s + _T_EPS_S, keep, t_recv, counts)  # compiled (the general channel's bits)
        n_near, n_lost, n_late, k = counts.tolist()
        self._n_sent += n
        self._n_oor += n - n_near
        self._n_lost += n_lost
        self._n_late += n_late
        dst = nodes[perm]
        room = max(self.cfg.max_in_flight - self._n_in_flight, 0)
        if k > room:  # the newest beyond max_in_flight are dropped
            over = np.flatnonzero(keep)[room:]
            keep[over] = False
            self._n_overflow += over.size
            k = room
        self._n_in_flight += k
        if k:
            self._pending.append(Due(self._seq, payload, dst[keep], t_recv[keep]))
        self._seq += 1
        return k

    # -- delivery -------------------------------------------------------------------------------
    def deliver(self, t_s: float) -> list[Due]:
        """Pop every copy due by ``t_s`` to a receiver still attached, per broadcast in send order
        (``Channel.deliver_indexed``); copies to detached receivers are discarded."""
        pending = self._pending
        if not pending:
            self._n_in_flight = 0
            return []
        attached, t_due = self._attached, t_s + _T_EPS_S
        if len(pending) == 1:  # the usual case: the last step's broadcast
            b = pending[0]
            due = (b.t_recv_s <= t_due) & attached[b.dst_idx]
            if due.all():
                self._pending, self._n_in_flight = [], 0
                self._n_delivered += due.size
                return pending
        out: list[Due] = []
        keep: list[Due] = []
        n_rest = 0
        for b in pending:
            live = attached[b.dst_idx]
            due = (b.t_recv_s <= t_due) & live
            rest = ~due & live
            nd, nr = int(np.count_nonzero(due)), int(np.count_nonzero(rest))
            if nd:
                out.append(b if nd == due.size else Due(b.seq, b.payload, b.dst_idx[due], b.t_recv_s[due]))
            if nr:
                keep.append(b if nr == rest.size else Due(b.seq, b.payload, b.dst_idx[rest], b.t_recv_s[rest]))
            n_rest += nr
            self._n_delivered += nd
        self._pending, self._n_in_flight = keep, n_rest
        return out

    @property
    def in_flight(self) -> int:
        """Copies sent but not yet delivered."""
        return self._n_in_flight

    def stats(self) -> ChannelStats:
        """The general channel's counters (no age of information: NaN)."""
        return ChannelStats.counted(self._n_sent, self._n_delivered, self._n_lost, self._n_oor, self._n_late,
                                    self._n_overflow)


class GeneralBroadcast:
    """:class:`RsuBroadcast`'s interface on the general channel (any loss model, e.g. Gilbert-Elliott)."""

    def __init__(self, cfg: ChannelConfig, rng: np.random.Generator, t_end_s: float | None, sender: str) -> None:
        self.channel = Channel(cfg, rng, t_end_s=t_end_s, aoi=False)
        self.sender = sender
        self.attach, self.detach, self.stats = self.channel.attach, self.channel.detach, self.channel.stats

    @property
    def names(self) -> list[str]:
        return self.channel.node_names

    def send(self, t_s: float, payload: Any, src_pos: np.ndarray, receivers: list[str], pos_m: np.ndarray) -> int:
        self.channel.set_positions_arrays(receivers, pos_m)  # the receivers' positions: all a broadcast reads
        return self.channel.send(t_s, self.sender, payload, src_pos)

    @property
    def in_flight(self) -> int:
        return self.channel.in_flight

    def deliver(self, t_s: float) -> list[Due]:
        return [Due(b.seq, b.payload, b.dst_idx, b.t_recv_s) for b in self.channel.deliver_indexed(t_s)]


def rsu_broadcast(cfg: ChannelConfig, rng: np.random.Generator, t_end_s: float | None,
                  sender: str) -> RsuBroadcast | GeneralBroadcast:
    """The lean broadcast under Bernoulli loss, else the general channel behind the same interface."""
    if isinstance(cfg.loss, BernoulliLoss):
        return RsuBroadcast(cfg, rng, t_end_s)
    return GeneralBroadcast(cfg, rng, t_end_s, sender)


def newest_per_receiver(due: list[Due], names: list[str], latest: dict[str, Any]) -> None:
    """Set ``latest[receiver]`` to the payload each receiver got last in ``Channel.deliver``'s order
    (delivery time, sender, receiver, send order) from one sender's ``due`` broadcasts (send order; one
    copy per receiver and broadcast): the copy with the latest delivery time, the later sent on a tie."""
    if len(due) == 1:  # the usual case: one broadcast due
        payload = due[0].payload
        for i in due[0].dst_idx.tolist():
            latest[names[i]] = payload
        return
    best: dict[int, tuple[float, int]] = {}
    for b, batch in enumerate(due):
        for i, tr in zip(batch.dst_idx.tolist(), batch.t_recv_s.tolist(), strict=True):
            if i not in best or (tr, b) >= best[i]:
                best[i] = (tr, b)
    for i, (_, b) in best.items():
        latest[names[i]] = due[b].payload


__all__ = ["Due", "GeneralBroadcast", "RsuBroadcast", "newest_per_receiver", "rsu_broadcast"]
