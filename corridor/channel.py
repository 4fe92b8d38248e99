"""A generic lossy, delayed, range-limited broadcast channel (V2X CAMs, MAVLink bytes, anything).

The channel models what a controller can know: a message sent at ``t_s`` arrives at each attached
receiver after ``latency_s + U(0, jitter_s)`` seconds, unless the receiver is out of range or the
per-link loss model drops it.  It carries any payload (a dataclass, ``bytes``) and never inspects it.

Model choices (written down because metrics depend on them):

- **Jitter** is uniform: ``delay = latency_s + U(0, jitter_s)``, so the mean delay is
  ``latency_s + jitter_s / 2`` and the delay lies in ``[latency_s, latency_s + jitter_s]``.
  Messages of one link may therefore overtake each other (as on a real radio with retries).
  ``latency_s`` and ``jitter_s`` are at most ``MAX_DELAY_S`` (60 s), checked at scenario load.
- **What can never arrive is dropped at send.** A channel built with the run's end ``t_end_s`` drops
  copies whose arrival time lies after it (``dropped_after_end``: nothing could read them), and at
  most ``max_in_flight`` copies are in flight: beyond, new copies are dropped (``dropped_overflow``).
  Both drops happen after the loss and delay draws, so they never change another copy's fate; a
  copy dropped after the end would not have been delivered within the run either, so the other
  statistics are the same as without the drop.
- **Range** is a disc (sphere in 3-D) of radius ``range_m`` around the sender, checked against
  positions known at send time (``set_positions`` each tick).  When the sender's or a receiver's
  position is unknown, that copy is not range checked.
- **Loss** is decided independently per directed link ``(src, dst)`` and per message copy:
  Bernoulli with probability ``p``, or a Gilbert–Elliott two-state Markov chain per link.  The chain
  starts in the good state and advances one step per in-range copy on that link *before* the loss
  draw (state of message k = state after k transitions); out-of-range copies do not advance it.
  With ``loss_good=0, loss_bad=1`` the loss bursts are geometric with mean ``1 / p_bad_to_good``
  and the stationary loss is ``p_gb / (p_gb + p_bg)``.
- **Delivery** (``deliver(t_s)``) pops every copy with ``t_recv <= t_s`` (1e-9 s tolerance against
  float round-off of ``t + latency``), sorted by ``(t_recv, src, dst, send order)`` (names compared
  as strings).  Copies for a
  receiver detached meanwhile are discarded (not counted as delivered).  ``deliver_batches(t_s)``
  pops the same copies grouped by sent message (send order; one payload, its receivers and their
  arrival times), for consumers that handle a broadcast once rather than copy by copy; sorting its
  copies by the key above gives ``deliver``'s list.  Statistics and inboxes are the same either way.
- **Age of information** (AoI): for every ordered pair (receiver, source) with at least one received
  message, and at every ``deliver(t_s)`` call *after* that call's deliveries, the sample is
  ``t_s - (send time of the newest message the receiver has from that source)``.  ``aoi_mean_s`` is
  the mean over all samples, ``aoi_max_s`` their maximum.  Detaching a node forgets its pairs both as
  receiver and as source (a vehicle that left no longer ages).  A channel built with ``aoi=False``
  keeps none of it (both NaN): a consumer that measures its own age of information skips the
  per-pair matrix work of every delivery.

Determinism: all randomness comes from the ``numpy.random.Generator`` passed in; every ``send``
draws a fixed number of arrays (loss and jitter uniforms over its receiver set, plus the
Gilbert–Elliott transition uniforms over its in-range copies), so identical call sequences with
identical seeds give identical deliveries.

Performance: receivers live in numpy arrays; one broadcast computes range, loss and delay for all
receivers at once, and the Gilbert–Elliott states are an N×N boolean matrix indexed by node.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, NamedTuple, TypeGuard, cast

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

_T_EPS_S = 1e-9  # [s] tolerance of the delivery time comparison
DELIVERY_TOLERANCE_S = _T_EPS_S  # public: a copy whose delay exceeds it is never due when it is sent
MAX_DELAY_S = 60.0  # [s] upper bound of latency_s and jitter_s: no radio link of a scenario is slower
DEFAULT_MAX_IN_FLIGHT = 1_000_000  # copies; beyond, new copies are dropped (``dropped_overflow``)


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class BernoulliLoss(_Frozen):
    """Independent loss of every message copy with probability ``p``."""

    model: Literal["bernoulli"] = "bernoulli"
    p: float = Field(0.0, ge=0.0, le=1.0)


class GilbertElliottLoss(_Frozen):
    """Bursty loss: a two-state (good/bad) Markov chain per link, advanced once per message copy."""

    model: Literal["gilbert_elliott"] = "gilbert_elliott"
    p_good_to_bad: float = Field(ge=0.0, le=1.0)
    p_bad_to_good: float = Field(gt=0.0, le=1.0)
    loss_good: float = Field(0.0, ge=0.0, le=1.0)
    loss_bad: float = Field(1.0, ge=0.0, le=1.0)

    def stationary_loss(self) -> float:
        """Long-run loss probability: pi_bad * loss_bad + pi_good * loss_good."""
        pi_bad = self.p_good_to_bad / (self.p_good_to_bad + self.p_bad_to_good)
        return pi_bad * self.loss_bad + (1.0 - pi_bad) * self.loss_good


LossModel = Annotated[BernoulliLoss | GilbertElliottLoss, Field(discriminator="model")]


class ChannelConfig(_Frozen):
    """Channel parameters as they appear in a scenario (``v2x.channel`` / ``uav.link``)."""

    range_m: float = Field(300.0, gt=0.0)  # [m] communication radius
    latency_s: float = Field(0.02, ge=0.0)  # [s] fixed part of the delay
    jitter_s: float = Field(0.01, ge=0.0)  # [s] width of the uniform random part of the delay
    loss: LossModel = BernoulliLoss(p=0.0)
    rate_hz: float = Field(10.0, gt=0.0, le=1000.0)  # [Hz] nominal message rate of periodic senders
    max_in_flight: int = Field(DEFAULT_MAX_IN_FLIGHT, ge=1, le=100_000_000)  # copies in flight at most

    @field_validator("latency_s", "jitter_s")
    @classmethod
    def _plausible_delay(cls, v: float) -> float:
        if v > MAX_DELAY_S:
            raise ValueError(f"must be at most {MAX_DELAY_S:g} s (got {v:g} s)")
        return v

    @property
    def period_s(self) -> float:
        """Nominal period of periodic senders [s]."""
        return 1.0 / self.rate_hz

    def mean_delay_s(self) -> float:
        """Expected delay of a delivered message [s]."""
        return self.latency_s + 0.5 * self.jitter_s


class DeliveredBatch(NamedTuple):
    """The copies of one sent message that reached their receivers in one ``deliver_batches`` call."""

    src: str
    t_sent_s: float  # [s]
    payload: Any
    dst: list[str]  # receivers (one copy each)
    t_recv_s: list[float]  # [s] per receiver
    seq: int  # send order (ties in deliver's ordering)


class IndexedBatch(NamedTuple):
    """A :class:`DeliveredBatch` with its receivers as node indices (``node_names``) in arrays.

    No per-copy Python object: a swarm's broadcasts are N^2 copies per tick.
    """

    src: str
    src_idx: int  # node index of the sender
    t_sent_s: float  # [s]
    payload: Any
    dst_idx: np.ndarray  # node indices of the receivers (one copy each)
    t_recv_s: np.ndarray  # [s] per receiver
    seq: int  # send order


class Delivery(NamedTuple):
    """One message copy that reached receiver ``dst`` (a NamedTuple: cheap to create in bulk)."""

    src: str
    dst: str
    t_sent_s: float  # [s]
    t_recv_s: float  # [s]
    payload: Any


@dataclass(frozen=True)
class ChannelStats:
    """Per-run channel statistics (see the module docstring for the exact definitions).

    ``sent`` counts addressed copies (one per attached receiver other than the sender);
    ``delivery_ratio`` is ``delivered / (sent - out_of_range)``, i.e. over copies in range.
    """

    sent: int
    delivered: int
    lost_random: int
    out_of_range: int
    delivery_ratio: float
    aoi_mean_s: float
    aoi_max_s: float
    dropped_after_end: int = 0  # copies that would have arrived after the run's end
    dropped_overflow: int = 0  # copies dropped because ``max_in_flight`` copies were in flight

    @classmethod
    def counted(cls, sent: int, delivered: int, lost: int, out_of_range: int, late: int, overflow: int) -> ChannelStats:
        """Statistics of a channel that keeps no age of information (NaN)."""
        in_range = sent - out_of_range
        return cls(sent=sent, delivered=delivered, lost_random=lost, out_of_range=out_of_range,
                   delivery_ratio=delivered / in_range if in_range else float("nan"), aoi_mean_s=float("nan"),
                   aoi_max_s=float("nan"), dropped_after_end=late, dropped_overflow=overflow)

    def as_dict(self, prefix: str = "") -> dict[str, float]:
        """Flat dict for a results row, e.g. ``prefix="v2x_"``."""
        return {prefix + k: float(v) for k, v in self.__dict__.items()}


@dataclass
class _Batch:
    """Copies of one sent message still in flight (struct of arrays over receivers)."""

    seq: int
    src: str
    src_idx: int
    t_sent_s: float
    payload: Any
    dst_idx: np.ndarray  # node indices
    t_recv_s: np.ndarray  # [s]


class Channel:
    """Broadcast/unicast channel with range, latency + jitter and per-link loss.

    Typical tick: ``set_positions(...)``; senders call ``send(...)``; then ``deliver(t_s)`` once and
    each receiver reads ``inbox(its_id)``.
    """

    def __init__(self, cfg: ChannelConfig, rng: np.random.Generator, t_end_s: float | None = None,
                 aoi: bool = True) -> None:
        """A channel drawing from ``rng``.

        ``t_end_s`` [s]: the run's end; copies arriving later are dropped at send (None: never).
        ``aoi`` False: no age-of-information bookkeeping (``stats()`` reports it as NaN), for a consumer
        that keeps its own; nothing else changes (the draws, deliveries and other statistics).
        """
        self.cfg = cfg
        self._aoi_on = aoi
        self._rng = rng
        self._t_end_s = math.inf if t_end_s is None else float(t_end_s)
        self._n_in_flight = 0
        self._n_late = self._n_overflow = 0
        self._index: dict[str, int] = {}
        self._names: list[str] = []
        self._cap = 0
        self._attached = np.zeros(0, dtype=bool)  # by node index
        self._ge_bad = np.zeros((0, 0), dtype=bool)  # [src, dst] Gilbert–Elliott state
        self._last_sent = np.zeros((0, 0))  # [dst, src] newest received send time, NaN = none
        self._has_col = np.zeros(0, dtype=bool)  # [src] a column of _last_sent that may hold a time
        self._positions: dict[str, np.ndarray] = {}
        self._pos_floats: dict[str, list[float]] | None = None  # the same positions as float lists (on demand)
        self._recv_idx = np.zeros(0, dtype=np.int64)  # attached receivers, attach order
        self._recv_row = np.zeros(0, dtype=np.int64)  # node index -> its row in _recv_idx (-1: none)
        self._recv_pos = np.zeros((0, 3))  # [m], NaN rows = unknown
        self._recv_dirty = True
        self._pending: list[_Batch] = []
        self._seq = 0
        self._inboxes: dict[str, list[Delivery]] | None = {}  # None: built from _last on demand
        self._last: tuple[list[_Batch], list[tuple[np.ndarray, np.ndarray]]] = ([], [])
        self._rank = np.zeros(0, dtype=np.int64)  # lexicographic rank of node names
        self._n_sent = self._n_delivered = self._n_lost = self._n_oor = 0
        self._aoi_sum_s = 0.0
        self._aoi_count = 0
        self._aoi_max_s = 0.0

    # -- membership and positions -------------------------------------------------------------
    def attach(self, receiver_id: str) -> None:
        """Make ``receiver_id`` receive broadcasts (idempotent)."""
        i = self._node(receiver_id)
        if not self._attached[i]:
            self._attached[i] = True
            self._recv_dirty = True

    def detach(self, receiver_id: str) -> None:
        """Stop delivering to ``receiver_id`` and forget its age-of-information pairs."""
        i = self._index.get(receiver_id)
        if i is None:
            return
        self._attached[i] = False
        self._last_sent[i, :] = np.nan
        self._last_sent[:, i] = np.nan
        self._has_col[i] = False
        self._recv_dirty = True

    @property
    def receivers(self) -> list[str]:
        """Currently attached receivers."""
        return [self._names[i] for i in np.flatnonzero(self._attached)]

    def set_positions(self, positions: Mapping[str, np.ndarray]) -> None:
        """Positions [m] (2-D or 3-D, local frame) used for range checks of the following sends."""
        self._positions = {k: _as3(v) for k, v in positions.items()}
        self._pos_floats = None
        self._recv_dirty = True

    def set_positions_arrays(self, ids: Iterable[str], pos_m: np.ndarray) -> None:
        """Same as ``set_positions`` from a snapshot's struct of arrays (ids[N], position[N, 2|3])."""
        pos = np.asarray(pos_m, dtype=float)
        if pos.ndim == 2 and pos.shape[1] == 3:  # each row is already the float 3-vector ``_as3`` makes
            ids = list(ids)
            self._positions = dict(zip(ids, pos, strict=True))
            self._pos_floats = dict(zip(ids, pos.tolist()))  # one conversion for the addressed sends
            self._recv_dirty = True
            return
        self.set_positions(dict(zip(ids, pos, strict=True)))

    # -- sending --------------------------------------------------------------------------------
    def send(
        self,
        t_s: float,
        src: str,
        payload: Any,
        src_pos: np.ndarray | None = None,
        dst: str | None = None,
    ) -> int:
        """Send ``payload`` from ``src`` at ``t_s``; broadcast unless ``dst`` is given.

        Returns the number of copies put in flight (after range and loss).
        """
        self._refresh_receivers()
        src_idx = self._node(src)
        dst_idx, dst_pos = self._targets(src_idx, dst)
        n = dst_idx.size
        if n == 0:
            return 0
        p_src = _as3(src_pos) if src_pos is not None else self._positions.get(src)
        in_range = self._in_range(p_src, dst_pos)
        u_loss = self._rng.random(n)
        u_delay = self._rng.random(n)
        lost = self._draw_loss(src_idx, dst_idx, in_range, u_loss)
        keep = in_range & ~lost
        self._n_sent += n
        self._n_oor += int(n - in_range.sum())
        self._n_lost += int(lost.sum())
        t_recv = t_s + self.cfg.latency_s + self.cfg.jitter_s * u_delay
        keep = self._admit(keep, t_recv)
        if keep.any():
            self._pending.append(_Batch(self._seq, src, src_idx, float(t_s), payload, dst_idx[keep], t_recv[keep]))
        self._seq += 1
        return int(keep.sum())

    def send_many(
        self, t_s: float, messages: Iterable[tuple[str, Any, np.ndarray | None, str | Sequence[str] | None]]
    ) -> list[int]:
        """``send(t_s, src, payload, src_pos, dst)`` for each ``(src, payload, src_pos, dst)`` in order.

        The same random draws, statistics and result as one ``send`` each; under Bernoulli loss the messages
        (broadcasts of a fleet's periodic reports, unicasts, or both mixed) are handled in one
        vectorised pass instead of message by message.

        ``dst`` may also be a sequence of receivers (a multicast): the same as one unicast ``send``
        per listed receiver, in order (the same draws and statistics), but the copies put in flight
        form one sent message (one batch of ``deliver_batches``, one send order) and the result is
        their total.
        """
        orig = list(messages)
        # per entry, the receivers of its messages (None: a broadcast); a multicast is one message per receiver
        dsts = [_receivers(m[3]) for m in orig]
        group = np.repeat(np.arange(len(orig)), [len(d) for d in dsts])  # the entry of each message
        if not isinstance(self.cfg.loss, BernoulliLoss):
            sent = [self.send(t_s, src, payload, src_pos=pos, dst=d)
                    for (src, payload, pos, _), ds in zip(orig, dsts, strict=True) for d in ds]
            totals: list[int] = np.bincount(group, weights=sent, minlength=len(orig)).astype(int).tolist()
            return totals
        if not group.size:
            return [0] * len(orig)
        if all(d is not None for ds in dsts for d in ds):  # every receiver named (unicasts, multicasts)
            addressed = self._send_addressed(t_s, orig, dsts)
            if addressed is not None:
                return addressed
        self._refresh_receivers()
        src_entry = np.array([self._node(m[0]) for m in orig])
        nan3 = np.full(3, np.nan)  # unknown sender position: no range check (as in send)
        p_entry = _rows3([pos if pos is not None else self._positions.get(src, nan3) for src, _, pos, _ in orig])
        src_idx, p_src = src_entry[group], p_entry[group]
        flat = [d for ds in dsts for d in ds]
        if None in flat:
            msg, counts, dst_idx, in_range = self._copies_mixed(src_idx, p_src, flat)
            n = len(msg)
            # send() draws random(n_i) for loss, then random(n_i) for delay, message after message
            u = self._rng.random(2 * n)
            start = np.cumsum(counts) - counts
            pos_in_msg = np.arange(n) - start[msg]
            u_loss, u_delay = u[2 * start[msg] + pos_in_msg], u[2 * start[msg] + counts[msg] + pos_in_msg]
        else:  # a unicast is at most one copy: its loss and delay uniforms are the next two
            msg, _, dst_idx, in_range = self._copies_unicast(src_idx, p_src, cast(list[str], flat))
            n = len(msg)
            u = self._rng.random(2 * n)
            u_loss, u_delay = u[0::2], u[1::2]
        lost = in_range & (u_loss < self.cfg.loss.p)
        keep = in_range & ~lost
        t_recv = t_s + self.cfg.latency_s + self.cfg.jitter_s * u_delay
        self._n_sent += n
        self._n_oor += int(n - np.count_nonzero(in_range))
        self._n_lost += int(np.count_nonzero(lost))
        keep = self._admit(keep, t_recv)
        kept_dst, kept_t = dst_idx[keep], t_recv[keep]  # message-major: one slice per entry
        counts_g = np.bincount(group[msg], minlength=len(orig)).tolist()  # copies per entry
        kept_g = np.bincount(group[msg[keep]], minlength=len(orig)).tolist()
        return self._enqueue(t_s, orig, src_entry.tolist(), counts_g, kept_g, kept_dst, kept_t)

    def _send_addressed(self, t_s: float, orig: list[tuple[str, Any, np.ndarray | None, Any]],
                        dsts: list[Sequence[str | None]]) -> list[int] | None:
        """``send_many`` under Bernoulli loss when every receiver is named (no broadcast).

        The copies are found in Python floats, entry by entry (a tick's few dozen copies cost less so
        than the (messages x receivers) arrays and the receivers' position table), then drawn and put
        in flight as the array path does: the same copies in the same order, the same draws, the same
        bits (the squared distance summed x, y, z in that order, as numpy's row sum of three).  None:
        a sender position that is not a float 3-vector (the array path handles it).
        """
        src_entry = [self._node(m[0]) for m in orig]
        index, attached, positions = self._index, self._attached, self._positions
        floats = self._pos_floats
        if floats is None:
            floats = self._pos_floats = {k: v.tolist() for k, v in positions.items()}
        r2 = self.cfg.range_m ** 2
        entry_of: list[int] = []  # per copy: its entry, receiver node, range flag
        dst_idx: list[int] = []
        in_range: list[bool] = []
        counts = [0] * len(orig)
        for e, ((src, _, pos, _), ds, si) in enumerate(zip(orig, dsts, src_entry, strict=True)):
            p = positions.get(src) if pos is None else pos
            if p is None:
                sx = sy = sz = math.nan
            elif type(p) is np.ndarray and p.shape == (3,) and p.dtype == np.float64:
                sx, sy, sz = p.tolist()
            else:
                return None
            for d in ds:
                j = index.get(d, -1)  # type: ignore[arg-type]
                if j < 0 or j == si or not attached[j]:
                    continue
                q = floats.get(d)  # type: ignore[arg-type]
                if q is None:
                    near = True  # unknown position: not range checked
                else:
                    qx, qy, qz = q
                    dx, dy, dz = qx - sx, qy - sy, qz - sz
                    d2 = dx * dx + dy * dy + dz * dz
                    near = d2 != d2 or d2 <= r2  # NaN: not range checked
                entry_of.append(e)
                dst_idx.append(j)
                in_range.append(near)
                counts[e] += 1
        n = len(dst_idx)
        u = self._rng.random(2 * n)  # a unicast's loss and delay uniforms are the next two
        near_a = np.array(in_range, dtype=bool)
        lost = near_a & (u[0::2] < cast(BernoulliLoss, self.cfg.loss).p)  # the caller sends here only with Bernoulli loss
        t_recv = t_s + self.cfg.latency_s + self.cfg.jitter_s * u[1::2]
        n_near = sum(in_range)
        self._n_sent += n
        self._n_oor += n - n_near
        self._n_lost += int(np.count_nonzero(lost))
        keep = self._admit(near_a & ~lost, t_recv)
        kept_dst, kept_t = np.array(dst_idx, dtype=np.int64)[keep], t_recv[keep]
        kept_g = np.bincount(np.array(entry_of, dtype=np.int64)[keep], minlength=len(orig)).tolist()
        return self._enqueue(t_s, orig, src_entry, counts, kept_g, kept_dst, kept_t)

    def _enqueue(self, t_s: float, orig: list[tuple[str, Any, Any, Any]], src_entry: list[int], counts_g: list[int],
                 kept_g: list[int], kept_dst: np.ndarray, kept_t: np.ndarray) -> list[int]:
        """One in-flight batch per entry with kept copies (message-major ``kept_dst`` / ``kept_t``).

        An entry with copies takes a send order; returns the copies kept per entry.
        """
        out = []
        t_sent, a = float(t_s), 0
        for c, k, si, (src, payload, _, _) in zip(counts_g, kept_g, src_entry, orig, strict=True):
            if c == 0:
                out.append(0)
                continue
            if k:
                self._pending.append(_Batch(self._seq, src, si, t_sent, payload, kept_dst[a : a + k], kept_t[a : a + k]))
                a += k
            self._seq += 1
            out.append(k)
        return out

    def _copies_mixed(self, src_idx: np.ndarray, p_src: np.ndarray, dst: list[str | None]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The copies of messages sent from nodes ``src_idx`` at ``p_src`` (M, 3) [m] to ``dst``.

        ``dst`` None is a broadcast. Message-major: their message, copies per message, receiver node
        and range flag.
        """
        recv = self._recv_idx[None, :]
        mask = recv != src_idx[:, None]  # (M, R): every receiver but the sender
        if any(d is not None for d in dst):  # a unicast goes to its receiver, if attached (send's
            #   ``_targets``): the one column of the receivers that is that node (none if detached or unknown)
            to = np.array([-1 if d is None else self._index.get(d, -2) for d in dst])
            uni = to != -1
            mask[uni] &= recv == to[uni, None]
        msg, col = np.nonzero(mask)
        d2 = np.sum((self._recv_pos[None, :, :] - p_src[:, None, :]) ** 2, axis=2)
        in_range = (np.isnan(d2) | (d2 <= self.cfg.range_m**2))[msg, col]
        return msg, np.bincount(msg, minlength=len(dst)), self._recv_idx[col], in_range

    def _copies_unicast(self, src_idx: np.ndarray, p_src: np.ndarray, dst: list[str]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_copies_mixed` when every message is a unicast.

        At most one copy each, found without the (messages x receivers) matrices.
        """
        to = np.array([self._index.get(d, -1) for d in dst])
        ok = (to >= 0) & (to != src_idx)  # a known receiver other than the sender ...
        ok[ok] = self._attached[to[ok]]  # ... that is attached (send's ``_targets``)
        msg = np.flatnonzero(ok)
        dst_idx = to[msg]
        d2 = np.sum((self._recv_pos[self._recv_row[dst_idx]] - p_src[msg]) ** 2, axis=1)
        return msg, ok.astype(np.int64), dst_idx, np.isnan(d2) | (d2 <= self.cfg.range_m**2)

    def _admit(self, keep: np.ndarray, t_recv: np.ndarray) -> np.ndarray:
        """The copies of ``keep`` that go in flight.

        Those arriving after the run's end are dropped, and beyond ``max_in_flight`` copies in flight
        the newest are (both counted).
        """
        late = keep & (t_recv > self._t_end_s + _T_EPS_S)
        if late.any():
            self._n_late += int(late.sum())
            keep = keep & ~late
        n = int(keep.sum())
        room = max(self.cfg.max_in_flight - self._n_in_flight, 0)
        if n > room:
            over = np.flatnonzero(keep)[room:]
            keep = keep.copy()
            keep[over] = False
            self._n_overflow += over.size
            n = room
        self._n_in_flight += n
        return keep

    def _targets(self, src_idx: int, dst: str | None) -> tuple[np.ndarray, np.ndarray]:
        """Receiver node indices and positions of one send (sender excluded)."""
        if dst is None:
            mask = self._recv_idx != src_idx
            return self._recv_idx[mask], self._recv_pos[mask]
        j = self._index.get(dst)
        if j is None or not self._attached[j] or j == src_idx:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        pos = self._positions.get(dst, np.full(3, np.nan))
        return np.array([j]), pos[None, :]

    def _in_range(self, p_src: np.ndarray | None, dst_pos: np.ndarray) -> np.ndarray:
        if p_src is None:
            return np.ones(len(dst_pos), dtype=bool)
        d2 = np.sum((dst_pos - p_src) ** 2, axis=1)
        near: np.ndarray = np.isnan(d2) | (d2 <= self.cfg.range_m**2)
        return near

    def _draw_loss(
        self, src_idx: int, dst_idx: np.ndarray, in_range: np.ndarray, u: np.ndarray
    ) -> np.ndarray:
        """Loss flags of the in-range copies (out-of-range copies are never 'lost')."""
        loss = self.cfg.loss
        if isinstance(loss, BernoulliLoss):
            return in_range & (u < loss.p)
        links = dst_idx[in_range]
        bad = self._ge_bad[src_idx, links]
        u_t = self._rng.random(links.size)
        bad = np.where(bad, u_t >= loss.p_bad_to_good, u_t < loss.p_good_to_bad)
        self._ge_bad[src_idx, links] = bad
        p_loss = np.where(bad, loss.loss_bad, loss.loss_good)
        lost = np.zeros(dst_idx.size, dtype=bool)
        lost[in_range] = u[in_range] < p_loss
        return lost

    # -- delivery -------------------------------------------------------------------------------
    def deliver(self, t_s: float) -> list[Delivery]:
        """Pop every copy with ``t_recv <= t_s``, deterministically ordered; refresh the inboxes."""
        due_batches, due_parts = self._pop_due(t_s)
        out = self._materialise(due_batches, due_parts)
        self._n_delivered += len(out)
        self._record_received(due_batches, due_parts)
        self._inboxes = self.group_by_dst(out)
        self._sample_aoi(t_s)
        return out

    def deliver_batches(self, t_s: float) -> list[DeliveredBatch]:
        """The copies ``deliver(t_s)`` would return, grouped by sent message in send order.

        See the module docstring; the same statistics, age of information and inboxes.
        """
        names = self._names
        return [DeliveredBatch(b.src, b.t_sent_s, b.payload, [names[i] for i in b.dst_idx.tolist()],
                               b.t_recv_s.tolist(), b.seq) for b in self.deliver_indexed(t_s)]

    def deliver_indexed(self, t_s: float) -> list[IndexedBatch]:
        """:meth:`deliver_batches` with node indices and arrays (see :class:`IndexedBatch`)."""
        due_batches, due_parts = self._pop_due(t_s)
        self._n_delivered += sum(d.size for d, _ in due_parts)
        self._record_received(due_batches, due_parts)
        self._inboxes, self._last = None, (due_batches, due_parts)
        self._sample_aoi(t_s)
        return [IndexedBatch(b.src, b.src_idx, b.t_sent_s, b.payload, d, t, b.seq)
                for b, (d, t) in zip(due_batches, due_parts, strict=True)]

    def node_index(self, name: str) -> int:
        """Index of node ``name`` in :attr:`node_names` (registered on first use)."""
        return self._node(name)

    @property
    def node_names(self) -> list[str]:
        """Every node (sender or receiver) the channel knows, by index."""
        return self._names

    def _pop_due(self, t_s: float) -> tuple[list[_Batch], list[tuple[np.ndarray, np.ndarray]]]:
        """Remove and return the due copies (batches in send order, with their due receivers/times).

        The due / still-live flags of every copy in flight are computed in one pass; a batch is only
        cut into new arrays when part of it is due (or part of it went to a detached receiver).
        """
        pending = self._pending
        if not pending:
            self._n_in_flight = 0
            return [], []
        sizes = [b.dst_idx.size for b in pending]
        dst = np.concatenate([b.dst_idx for b in pending])
        t_recv = np.concatenate([b.t_recv_s for b in pending])
        live = self._attached[dst]
        due = (t_recv <= t_s + _T_EPS_S) & live
        if due.all():  # every copy in flight is due (a delay below the tick): no batch is cut
            self._pending, self._n_in_flight = [], 0
            return pending, [(b.dst_idx, b.t_recv_s) for b in pending]
        rest = ~due & live
        starts: np.ndarray = np.cumsum(sizes) - sizes
        n_due = np.add.reduceat(due, starts).tolist()
        n_rest = np.add.reduceat(rest, starts).tolist()
        due_batches: list[_Batch] = []
        due_parts: list[tuple[np.ndarray, np.ndarray]] = []
        keep: list[_Batch] = []
        for b, size, a, nd, nr in zip(pending, sizes, starts.tolist(), n_due, n_rest, strict=True):
            if nd:
                due_batches.append(b)
                sel = due[a : a + size]
                due_parts.append((b.dst_idx, b.t_recv_s) if nd == size else (b.dst_idx[sel], b.t_recv_s[sel]))
            if nr == size:
                keep.append(b)
            elif nr:
                sel = rest[a : a + size]
                keep.append(_Batch(b.seq, b.src, b.src_idx, b.t_sent_s, b.payload, b.dst_idx[sel], b.t_recv_s[sel]))
        self._pending = keep
        self._n_in_flight = int(np.count_nonzero(rest))
        return due_batches, due_parts

    def _record_received(self, batches: list[_Batch], parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """Newest received send time per (receiver, source): the age-of-information state."""
        if not batches or not self._aoi_on:
            return
        counts = [d.size for d, _ in parts]
        dst = np.concatenate([d for d, _ in parts])
        src = np.repeat([b.src_idx for b in batches], counts)
        t_sent = np.repeat([b.t_sent_s for b in batches], counts)
        np.fmax.at(self._last_sent, (dst, src), t_sent)
        self._has_col[src] = True

    def _materialise(
        self, batches: list[_Batch], parts: list[tuple[np.ndarray, np.ndarray]]
    ) -> list[Delivery]:
        """Delivery objects sorted by (t_recv, src name, dst name, send order)."""
        if not batches:
            return []
        counts = [d.size for d, _ in parts]
        batch_of = np.repeat(np.arange(len(batches)), counts)
        dst = np.concatenate([d for d, _ in parts])
        t_recv = np.concatenate([t for _, t in parts])
        src = np.array([b.src_idx for b in batches])[batch_of]
        rank = self._name_rank()
        order = np.lexsort((batch_of, rank[dst], rank[src], t_recv))
        names = self._names
        return [
            Delivery(batches[bi].src, names[di], batches[bi].t_sent_s, tr, batches[bi].payload)
            for bi, di, tr in zip(batch_of[order].tolist(), dst[order].tolist(), t_recv[order].tolist())
        ]

    def _name_rank(self) -> np.ndarray:
        """Lexicographic rank of every node name (for the deterministic delivery order)."""
        if self._rank.size != len(self._names):
            self._rank = np.argsort(np.argsort(np.array(self._names, dtype=object), kind="stable"))
        return self._rank

    def inbox(self, dst: str) -> list[Delivery]:
        """Deliveries to ``dst`` from the latest ``deliver`` (or ``deliver_batches``) call."""
        if self._inboxes is None:
            self._inboxes = self.group_by_dst(self._materialise(*self._last))
            self._last = ([], [])
        return self._inboxes.get(dst, [])

    @staticmethod
    def group_by_dst(deliveries: Iterable[Delivery]) -> dict[str, list[Delivery]]:
        """Group deliveries by receiver, keeping their order."""
        groups: dict[str, list[Delivery]] = {}
        for d in deliveries:
            groups.setdefault(d.dst, []).append(d)
        return groups

    @property
    def in_flight(self) -> int:
        """Copies sent but not yet delivered."""
        return self._n_in_flight

    # -- statistics -----------------------------------------------------------------------------
    def stats(self) -> ChannelStats:
        """Counters and age of information so far."""
        in_range = self._n_sent - self._n_oor
        return ChannelStats(
            sent=self._n_sent,
            delivered=self._n_delivered,
            lost_random=self._n_lost,
            out_of_range=self._n_oor,
            delivery_ratio=self._n_delivered / in_range if in_range else float("nan"),
            aoi_mean_s=self._aoi_sum_s / self._aoi_count if self._aoi_count else float("nan"),
            aoi_max_s=self._aoi_max_s if self._aoi_count else float("nan"),
            dropped_after_end=self._n_late,
            dropped_overflow=self._n_overflow,
        )

    def _sample_aoi(self, t_s: float) -> None:
        if not self._aoi_on:
            return
        # only attached receivers hold received times (detach clears a node's row and column), and only
        # the columns of sources with a received time (``_has_col``): their block gives the same values
        # in the same (row-major) order as the whole matrix
        rows = self._last_sent[np.ix_(np.flatnonzero(self._attached), np.flatnonzero(self._has_col))]
        known = rows[~np.isnan(rows)]
        if known.size == 0:
            return
        ages = t_s - known
        self._aoi_sum_s += float(ages.sum())
        self._aoi_count += int(ages.size)
        self._aoi_max_s = max(self._aoi_max_s, float(ages.max()))

    # -- node bookkeeping -----------------------------------------------------------------------
    def _node(self, name: str) -> int:
        i = self._index.get(name)
        if i is not None:
            return i
        i = len(self._names)
        self._index[name] = i
        self._names.append(name)
        if i >= self._cap:
            self._grow(max(16, 2 * self._cap))
        return i

    def _grow(self, cap: int) -> None:
        n = self._cap
        attached = np.zeros(cap, dtype=bool)
        attached[:n] = self._attached
        ge = np.zeros((cap, cap), dtype=bool)
        ge[:n, :n] = self._ge_bad
        last = np.full((cap, cap), np.nan)
        last[:n, :n] = self._last_sent
        has_col = np.zeros(cap, dtype=bool)
        has_col[:n] = self._has_col
        self._attached, self._ge_bad, self._last_sent, self._cap = attached, ge, last, cap
        self._has_col = has_col

    def _refresh_receivers(self) -> None:
        if not self._recv_dirty:
            return
        idx = np.flatnonzero(self._attached)
        nan3 = np.full(3, np.nan)
        self._recv_idx = idx
        self._recv_row = np.full(len(self._attached), -1, dtype=np.int64)  # node -> row of _recv_pos
        self._recv_row[idx] = np.arange(len(idx))
        self._recv_pos = np.array([self._positions.get(self._names[i], nan3) for i in idx]).reshape(-1, 3)
        self._recv_dirty = False


def _is_multi(dst: object) -> TypeGuard[Sequence[str]]:
    """A multicast destination: a sequence of receiver names (a plain name is a unicast)."""
    return isinstance(dst, list | tuple)


def _receivers(dst: str | Sequence[str] | None) -> Sequence[str | None]:
    """The receivers of one ``send_many`` entry: a multicast's names, else the one (``None``: broadcast)."""
    return dst if _is_multi(dst) else (cast(str | None, dst),)


def _rows3(points: list[Any]) -> np.ndarray:
    """Positions as an (M, 3) float array, each row as ``_as3`` makes it (2-D points get z = 0)."""
    try:
        a = np.array(points, dtype=float) if points else np.zeros((0, 3))
    except ValueError:  # mixed lengths
        a = np.zeros(0)
    if a.ndim == 2 and a.shape[1] == 3:
        return a
    if a.ndim == 2 and a.shape[1] == 2:
        return np.column_stack([a, np.zeros(len(a))])
    return np.array([_as3(p) for p in points]).reshape(-1, 3)


def _as3(p: np.ndarray | Iterable[float]) -> np.ndarray:
    """A position as a float 3-vector (2-D positions get z = 0)."""
    a = np.asarray(p, dtype=float).ravel()
    return a if a.size == 3 else np.concatenate([a, np.zeros(3 - a.size)])
