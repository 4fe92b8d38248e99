"""The compiled node-indexed track pool (vehicles/tracks/node_pool) holds the same tracks, bit for bit,
as the V2X merging controller's former path: the delivered copies filtered in Python (the receiver
keeps tracks; the roadside unit tracks everyone, a vehicle the senders it listens to), sorted by
(arrival, send order) and fused by ``TrackPool`` (itself checked against filterpy)."""

from __future__ import annotations

from typing import Any

import numpy as np

from corridor.vehicles.tracks.node_pool import NodeTrackPool
from corridor.vehicles.tracks.pool import TrackPool

NAMES = ["rsu", *[f"v{i}" for i in range(10)]]
INDEX = {n: i for i, n in enumerate(NAMES)}
RSU = "rsu"


def _reference_fuse(pool: TrackPool, copies: list[tuple[int, int, int, float, float, float, float, int]],
                    listen: dict[str, set[str]]) -> None:
    """The former ``V2XMerging._fuse_cams``: copies (seq, src, dst, t_sent, t_recv, z0, z1, ref)."""
    rx = set(pool.receivers)
    kept = []
    for seq, s, d, t_sent, t_recv, z0, z1, ref in copies:
        src, dst = NAMES[s], NAMES[d]
        if ref < 0 and dst in rx and (dst == RSU or src in listen.get(dst, ())):
            kept.append((t_recv, seq, dst, src, t_sent, np.array([z0, z1])))
    kept.sort(key=lambda c: (c[0], c[1]))
    if kept:
        pool.fuse([c[2] for c in kept], [c[3] for c in kept], np.array([c[4] for c in kept]),
                  np.array([c[5] for c in kept]))


def _churn(rng: np.random.Generator, pools: tuple[Any, ...]) -> None:
    """Receivers come and go: the same draw decides for every pool."""
    for name in NAMES[1:]:
        u = rng.random()
        for p in pools:
            if u < 0.05:
                p.remove_receiver(name)
            elif u < 0.2:
                p.add_receiver(name)


def _listen(rng: np.random.Generator) -> dict[str, set[str]]:
    """Which senders each vehicle listens to (about 60 % of them listen, to 3 draws each)."""
    return {v: {NAMES[k] for k in rng.choice(len(NAMES), 3).tolist()} for v in NAMES[1:] if rng.random() < 0.6}


def _tick_copies(rng: np.random.Generator, t: float, seq0: int) -> list[tuple[int, int, int, float, float, float, float, int]]:
    """A delivery in send order: each message one sender, one send time (some older than a tick, so a
    pair may get two, out of order), a measurement, and its copies."""
    out = []
    for m in range(rng.integers(0, 12)):
        s = int(rng.integers(len(NAMES)))
        t_sent = t - 0.1 * int(rng.integers(0, 3)) + 0.01 * int(rng.integers(0, 3))
        z0, z1 = rng.normal(0, 50), rng.normal(20, 5)
        ref = -1 if rng.random() < 0.9 else m
        for d in rng.choice(len(NAMES), int(rng.integers(1, 4)), replace=False).tolist():
            t_recv = t - 0.1 + 0.1 * float(rng.integers(0, 4)) / 3.0  # ties in arrival
            out.append((seq0 + m, s, d, t_sent, t_recv, z0, z1, ref))
    return out


def test_node_pool_equals_track_pool_with_the_former_filter() -> None:
    rng = np.random.default_rng(3)
    ref = TrackPool(dim=1, process_noise=1.0, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45)
    new = NodeTrackPool(INDEX, process_noise=1.0, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45)
    for p in (ref, new):
        p.add_receiver(RSU)
    fused = 0
    for step in range(400):
        t = 0.1 * step
        _churn(rng, (ref, new))
        listen = _listen(rng)
        copies = _tick_copies(rng, t, 100 * step)
        _reference_fuse(ref, copies, listen)
        keys = sorted((INDEX[v] << 32) | INDEX[s] for v, srcs in listen.items() for s in srcs)
        a = np.array(copies, dtype=float).reshape(-1, 8)
        new.fuse_delivered(a[:, 1].astype(np.int64), a[:, 2].astype(np.int64), a[:, 3], a[:, 4],
                           np.ascontiguousarray(a[:, 5:7]), a[:, 7].astype(np.int64), INDEX[RSU],
                           np.array(keys, dtype=np.int64))
        if step % 3 == 0:
            ref.drop_stale(t)
            new.drop_stale(t)
        assert new.receivers == ref.receivers
        for rx in ref.receivers:
            for src in NAMES:
                assert new.has_track(rx, src) == ref.has_track(rx, src)
                if ref.has_track(rx, src):
                    fused += 1
                    x, p = ref.state(rx, src)
                    x2, p2 = new.state(rx, src)
                    assert x2.tolist() == x.tolist() and p2.tolist() == p.tolist()  # the same bits
                    assert new.last_update_s(rx, src) == ref.last_update_s(rx, src)
                assert new.predict_one(rx, src, t + 0.05) == ref.predict_one(rx, src, t + 0.05)
    assert fused > 2000


def test_the_one_call_fuse_and_drop_equals_fuse_delivered_then_drop_stale() -> None:
    """``fuse_and_drop`` (the process-noise terms from a table of the intervals seen, one compiled call;
    issue 27's seventh CPU pass) holds the same tracks, bit for bit, as ``fuse_delivered`` (``cv_terms`` in
    numpy per tick) followed by ``drop_stale``; send times off the tick grid give many new intervals (the
    rounding on exact halves: the next test)."""
    rng = np.random.default_rng(11)
    old = NodeTrackPool(INDEX, process_noise=1.3, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45)
    new = NodeTrackPool(INDEX, process_noise=1.3, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45)
    for p in (old, new):
        p.add_receiver(RSU)
    fused = 0
    for step in range(500):
        t = 0.1 * step
        _churn(rng, (old, new))
        listen = _listen(rng)
        copies = _tick_copies(rng, t, 100 * step)
        if step % 4 == 0:  # send times off the grid: new intervals
            copies = [(c[0], c[1], c[2], c[3] + float(rng.choice([0.5e-9, 1.5e-9, rng.uniform(0, 0.05)])), *c[4:])
                      for c in copies]
        keys = np.array(sorted((INDEX[v] << 32) | INDEX[s] for v, srcs in listen.items() for s in srcs), dtype=np.int64)
        a = np.array(copies, dtype=float).reshape(-1, 8)
        args = (a[:, 1].astype(np.int64), a[:, 2].astype(np.int64), a[:, 3], a[:, 4], np.ascontiguousarray(a[:, 5:7]),
                a[:, 7].astype(np.int64), INDEX[RSU], keys)
        old.fuse_delivered(*args)
        old.drop_stale(t)
        new.fuse_and_drop(t, *args)
        for rx in old.receivers:
            for src in NAMES:
                assert new.has_track(rx, src) == old.has_track(rx, src)
                if old.has_track(rx, src):
                    fused += 1
                    x, p = old.state(rx, src)
                    x2, p2 = new.state(rx, src)
                    assert x2.tobytes() == x.tobytes() and p2.tobytes() == p.tobytes()
                    assert new.last_update_s(rx, src) == old.last_update_s(rx, src)
    assert fused > 2000
    assert len(new._q_table[0]) > 50  # many intervals: the table grew while fusing


def test_the_compiled_interval_rounding_is_numpys() -> None:
    """The table's key of an interval is ``cv_terms``' rounding (``np.round(dt * 1e9) * 1e-9``, half to
    even), also on exact halves of a nanosecond, where rounding half up would differ."""
    from corridor.vehicles.tracks.node_pool import _apply_table
    from corridor.vehicles.tracks.stack import cv_terms

    rng = np.random.default_rng(2)
    dt = np.concatenate([(rng.integers(0, 10**9, 3000) + 0.5) * 1e-9, rng.uniform(0.0, 2.0, 3000)])
    assert (np.rint(dt * 1e9) != np.floor(dt * 1e9 + 0.5)).sum() > 500  # exact halves
    want = cv_terms(dt, 1.0)[0]
    pool = NodeTrackPool(INDEX, process_noise=1.0, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45)
    pool._add_terms(want)
    m = len(dt)
    at, missing = np.full(m, -1, dtype=np.int64), np.empty(m)
    x, p = np.zeros((1, 2)), np.tile(np.eye(2), (1, 1, 1))
    n_miss = _apply_table(m, np.zeros(m, dtype=np.int64), x, p, np.ones(m, dtype=bool), dt, np.zeros((m, 2)),
                          np.eye(2), *pool._q_table, at, missing)
    assert n_miss == 0
    assert pool._q_table[0][at].tobytes() == want.tobytes()


def test_the_delivery_in_the_same_call_equals_deliver_then_fuse_and_drop() -> None:
    """``deliver_fuse_and_drop`` (the channel's delivery and the fuse in one compiled call) delivers the same
    copies, keeps the same channel counts and holds the same tracks as ``AddressedChannel.deliver`` followed
    by ``fuse_and_drop``."""
    from corridor.addressed_channel import AddressedChannel
    from corridor.channel import BernoulliLoss, ChannelConfig

    cfg = ChannelConfig(range_m=200.0, latency_s=0.05, jitter_s=0.12, loss=BernoulliLoss(p=0.2), max_in_flight=60)
    chans = [AddressedChannel(cfg, np.random.default_rng(4), t_end_s=60.0) for _ in range(3)]
    pools = [NodeTrackPool(INDEX, process_noise=1.0, meas_noise=0.5, vel_noise=0.3, stale_after_s=0.45) for _ in range(3)]
    for ch, pool in zip(chans, pools, strict=True):
        for name in NAMES:
            ch.attach(name)
        pool.add_receiver(RSU)
    rng = np.random.default_rng(9)
    delivered = fused = n_refs = 0
    for step in range(650):  # past the end of the run (60 s): copies dropped after it
        t = 0.1 * step
        names_u = rng.random(len(NAMES))
        for ch, pool in zip(chans, pools, strict=True):
            for name, u in zip(NAMES[1:], names_u[1:], strict=True):
                if u < 0.05:
                    pool.remove_receiver(name)
                    ch.detach(name)
                elif u < 0.25:
                    ch.attach(name)
                    pool.add_receiver(name)
        k = int(rng.integers(0, 12))
        src = rng.integers(0, len(NAMES), k)
        counts = rng.integers(0, 4, k)
        ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        dst = rng.integers(0, len(NAMES), int(ptr[-1]))
        pos = rng.uniform(-150.0, 150.0, (k, 3))
        val = np.column_stack([rng.normal(0, 50, k), rng.normal(20, 5, k)])
        ref = np.where(rng.random(k) < 0.9, -1, np.arange(k)).astype(np.int64)
        node_pos = rng.uniform(-150.0, 150.0, (len(NAMES), 3))
        listen = _listen(rng)
        keys = np.array(sorted((INDEX[v] << 32) | INDEX[s] for v, srcs in listen.items() for s in srcs), dtype=np.int64)
        for ch in chans:
            ch.set_positions(np.arange(len(NAMES)), node_pos)
            ch.send(t, src, pos, ptr, dst, val, ref)
        d = chans[0].deliver(t)
        pools[0].fuse_and_drop(t, d.src, d.dst, d.t_sent_s, d.t_recv_s, d.val, d.ref, INDEX[RSU], keys)
        d2 = pools[1].deliver_fuse_and_drop(chans[1], t, INDEX[RSU], keys)
        for f in ("seq", "src", "dst", "t_sent_s", "t_recv_s", "val", "ref"):
            assert getattr(d2, f).tobytes() == getattr(d, f).tobytes(), f
        assert repr(chans[1].stats()) == repr(chans[0].stats()) and chans[1].in_flight == chans[0].in_flight
        # the same call returning only the references, in the order (t_recv, send order): V2XMerging's former sort
        k3, t3, dr3 = pools[2].deliver_fuse_and_drop_refs(chans[2], t, INDEX[RSU], keys)
        a = np.flatnonzero(d.ref >= 0)
        want = sorted(zip(d.t_recv_s[a].tolist(), d.seq[a].tolist(), d.dst[a].tolist(), d.ref[a].tolist()),
                      key=lambda c: (c[0], c[1]))
        assert list(zip(t3[:k3].tolist(), *zip(*dr3[:k3].tolist()))) == [(c[0], c[2], c[3]) for c in want]
        assert repr(chans[2].stats()) == repr(chans[0].stats()) and chans[2].in_flight == chans[0].in_flight
        n_refs += k3
        delivered += len(d)
        for rx in pools[0].receivers:
            for s in NAMES:
                assert pools[1].has_track(rx, s) == pools[0].has_track(rx, s)
                if pools[0].has_track(rx, s):
                    fused += 1
                    x, p = pools[0].state(rx, s)
                    x2, p2 = pools[1].state(rx, s)
                    assert x2.tobytes() == x.tobytes() and p2.tobytes() == p.tobytes()
                    x3, p3 = pools[2].state(rx, s)
                    assert x3.tobytes() == x.tobytes() and p3.tobytes() == p.tobytes()
    assert delivered > 1000 and fused > 1000 and n_refs > 100


def test_the_references_in_delivery_order_are_pythons_stable_sort() -> None:
    """``referenced_in_order`` (issue 27's ninth CPU pass) orders the delivered copies with a reference as
    Python's stable ``sorted`` on (arrival, send order) did in ``V2XMerging._receive``, ties included."""
    from corridor.vehicles.tracks.node_pool import referenced_in_order

    rng = np.random.default_rng(31)
    ties = 0
    for _ in range(3000):
        n = int(rng.integers(0, 30))
        t_recv = rng.choice(np.array([0.1, 0.12, 0.125, 0.2]), n) if rng.random() < 0.5 else rng.uniform(0, 1, n)
        seq = rng.integers(0, 6, n)
        dst, ref = rng.integers(0, 40, n), np.where(rng.random(n) < 0.6, rng.integers(0, 500, n), -1)
        out_t, out_dr = np.empty(n), np.empty((n, 2), dtype=np.int64)
        k = referenced_in_order(t_recv, seq, dst, ref, n, out_t, out_dr)
        a = [i for i in range(n) if ref[i] >= 0]
        want = sorted(((float(t_recv[i]), int(seq[i]), int(dst[i]), int(ref[i])) for i in a), key=lambda c: (c[0], c[1]))
        assert [(float(out_t[j]), *out_dr[j].tolist()) for j in range(k)] == [(c[0], c[2], c[3]) for c in want]
        ties += len({(c[0], c[1]) for c in want}) < len(want)
    assert ties > 500
