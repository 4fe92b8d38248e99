"""city_separation counts what uav_separation counts (same thresholds, same continuous check), with
k-d tree candidates instead of all pairs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from corridor.analysis.monitoring.city_separation import CitySeparation
from corridor.analysis.monitoring.separation import SeparationMonitor
from corridor.engine import RunContext
from corridor.snapshot import Kind, Role, WorldSnapshot


def snapshots(seed: int, n: int = 60, ticks: int = 80, dt: float = 0.1) -> list[WorldSnapshot]:
    """n aircraft (two piloted, fast) crossing a 400 m square at 5-25 m/s in two layers."""
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(0, 400, (n, 2)), rng.choice([60.0, 66.0], n)])
    v = np.column_stack([rng.normal(0, 12, (n, 2)), np.zeros(n)])
    kind = np.full(n, Kind.UAV, dtype=np.int8)
    kind[:2] = Kind.AIRCRAFT
    v[:2, :2] *= 4.0
    out = []
    for k in range(ticks):
        q = p + v * k * dt
        out.append(WorldSnapshot(t=k * dt, ids=np.array([f"a{i}" for i in range(n)], dtype=object), kind=kind,
                                 role=np.full(n, Role.OTHER, dtype=np.int8), position=q, velocity=v.copy(),
                                 heading=np.zeros(n), size=np.tile([0.5, 0.5, 0.2], (n, 1))))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_city_monitor_equals_all_pairs_monitor(tmp_path: Path, seed: int) -> None:
    ref = SeparationMonitor("ref", SeparationMonitor.Params(backend=None, track_period_s=None), None)
    city = CitySeparation("city", CitySeparation.Params(backend=None), None)
    ctx = RunContext(run_seed=0, dt=0.1, duration=8.0, workdir=tmp_path)
    ref.setup(ctx)
    city.setup(ctx)
    for s in snapshots(seed):
        ctx.t, ctx.snapshot = s.t, s
        ref.tick(ctx)
        city.tick(ctx)
    a, b = ref.finish(ctx), city.finish(ctx)
    assert b["nmac"] == a["nmac"] and b["los"] == a["los"]
    assert a["los"] > 3 and a["nmac"] > 0  # the scene has both
    assert b["sep_min_h_m"] == pytest.approx(a["sep_min_h_m"], abs=1e-9)
    assert b["sep_min_3d_m"] == pytest.approx(a["sep_min_3d_m"], abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_neighbour_minima_equal_a_full_query_every_tick(tmp_path: Path, seed: int) -> None:
    """The monitor queries nearest neighbours only where a minimum can still fall; the per-aircraft
    nearest approach and the global minima equal those of a full query at every tick."""
    from scipy.spatial import cKDTree

    city = CitySeparation("city", CitySeparation.Params(backend=None), None)
    ctx = RunContext(run_seed=0, dt=0.1, duration=8.0, workdir=tmp_path)
    city.setup(ctx)
    nn, min_h, min_3d = None, np.inf, np.inf
    for s in snapshots(seed, n=120):
        ctx.t, ctx.snapshot = s.t, s
        city.tick(ctx)
        d3 = cKDTree(s.position).query(s.position, k=2)[0][:, 1]
        dh = cKDTree(s.position[:, :2]).query(s.position[:, :2], k=2)[0][:, 1]
        nn = d3 if nn is None else np.minimum(nn, d3)
        min_h, min_3d = min(min_h, dh.min()), min(min_3d, d3.min())
        assert np.all(city.nn <= nn + 1e-9)  # the continuous check can only go lower than the ticks
        assert city.min_h <= min_h + 1e-9 and city.min_3d <= min_3d + 1e-9
    # tick minima never missed: where the continuous check adds nothing the values are the ticks'
    full = CitySeparation("full", CitySeparation.Params(backend=None), None)
    full.setup(ctx)
    full._nearest = lambda pos, tree, reach, paired: CitySeparation._nearest(full, pos, tree, -1.0, paired)  # all
    for s in snapshots(seed, n=120):
        ctx.t, ctx.snapshot = s.t, s
        full.tick(ctx)
    np.testing.assert_array_equal(city.nn, full.nn)
    assert (city.min_h, city.min_3d) == (full.min_h, full.min_3d)
    assert city.finish(ctx) == full.finish(ctx)
