"""TrackPool (named receivers x sources, stacked rounds) against the reference, filterpy through one
``TrackTable`` per receiver: in 1-D (the merging controller's tracks) the same bits, the same
rejections, the same stale drops."""

from __future__ import annotations

import numpy as np

from corridor.vehicles.tracks.pool import TrackPool
from corridor.vehicles.tracks.table import TrackTable

Q, R_POS, R_VEL, STALE = 1.0, 0.5, 0.3, 0.35


def test_pool_matches_filterpy_tables_bit_for_bit_in_1d() -> None:
    rng = np.random.default_rng(5)
    pool = TrackPool(1, Q, R_POS, R_VEL, stale_after_s=STALE)
    ref: dict[str, TrackTable] = {}
    names = [f"v{i}" for i in range(7)]
    for step in range(300):
        t_now = 0.1 * step
        for rx in rng.choice(names, size=2, replace=False).tolist():  # receivers come and go
            if rx in ref and rng.random() < 0.3:
                pool.remove_receiver(rx)
                del ref[rx]
            elif rx not in ref:
                pool.add_receiver(rx)
                ref[rx] = TrackTable(1, Q, R_POS, stale_after_s=STALE, vel_noise=R_VEL)
        k = int(rng.integers(0, 12))
        rx = [str(r) for r in rng.choice(list(ref), size=k)] if ref else []
        src = [str(s) for s in rng.choice(names, size=len(rx))]  # repeated pairs included
        t = np.maximum(0.0, t_now - rng.choice([0.0, 0.02, 0.15, 0.3], size=len(rx)))
        z = np.column_stack([rng.normal(0.0, 200.0, len(rx)), rng.normal(20.0, 5.0, len(rx))])
        used = pool.fuse(rx, src, t, z)
        for i in range(len(rx)):
            assert used[i] == ref[rx[i]].update(src[i], t[i], z[i, :1], z[i, 1:])
        pool.drop_stale(t_now)
        for table in ref.values():
            table.drop_stale(t_now)
        for r, table in ref.items():
            assert sorted(s for s in names if pool.has_track(r, s)) == sorted(table.ids)
            for s in table.ids:
                x, cov = pool.state(r, s)
                kf = table.filter(s)
                assert np.array_equal(x, kf.x) and np.array_equal(cov, kf.P)
                assert pool.last_update_s(r, s) == table.last_update_s(s)
            known, x, age = pool.predict_states(r, names, t_now + 0.05)
            pred = table.predict_all(t_now + 0.05)
            assert known.tolist() == [s in pred for s in names]
            for i, s in enumerate(names):
                if s in pred:
                    assert x[i, 0] == pred[s].pos[0] and x[i, 1] == pred[s].vel[0] and age[i] == pred[s].age_s
                one = pool.predict_one(r, s, t_now + 0.05)  # the scalar path: the same bits
                assert (one is None) == (s not in pred)
                if one is not None:
                    assert one == (x[i, 0], x[i, 1], age[i])


def test_pool_rows_are_recycled_and_storage_grows() -> None:
    pool = TrackPool(1, Q, R_POS, R_VEL, stale_after_s=1.0)
    pool.add_receiver("a")
    srcs = [f"s{i}" for i in range(100)]  # more than the initial 64 rows
    pool.fuse(["a"] * 100, srcs, np.zeros(100), np.ones((100, 2)))
    assert all(pool.has_track("a", s) for s in srcs)
    pool.remove_receiver("a")
    assert "a" not in pool and not pool.has_track("a", "s0")
    pool.add_receiver("b")
    pool.fuse(["b"], ["s0"], np.array([5.0]), np.array([[3.0, 4.0]]))
    known, x, age = pool.predict_states("b", ["s0", "s1"], 5.5)
    assert known.tolist() == [True, False]
    assert x[0].tolist() == [3.0 + 0.5 * 4.0, 4.0] and age[0] == 0.5  # constant velocity
