"""The compiled addressed channel (corridor.addressed_channel) delivers what the general channel's
``send_many`` / ``deliver_indexed`` deliver, copy for copy, with the same statistics, on random
sequences of multicasts and unicasts, positions (unknown, NaN, out of range), attach / detach,
Bernoulli and Gilbert-Elliott loss, delays longer than a tick, end-of-run and overflow drops."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from corridor.addressed_channel import AddressedChannel
from corridor.channel import BernoulliLoss, Channel, ChannelConfig, GilbertElliottLoss

NAMES = ["rsu", *[f"v{i}" for i in range(40)]]  # more than the channel's first 16 node slots


def _random_tick(rng: np.random.Generator, t: float) -> tuple[list[str], np.ndarray, list[tuple[str, np.ndarray, list[str]]]]:
    """One tick's known positions and messages (sender, its position, listed receivers)."""
    known = [n for n in NAMES if rng.random() < 0.8]
    pos = rng.uniform(-250.0, 250.0, (len(known), 3))
    pos[:, 2] = rng.uniform(0.0, 2.0, len(known))
    if len(known) > 2:
        pos[rng.integers(len(known))] = np.nan  # a NaN position: not range checked
    msgs = []
    for _ in range(rng.integers(0, 9)):
        src = NAMES[rng.integers(len(NAMES))]
        p = rng.uniform(-250.0, 250.0, 3)
        if rng.random() < 0.1:
            p[0] = np.nan
        dst = [NAMES[k] if k < len(NAMES) else f"unknown{k}" for k in rng.integers(0, len(NAMES) + 2, rng.integers(0, 5))]
        msgs.append((src, p, dst))
    return known, pos, msgs


def _run(cfg: ChannelConfig, seed: int, t_end_s: float, ticks: int = 300) -> tuple[list[Any], list[Any], Any, Any]:
    ref = Channel(cfg, np.random.default_rng(seed), t_end_s=t_end_s, aoi=False)
    new = AddressedChannel(cfg, np.random.default_rng(seed), t_end_s=t_end_s)
    drive = np.random.default_rng(seed + 1000)
    got_ref: list[Any] = []
    got_new: list[Any] = []
    for step in range(ticks):
        t = 0.1 * step
        for name in NAMES:  # attach / detach at random
            u = drive.random()
            if u < 0.08:
                ref.detach(name)
                new.detach(name)
            elif u < 0.3:
                ref.attach(name)
                new.attach(name)
        known, pos, msgs = _random_tick(drive, t)
        ref.set_positions_arrays(known, pos)
        new.set_positions(np.array([new.node(n) for n in known], dtype=np.int64), pos)
        for b in ref.deliver_indexed(t):  # (send order omitted: Gilbert-Elliott gives each copy one)
            got_ref += [(b.src, ref.node_names[d], b.t_sent_s, tr, b.payload)
                        for d, tr in zip(b.dst_idx.tolist(), b.t_recv_s.tolist(), strict=True)]
        d = new.deliver(t)
        got_new += [(new.names[s], new.names[r], ts, tr, (v0, v1, k)) for s, r, ts, tr, (v0, v1), k in
                    zip(d.src.tolist(), d.dst.tolist(), d.t_sent_s.tolist(), d.t_recv_s.tolist(), d.val.tolist(),
                        d.ref.tolist(), strict=True)]
        assert np.all(np.diff(d.seq) >= 0)  # in send order
        payloads = [(float(i), float(-i), step * 100 + i) for i in range(len(msgs))]
        ref.send_many(t, [(src, pl, p, dst) for (src, p, dst), pl in zip(msgs, payloads, strict=True)])
        ptr = np.zeros(len(msgs) + 1, dtype=np.int64)
        np.cumsum([len(m[2]) for m in msgs], out=ptr[1:])
        new.send(t, np.array([new.node(m[0]) for m in msgs], dtype=np.int64), np.array([m[1] for m in msgs]).reshape(-1, 3),
                 ptr, np.array([new.index.get(x, -1) for m in msgs for x in m[2]], dtype=np.int64),
                 np.array([pl[:2] for pl in payloads]).reshape(-1, 2), np.array([pl[2] for pl in payloads], dtype=np.int64))
        assert new.in_flight == ref.in_flight
    return got_ref, got_new, ref.stats(), new.stats()


@pytest.mark.parametrize("loss", [BernoulliLoss(p=0.3), GilbertElliottLoss(p_good_to_bad=0.2, p_bad_to_good=0.4, loss_good=0.05)])
@pytest.mark.parametrize(("latency_s", "jitter_s", "max_in_flight", "t_end_s"),
                         [(0.02, 0.01, 1_000_000, 25.0), (0.15, 0.2, 1_000_000, 29.9), (0.05, 0.3, 12, 29.95)])
def test_addressed_channel_equals_the_general_channel(loss: Any, latency_s: float, jitter_s: float,
                                                      max_in_flight: int, t_end_s: float) -> None:
    cfg = ChannelConfig(range_m=200.0, latency_s=latency_s, jitter_s=jitter_s, loss=loss, max_in_flight=max_in_flight)
    got_ref, got_new, st_ref, st_new = _run(cfg, seed=7, t_end_s=t_end_s)
    assert len(got_ref) > 200
    assert got_new == got_ref  # the same copies, in the same order, with the same bits
    assert {k: v for k, v in st_new.__dict__.items() if "aoi" not in k} == {k: v for k, v in st_ref.__dict__.items() if "aoi" not in k}
    assert st_ref.lost_random > 0 and st_ref.out_of_range > 0
    if max_in_flight < 100:
        assert st_ref.dropped_overflow > 0
    if t_end_s < 29.97:
        assert st_ref.dropped_after_end > 0


def test_attach_beyond_the_first_node_slots() -> None:
    """Attaching a node the channel has not seen grows its arrays first (then marks it attached)."""
    ch = AddressedChannel(ChannelConfig(latency_s=0.02, jitter_s=0.0), np.random.default_rng(0))
    names = [f"n{i}" for i in range(40)]
    for n in names:
        ch.attach(n)
    ptr = np.array([0, len(names)], dtype=np.int64)
    dst = np.array([ch.index[n] for n in names], dtype=np.int64)
    ch.send(0.0, np.array([ch.node("sender")], dtype=np.int64), np.zeros((1, 3)), ptr, dst, np.zeros((1, 2)),
            np.array([-1], dtype=np.int64))
    got = ch.deliver(0.1)
    assert [ch.names[d] for d in got.dst.tolist()] == names
