"""The channel's loss, latency, range and age of information match their configured statistics."""

from __future__ import annotations

import math

import numpy as np
import pydantic
import pytest

from corridor.channel import BernoulliLoss, Channel, ChannelConfig, GilbertElliottLoss


def _pair_channel(cfg: ChannelConfig, seed: int = 0) -> Channel:
    ch = Channel(cfg, np.random.default_rng(seed))
    ch.attach("a")
    ch.attach("b")
    return ch


def _loss_sequence(ch: Channel, n: int, src: str = "a", dst: str = "b") -> np.ndarray:
    """Send n unicast messages a->b one by one; True where the copy was lost."""
    return np.array([ch.send(float(k), src, k, dst=dst) == 0 for k in range(n)])


def _burst_lengths(lost: np.ndarray) -> np.ndarray:
    """Lengths of the runs of consecutive losses."""
    padded = np.concatenate([[0], lost.astype(int), [0]])
    edges = np.flatnonzero(np.diff(padded))
    return edges[1::2] - edges[0::2]


def test_config_validates_union_and_rejects_unknown_fields() -> None:
    cfg = ChannelConfig.model_validate(
        {"loss": {"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.5}}
    )
    assert isinstance(cfg.loss, GilbertElliottLoss)
    assert cfg.loss.stationary_loss() == pytest.approx(0.1 / 0.6)
    assert isinstance(ChannelConfig().loss, BernoulliLoss)
    with pytest.raises(pydantic.ValidationError):
        ChannelConfig.model_validate({"loss": {"model": "bernoulli", "p": 0.1, "q": 1}})
    with pytest.raises(pydantic.ValidationError):
        ChannelConfig.model_validate({"loss": {"model": "bernoulli", "p": 1.5}})
    with pytest.raises(pydantic.ValidationError):
        ChannelConfig(latency_s=-0.1)


def test_bernoulli_loss_ratio_matches_p() -> None:
    p, n = 0.3, 20000
    lost = _loss_sequence(_pair_channel(ChannelConfig(loss=BernoulliLoss(p=p))), n)
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(lost.sum() - n * p) < 4 * sigma
    # independent losses: mean burst length of a geometric run is 1 / (1 - p)
    assert _burst_lengths(lost).mean() == pytest.approx(1 / (1 - p), rel=0.05)


def test_gilbert_elliott_stationary_loss_and_bursts() -> None:
    p_gb, p_bg, n = 0.05, 0.25, 60000
    loss = GilbertElliottLoss(p_good_to_bad=p_gb, p_bad_to_good=p_bg)
    lost = _loss_sequence(_pair_channel(ChannelConfig(loss=loss), seed=3), n)
    pi_bad = p_gb / (p_gb + p_bg)
    # Markov-correlated samples: variance of the mean inflates by (1 + lam) / (1 - lam), lam = 1 - p_gb - p_bg
    lam = 1 - p_gb - p_bg
    sigma = math.sqrt(pi_bad * (1 - pi_bad) / n * (1 + lam) / (1 - lam))
    assert abs(lost.mean() - pi_bad) < 4 * sigma
    bursts = _burst_lengths(lost)
    se = math.sqrt(1 - p_bg) / p_bg / math.sqrt(bursts.size)  # geometric(p_bg) std / sqrt(count)
    assert abs(bursts.mean() - 1 / p_bg) < 4 * se
    assert bursts.mean() > 2.5  # clearly burstier than Bernoulli at the same mean loss (1.2)


def test_gilbert_elliott_state_is_per_link() -> None:
    """A link that is never used stays in the good state: its first copy gets through."""
    loss = GilbertElliottLoss(p_good_to_bad=1.0, p_bad_to_good=1e-9)  # first transition -> bad forever
    ch = _pair_channel(ChannelConfig(loss=loss))
    ch.attach("c")
    assert all(ch.send(float(k), "a", k, dst="b") == 0 for k in range(5))
    # link a->c advances only now; with p_good_to_bad = 1 it is also bad, but c->a is its own chain
    assert ch.send(10.0, "a", 0, dst="c") == 0
    assert ch.stats().lost_random == 6
    loss0 = GilbertElliottLoss(p_good_to_bad=0.0, p_bad_to_good=1.0)
    ch0 = _pair_channel(ChannelConfig(loss=loss0))
    assert all(ch0.send(float(k), "a", k, dst="b") == 1 for k in range(100))


def test_latency_mean_and_bounds() -> None:
    lat, jit, n = 0.1, 0.04, 5000
    ch = _pair_channel(ChannelConfig(latency_s=lat, jitter_s=jit))
    for k in range(n):
        ch.send(float(k), "a", k)
    got = ch.deliver(float(n + 1))
    delay = np.array([d.t_recv_s - d.t_sent_s for d in got])
    assert len(got) == n
    assert delay.min() >= lat - 1e-12 and delay.max() <= lat + jit + 1e-12
    se = jit / math.sqrt(12 * n)
    assert abs(delay.mean() - (lat + jit / 2)) < 4 * se
    assert delay.std() == pytest.approx(jit / math.sqrt(12), rel=0.05)


def test_delivery_waits_for_delay_and_is_sorted() -> None:
    ch = Channel(ChannelConfig(latency_s=0.05, jitter_s=0.0), np.random.default_rng(0))
    for r in ("c", "a", "b"):
        ch.attach(r)
    ch.send(0.0, "c", "x")
    ch.send(0.0, "a", "y")
    assert ch.deliver(0.04) == []
    got = ch.deliver(0.05)
    assert [(d.src, d.dst) for d in got] == [("a", "b"), ("a", "c"), ("c", "a"), ("c", "b")]
    assert all(d.t_recv_s == pytest.approx(0.05) for d in got)
    assert [d.payload for d in ch.inbox("b")] == ["y", "x"]
    assert ch.deliver(1.0) == [] and ch.inbox("b") == []


def test_range_cutoff_2d_3d_and_unknown_positions() -> None:
    ch = Channel(ChannelConfig(range_m=300.0, jitter_s=0.0), np.random.default_rng(0))
    for r in ("tx", "near", "far", "high", "unknown"):
        ch.attach(r)
    ch.set_positions(
        {
            "tx": np.zeros(2),
            "near": np.array([299.0, 0.0]),
            "far": np.array([0.0, 301.0]),
            "high": np.array([200.0, 0.0, 250.0]),
        }  # 320 m in 3-D
    )
    assert ch.send(0.0, "tx", "m") == 2
    assert {d.dst for d in ch.deliver(1.0)} == {"near", "unknown"}
    # an explicit sender position overrides the table
    assert ch.send(1.0, "tx", "m", src_pos=np.array([200.0, 0.0, 250.0])) == 3  # "far" now 440 m
    s = ch.stats()
    assert (s.sent, s.out_of_range, s.lost_random) == (8, 3, 0)
    assert s.delivery_ratio == pytest.approx(2 / 5)  # 2 of the 5 in-range copies delivered so far


def test_unicast_sender_excluded_and_detach() -> None:
    ch = Channel(ChannelConfig(jitter_s=0.0), np.random.default_rng(0))
    for r in ("a", "b", "c"):
        ch.attach(r)
    assert ch.send(0.0, "a", "hi", dst="c") == 1
    assert ch.send(0.0, "a", "self", dst="a") == 0
    assert ch.send(0.0, "a", "nobody", dst="zz") == 0
    assert ch.send(0.0, "a", "all") == 2
    ch.detach("b")  # b leaves while its copy is in flight
    got = ch.deliver(1.0)
    assert [(d.dst, d.payload) for d in got] == [("c", "hi"), ("c", "all")]  # ties keep send order
    assert ch.receivers == ["a", "c"]
    assert ch.stats().delivered == 2


def test_age_of_information_closed_form() -> None:
    """Zero loss, fixed 20 ms latency, 10 Hz sends, deliveries sampled 50 ms after each send: AoI = 50 ms."""
    ch = _pair_channel(ChannelConfig(latency_s=0.02, jitter_s=0.0, rate_hz=10))
    for k in range(50):
        t = 0.1 * k
        ch.send(t, "a", k)
        ch.send(t, "b", k)
        ch.deliver(t + 0.05)
    s = ch.stats()
    assert s.aoi_mean_s == pytest.approx(0.05) and s.aoi_max_s == pytest.approx(0.05)
    assert s.delivery_ratio == 1.0 and s.delivered == 100


def test_aoi_grows_when_every_message_is_lost() -> None:
    ch = _pair_channel(ChannelConfig(latency_s=0.0, jitter_s=0.0))
    ch.send(0.0, "a", 0)
    ch.deliver(0.0)
    for k in range(1, 11):
        ch.deliver(float(k))  # nothing sent: the info received at t=0 ages
    s = ch.stats()
    assert s.aoi_max_s == pytest.approx(10.0)
    assert s.aoi_mean_s == pytest.approx(np.mean(np.arange(0, 11)))


def test_channel_without_aoi_delivers_the_same_and_reports_no_aoi() -> None:
    """``aoi=False`` skips the age-of-information bookkeeping only: the same draws, deliveries,
    detaches and counters; both AoI figures NaN."""
    def run(aoi: bool) -> tuple[list[tuple[str, int, float, list[int]]], object]:
        ch = Channel(ChannelConfig(range_m=150.0, latency_s=0.02, jitter_s=0.05, loss=BernoulliLoss(p=0.3)),
                     np.random.default_rng(3), aoi=aoi)
        ids = [f"v{i}" for i in range(10)]
        got = []
        for k in range(40):
            t = 0.1 * k
            for i in ids[k % 3: 10 - k % 2]:
                ch.attach(i)
            ch.detach(ids[k % 10])
            ch.set_positions_arrays(ids, np.c_[np.linspace(0.0, 300.0, 10) + t, np.zeros(10)])
            ch.send_many(t, [(i, (i, k), None, None) for i in ids[:6]] + [("rsu", k, None, ids[7:9])])
            got += [(b.src, b.seq, b.t_sent_s, b.dst_idx.tolist()) for b in ch.deliver_indexed(t)]
        return got, ch.stats()

    (got_on, st_on), (got_off, st_off) = run(True), run(False)
    assert got_on == got_off and len(got_on) > 100
    assert math.isfinite(st_on.aoi_mean_s) and math.isnan(st_off.aoi_mean_s) and math.isnan(st_off.aoi_max_s)
    assert {**st_on.__dict__, "aoi_mean_s": 0, "aoi_max_s": 0} == {**st_off.__dict__, "aoi_mean_s": 0, "aoi_max_s": 0}


def test_set_positions_arrays_of_3d_rows_equals_set_positions() -> None:
    """The (N, 3) fast path of ``set_positions_arrays`` range-checks as ``set_positions`` does."""
    def run(fast: bool) -> list[tuple[str, str, float]]:
        ch = Channel(ChannelConfig(range_m=120.0, loss=BernoulliLoss(p=0.2)), np.random.default_rng(4))
        ids = [f"v{i}" for i in range(8)]
        for i in ids:
            ch.attach(i)
        got = []
        for k in range(30):
            pos = np.c_[np.linspace(0.0, 400.0, 8) + 2.0 * k, np.full(8, -3.5), np.zeros(8)]
            if fast:
                ch.set_positions_arrays(ids, pos)
            else:
                ch.set_positions({i: [float(v) for v in p] for i, p in zip(ids, pos, strict=True)})
            ch.send_many(0.1 * k, [(i, k, None, None) for i in ids])
            got += [(d.src, d.dst, d.t_recv_s) for d in ch.deliver(0.1 * k + 0.1)]
        return got

    assert run(True) == run(False) and len(run(True)) > 100


def _run(seed: int) -> list[tuple[str, str, float, int]]:
    cfg = ChannelConfig(range_m=150.0, loss=GilbertElliottLoss(p_good_to_bad=0.2, p_bad_to_good=0.3))
    ch = Channel(cfg, np.random.default_rng(seed))
    ids = [f"v{i}" for i in range(30)]
    for i in ids:
        ch.attach(i)
    x0_m = np.linspace(0.0, 600.0, 30)
    out = []
    for k in range(20):
        t = 0.1 * k
        ch.set_positions_arrays(ids, np.c_[x0_m + 10.0 * t, np.zeros(30)])
        for i in ids:
            ch.send(t, i, (i, k))
        out += [(d.src, d.dst, d.t_recv_s, d.payload[1]) for d in ch.deliver(t + 0.1)]
    return out


def test_determinism_same_seed_same_deliveries() -> None:
    a, b, c = _run(7), _run(7), _run(8)
    assert a == b
    assert a != c
    assert len(a) > 1000


def _fleet_channel(seed: int) -> tuple[Channel, list[str]]:
    ch = Channel(ChannelConfig(range_m=150.0, latency_s=0.05, jitter_s=0.03, loss=BernoulliLoss(p=0.2)),
                 np.random.default_rng(seed))
    ids = [f"v{i}" for i in range(12)]
    for i in ids:
        ch.attach(i)
    ch.attach("listener")  # attached, position unknown: never range checked
    return ch, ids


def test_send_many_and_deliver_batches_equal_send_and_deliver() -> None:
    """A fleet's broadcasts in one send_many draw the same numbers as send after send, and
    deliver_batches hands over the same copies as deliver (grouped by message), with the same
    statistics and age of information."""
    ref, ids = _fleet_channel(5)
    new, _ = _fleet_channel(5)
    got_ref, got_new = [], []
    for k in range(30):
        t = 0.1 * k
        pos = np.c_[np.linspace(0.0, 400.0, 12) + 3.0 * t, np.zeros(12)]
        ref.set_positions_arrays(ids, pos)
        new.set_positions_arrays(ids, pos)
        msgs = [(i, (i, k), pos[j], None) for j, i in enumerate(ids)] + [("gcs", ("hb", k), None, None)]
        counts = [ref.send(t, src, payload, src_pos=p) for src, payload, p, _ in msgs]
        assert new.send_many(t, msgs) == counts
        got_ref += ref.deliver(t + 0.1)
        batches = new.deliver_batches(t + 0.1)
        got_new += [(b.src, d, b.t_sent_s, tr, b.payload, b.seq)
                    for b in batches for d, tr in zip(b.dst, b.t_recv_s, strict=True)]
        assert [(d.src, d.payload) for d in new.inbox("listener")] == [
            (d.src, d.payload) for d in ref.inbox("listener")]
    assert len(got_ref) > 1000 and ref.stats().out_of_range > 0 and ref.stats().lost_random > 0
    # deliver's order is (t_recv, src, dst, send order)
    ordered = sorted(got_new, key=lambda c: (c[3], c[0], c[1], c[5]))
    assert [(d.src, d.dst, d.t_sent_s, d.t_recv_s, d.payload) for d in got_ref] == [c[:5] for c in ordered]
    assert ref.stats() == new.stats()


def test_send_many_unicasts_and_broadcasts_mixed_equal_send_after_send() -> None:
    """Unicasts (to attached, detached, unknown receivers and to the sender itself) mixed with
    broadcasts in one send_many: the same copies, draws, deliveries and statistics as send after send."""
    ref, ids = _fleet_channel(9)
    new, _ = _fleet_channel(9)
    for ch in (ref, new):
        ch.detach("v3")
    rng = np.random.default_rng(4)
    dsts = [*ids, "listener", "nobody", None, None]
    got_ref, got_new = [], []
    for k in range(30):
        t = 0.1 * k
        pos = np.c_[np.linspace(0.0, 400.0, 12) + 3.0 * t, np.zeros(12)]
        ref.set_positions_arrays(ids, pos)
        new.set_positions_arrays(ids, pos)
        msgs = [(ids[j], (j, k, m), pos[j] if m % 3 else None, dsts[rng.integers(len(dsts))])
                for m, j in enumerate(rng.integers(0, 12, 25))]
        counts = [ref.send(t, src, payload, src_pos=p, dst=dst) for src, payload, p, dst in msgs]
        assert new.send_many(t, msgs) == counts
        got_ref += ref.deliver(t + 0.1)
        got_new += new.deliver(t + 0.1)
    assert got_new == got_ref and len(got_ref) > 300
    assert ref.stats() == new.stats() and ref.stats().out_of_range > 0 and ref.stats().lost_random > 0


@pytest.mark.parametrize("with_broadcasts", [True, False])  # False: the unicast-only path
@pytest.mark.parametrize("dims", [2, 3])  # 3: float 3-vectors, the addressed path in Python floats
def test_send_many_multicast_equals_unicasts_send_after_send_as_one_message(with_broadcasts: bool, dims: int) -> None:
    """A multicast entry (a list of receivers, including detached, unknown, repeated-free, the sender
    itself, and an empty list) draws, counts and delivers what one unicast send per listed receiver
    does, in order; its copies in flight form one batch (one message of deliver_batches)."""
    ref, ids = _fleet_channel(13)
    new, _ = _fleet_channel(13)
    for ch in (ref, new):
        ch.detach("v3")
    rng = np.random.default_rng(8)
    pool = [*ids, "listener", "nobody"]
    got_ref, got_new, batches_seen = [], [], 0
    addressed = new._send_addressed
    used: list[bool] = []  # which path each send_many took (the addressed path needs 3-vectors, no broadcast)
    new._send_addressed = lambda *a: (r := addressed(*a), used.append(r is not None))[0]  # type: ignore[method-assign]
    for k in range(30):
        t = 0.1 * k
        pos = np.c_[np.linspace(0.0, 400.0, 12) + 3.0 * t, np.zeros(12)]
        if dims == 3:  # off the plane, with digits that make the squared distance's sum order matter
            pos = np.c_[pos + rng.normal(0.0, 1.0, (12, 2)), rng.normal(0.0, 30.0, 12)]
        ref.set_positions_arrays(ids, pos)
        new.set_positions_arrays(ids, pos)
        msgs = []
        for m, j in enumerate(rng.integers(0, 12, 15)):
            dst = [str(d) for d in rng.choice(pool, size=int(rng.integers(0, 5)), replace=False)]
            single = dst[:1] or None if with_broadcasts else (dst[:1] or ["nobody"])[0]
            msgs.append((ids[j], (j, k, m), pos[j] if m % 3 else None, dst if m % 4 else single))
        counts = [sum(ref.send(t, src, payload, src_pos=p, dst=d) for d in (dst if isinstance(dst, list) else [dst]))
                  for src, payload, p, dst in msgs]
        assert new.send_many(t, msgs) == counts
        got_ref += ref.deliver(t + 0.1)
        batches = new.deliver_batches(t + 0.1)
        assert len({b.payload for b in batches}) == len(batches)  # one batch per sent message
        batches_seen += sum(len(b.dst) > 1 for b in batches)
        got_new += [(b.src, d, b.t_sent_s, tr, b.payload, b.seq)
                    for b in batches for d, tr in zip(b.dst, b.t_recv_s, strict=True)]
    ordered = sorted(got_new, key=lambda c: (c[3], c[0], c[1], c[5]))
    assert [(d.src, d.dst, d.t_sent_s, d.t_recv_s, d.payload) for d in got_ref] == [c[:5] for c in ordered]
    assert len(got_ref) > 200 and batches_seen > 50
    assert ref.stats() == new.stats() and ref.stats().out_of_range > 0 and ref.stats().lost_random > 0
    if dims == 3 and not with_broadcasts:
        assert used == [True] * 30  # every send_many went through the addressed path

def test_send_many_falls_back_to_send_for_bursty_loss() -> None:
    loss = GilbertElliottLoss(p_good_to_bad=0.2, p_bad_to_good=0.3)
    a, b = (_pair_channel(ChannelConfig(loss=loss), seed=2) for _ in range(2))
    for k in range(200):
        assert b.send_many(float(k), [("a", k, None, None), ("b", -k, None, "a")]) == [
            a.send(float(k), "a", k), a.send(float(k), "b", -k, dst="a")]
    assert [d.payload for d in a.deliver(1e3)] == [d.payload for d in b.deliver(1e3)]
    assert a.stats() == b.stats()


# -- messages that can never arrive ---------------------------------------------------------------
@pytest.mark.parametrize("field", ["latency_s", "jitter_s"])
@pytest.mark.parametrize("value", [1e9, 60.5, math.nan, math.inf])
def test_config_rejects_implausible_or_non_finite_delay(field: str, value: float) -> None:
    with pytest.raises(pydantic.ValidationError) as exc:
        ChannelConfig(**{field: value})
    msg = str(exc.value)
    assert field in msg
    assert ("60 s" in msg) if math.isfinite(value) else ("finite" in msg)
    ChannelConfig(**{field: 60.0})  # the bound itself is allowed


def test_scenario_rejects_huge_latency_in_one_line(capsys, scenario_path) -> None:
    from corridor.cli import main

    scenario = scenario_path("merging")
    assert main([str(scenario), "--set", "channels.v2x.latency_s=1e9"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "channels.v2x.latency_s" in err and "60 s" in err, err


def test_copies_arriving_after_the_run_end_are_dropped_and_counted() -> None:
    cfg = ChannelConfig(latency_s=50.0, jitter_s=0.0)
    ch = Channel(cfg, np.random.default_rng(0), t_end_s=10.0)
    for name in ("a", "b", "c"):
        ch.attach(name)
    for k in range(100):  # 10 s of 10 Hz broadcasts, each would arrive 50 s later: after the end
        assert ch.send(0.1 * k, "a", k) == 0
        ch.deliver(0.1 * k)
    assert ch.in_flight == 0
    assert not ch._pending  # nothing kept to be scanned every tick
    st = ch.stats()
    assert st.sent == 200 and st.delivered == 0 and st.dropped_after_end == 200 and st.dropped_overflow == 0


def test_end_drop_keeps_every_copy_that_arrives_in_time_identical() -> None:
    """Dropping late copies changes nothing else: same draws, same deliveries within the run."""
    cfg = ChannelConfig(latency_s=0.3, jitter_s=0.5, loss=BernoulliLoss(p=0.2))

    def run(t_end: float | None) -> tuple[list, object]:
        ch = Channel(cfg, np.random.default_rng(3), t_end_s=t_end)
        for name in ("a", "b", "c", "d"):
            ch.attach(name)
        got = []
        for k in range(51):
            t = 0.1 * k
            ch.send(t, "a", k)
            ch.send_many(t, [("b", -k, None, None), ("c", 1000 + k, None, None)])
            got += [(d.src, d.dst, d.payload, d.t_recv_s) for d in ch.deliver(t)]
        return got, ch.stats()

    free, st_free = run(None)
    ended, st_end = run(5.0)
    assert ended == free
    assert st_end.delivered == st_free.delivered and st_end.lost_random == st_free.lost_random
    assert st_end.dropped_after_end > 0 and st_free.dropped_after_end == 0


def test_in_flight_queue_is_bounded_and_overflow_counted() -> None:
    cfg = ChannelConfig(latency_s=10.0, jitter_s=0.0, max_in_flight=25)
    ch = Channel(cfg, np.random.default_rng(0))
    for name in ("a", "b", "c"):
        ch.attach(name)
    sent_copies = [ch.send(0.1 * k, "a", k) for k in range(20)]  # 2 copies each
    sent_copies += ch.send_many(2.0, [("b", "x", None, None), ("c", "y", None, None)])
    assert ch.in_flight == 25
    assert sum(sent_copies) == 25
    st = ch.stats()
    assert st.dropped_overflow == 44 - 25
    assert len(ch.deliver(100.0)) == 25 and ch.in_flight == 0
    assert ch.send(100.0, "a", "again") == 2  # room again after delivery
