"""CAM generation rate, message contents and transport over the channel."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.channel import BernoulliLoss, Channel, ChannelConfig
from corridor.traffic.v2x import CamGenerator, CamMessage, broadcast, latest_by_sender


def _state(n: int) -> dict[str, np.ndarray]:
    return {
        "pos_m": np.c_[np.arange(n) * 10.0, np.zeros(n)],
        "speed_mps": np.full(n, 20.0),
        "accel_mps2": np.linspace(-1.0, 1.0, n),
        "heading_rad": np.zeros(n),
        "lane_index": np.arange(n) % 2,
    }


def test_generation_rate_matches_config_on_a_fine_tick() -> None:
    ids = [f"v{i}" for i in range(5)]
    gen = CamGenerator(rate_hz=10.0, rng=np.random.default_rng(0))
    counts = dict.fromkeys(ids, 0)
    times: dict[str, list[float]] = {i: [] for i in ids}
    for k in range(1000):  # 10 s at dt = 0.01 s
        t = 0.01 * k
        for m in gen.build(t, ids, **_state(5)):
            counts[m.sender_id] += 1
            times[m.sender_id].append(m.t_sent_s)
    assert all(c in (100, 101) for c in counts.values())  # 10 Hz over 10 s, first slot at a random phase
    assert all(np.allclose(np.diff(ts), 0.1) for ts in times.values())
    assert len({round(ts[0], 2) for ts in times.values()}) > 1  # not in lock-step


def test_coarse_tick_sends_once_per_due_tick_and_fields_are_copied() -> None:
    gen = CamGenerator(rate_hz=4.0)  # period 0.25 s, no rng: phase 0
    ids = ["a", "b"]
    st = _state(2)
    sent = [len(gen.build(0.1 * k, ids, **st)) for k in range(10)]
    # due at t = 0, 0.3 (>=0.25), 0.5, 0.8 (>=0.75): each tick at most one message per vehicle
    assert sent == [2, 0, 0, 2, 0, 2, 0, 0, 2, 0]
    msgs = gen.build(
        1.0,
        ids,
        **st,
        merge_time_s=np.array([12.5, np.nan]),
        road=["main", "ramp"],
        dist_to_merge_m=np.array([100.0, 50.0]),
    )
    assert msgs[0] == CamMessage("a", 1.0, 0.0, 0.0, 20.0, -1.0, 0.0, 0, 12.5, "main", 100.0)
    assert msgs[1].merge_time_s is None and msgs[1].lane_index == 1 and msgs[1].road == "ramp"
    with pytest.raises(ValueError):
        CamGenerator(rate_hz=0.0)


def test_broadcast_over_channel_and_latest_by_sender() -> None:
    ch = Channel(
        ChannelConfig(range_m=25.0, jitter_s=0.0, loss=BernoulliLoss(p=0.0)), np.random.default_rng(1)
    )
    ids = ["a", "b", "c"]  # at x = 0, 10, 20 m
    for i in ids:
        ch.attach(i)
    gen = CamGenerator(rate_hz=10.0)
    for k in range(3):
        broadcast(ch, gen.build(0.1 * k, ids, **_state(3)))
    got = ch.deliver(1.0)
    assert len(got) == 3 * 6  # all pairs within 25 m
    latest = latest_by_sender(ch.inbox("b"))
    assert set(latest) == {"a", "c"} and latest["a"].t_sent_s == pytest.approx(0.2)
    # the range check uses the message's own position: a at 0 m cannot reach c at 30 m
    ch.set_positions({"c": np.array([30.0, 0.0])})
    broadcast(ch, gen.build(0.3, ["a"], **{k: v[:1] for k, v in _state(1).items()}))
    assert {d.dst for d in ch.deliver(2.0)} == {"b"}
