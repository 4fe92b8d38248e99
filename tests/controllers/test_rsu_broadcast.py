"""The roadside unit's lean broadcast (controllers/merging/rsu_broadcast.py) delivers what the general
channel's broadcast ``send`` and ``deliver_indexed`` deliver, copy for copy, with the same statistics,
and ``newest_per_receiver`` keeps what a loop over ``Channel.deliver`` keeps, on random sequences of
attach / detach (re-attach included), positions (NaN, out of range), delays longer than a tick,
end-of-run and overflow drops."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from corridor.channel import BernoulliLoss, Channel, ChannelConfig, GilbertElliottLoss
from corridor.controllers.merging.rsu_broadcast import (
    GeneralBroadcast,
    RsuBroadcast,
    newest_per_receiver,
    rsu_broadcast,
)

NAMES = [f"v{i}" for i in range(30)]  # more than the channel's first 16 node slots
SRC = np.array([100.0, 0.0, 0.0])


def _run(cfg: ChannelConfig, seed: int, t_end_s: float, ticks: int = 300) -> None:
    ref = Channel(cfg, np.random.default_rng(seed), t_end_s=t_end_s, aoi=False)
    ref_sorted = Channel(cfg, np.random.default_rng(seed), t_end_s=t_end_s, aoi=False)  # deliver(): sorted copies
    new = rsu_broadcast(cfg, np.random.default_rng(seed), t_end_s, "rsu")
    assert isinstance(new, RsuBroadcast if isinstance(cfg.loss, BernoulliLoss) else GeneralBroadcast)
    drive = np.random.default_rng(seed + 1000)
    attached: set[str] = set()
    latest_ref: dict[str, Any] = {}
    latest_new: dict[str, Any] = {}
    n_copies = 0
    for step in range(ticks):
        t = 0.1 * step
        for name in NAMES:  # attach / detach at random
            u = drive.random()
            if u < 0.08 and name in attached:
                attached.discard(name)
                for ch in (ref, ref_sorted, new):
                    ch.detach(name)
                latest_ref.pop(name, None)
                latest_new.pop(name, None)
            elif u < 0.2 and name not in attached:
                attached.add(name)
                for ch in (ref, ref_sorted, new):
                    ch.attach(name)
        got_ref = [(b.seq, b.payload, [ref.node_names[i] for i in b.dst_idx.tolist()], b.t_recv_s.tolist())
                   for b in ref.deliver_indexed(t)]
        due = new.deliver(t)
        assert [(b.seq, b.payload, [new.names[i] for i in b.dst_idx.tolist()], b.t_recv_s.tolist())
                for b in due] == got_ref
        n_copies += sum(len(g[2]) for g in got_ref)
        for d in ref_sorted.deliver(t):  # the controller's loop before: the last copy in deliver's order wins
            latest_ref[d.dst] = d.payload
        newest_per_receiver(due, new.names, latest_new)
        assert latest_new == latest_ref
        if drive.random() < 0.7:  # a broadcast (receivers in any order, some without a position)
            receivers = [n for n in NAMES if n in attached]
            drive.shuffle(receivers)
            pos = drive.uniform(-150.0, 350.0, (len(receivers), 3))
            pos[drive.random(len(receivers)) < 0.1] = np.nan  # unknown: not range checked
            ref.set_positions_arrays(receivers, pos)
            ref_sorted.set_positions_arrays(receivers, pos)
            k_ref = ref.send(t, "rsu", step, SRC)
            ref_sorted.send(t, "rsu", step, SRC)
            assert new.send(t, step, SRC, receivers, pos) == k_ref
        assert new.in_flight == ref.in_flight
    assert n_copies > 100
    assert new.stats() == ref.stats() or str(new.stats()) == str(ref.stats())  # NaN age of information


@pytest.mark.parametrize("loss", [BernoulliLoss(p=0.3), GilbertElliottLoss(p_good_to_bad=0.2, p_bad_to_good=0.4, loss_good=0.05)])
@pytest.mark.parametrize(("latency_s", "jitter_s", "max_in_flight", "t_end_s"),
                         [(0.02, 0.01, 1_000_000, 25.0), (0.15, 0.2, 1_000_000, 29.9), (0.05, 0.3, 12, 29.95)])
def test_rsu_broadcast_equals_the_general_channel(loss: Any, latency_s: float, jitter_s: float,
                                                  max_in_flight: int, t_end_s: float) -> None:
    cfg = ChannelConfig(range_m=200.0, latency_s=latency_s, jitter_s=jitter_s, loss=loss, max_in_flight=max_in_flight)
    for seed in range(3):
        _run(cfg, seed, t_end_s)


def test_rsu_broadcast_needs_the_attached_receivers() -> None:
    ch = RsuBroadcast(ChannelConfig(loss=BernoulliLoss(p=0.1)), np.random.default_rng(0))
    ch.attach("a")
    with pytest.raises(ValueError, match="1 attached"):
        ch.send(0.0, "x", SRC, [], np.zeros((0, 3)))
    with pytest.raises(ValueError, match="Bernoulli"):
        RsuBroadcast(ChannelConfig(loss=GilbertElliottLoss(p_good_to_bad=0.1, p_bad_to_good=0.5)), np.random.default_rng(0))
