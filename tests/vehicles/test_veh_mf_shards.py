"""Sharded runs (``corridor.shards``, ``backends.air.params.shards``): every rank steps the world, the
JSBSim aircraft fly on their pool group's rank, the separation and collision checks are split by
strips of the city with a halo.

- a 2-shard run gives the one-process run's rows and event log (small dense city, 20 s);
- hand-over: a pair in LoS flying across the strip edge is counted once, its minima are the
  one-process ones, and the aircraft's trajectory is the same snapshot rows whichever rank counts it;
- halo: a pair converging across the strip edge (one aircraft in each strip) is seen as in one
  process (LoS and NMAC once each, the same minimum separations);
- a shard count outside 1..POOL_GROUPS is refused.
"""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.analysis.monitoring.city_separation import CitySeparation
from corridor.engine import RunContext
from corridor.errors import CorridorError
from corridor.run import simulate
from corridor.scenario import load
from corridor.shards import ShardComm, Strips
from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.vehicles.air.jsbsim_switch import POOL_GROUPS
from tests.conftest import scenario_file

CITY = scenario_file("uav_city")
SMALL = ["backends.air.params.city.n=80", "backends.air.params.city.size_m=1200", "backends.air.params.city.vertiports=6",
         "backends.air.params.city.vertiport_spacing_m=200", "backends.air.params.city.start_spacing_m=60",
         "duration=20"]
MACHINE = {"wall_s", "rtf", "cpu_per_sim_s"}  # measurements of the machine, not of the scenario


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def test_two_shards_give_the_one_shard_rows() -> None:
    rows, logs, ctxs = {}, {}, {}
    for k in (1, 2):
        sc, _ = load(CITY, [*SMALL, f"backends.air.params.shards={k}"])
        rows[k], ctxs[k], _ = simulate(sc, 0)
        logs[k] = sorted((e.t, e.source, e.kind, e.message) for e in ctxs[k].events.events)
    one, two = rows[1], rows[2]
    # the strips follow the load (each rank's JSBSim aircraft count beside the aircraft in its strip):
    # the monitors and the avoidance share the air backend's balanced split, whose edge moved
    strips, comps = ctxs[2].shard.strips, ctxs[2].components
    assert strips is comps["separation"].strips is comps["collisions"]._strips is comps["avoid"].strips
    assert ctxs[2].shard.idle is not None  # a waiting rank prefetches FDMs (shard_balance.prefetch)
    start_x = np.array([a.start_enu[0] for a in comps["air"].aircraft])
    edge0, edge = float(np.median(start_x)), float(strips.edges[0])
    assert abs(edge - edge0) > 20.0
    # hand-overs (aircraft and edge moving): aircraft that changed strips end where they end in one
    # process (bit for bit)
    end = ctxs[2].snapshot.position
    assert np.count_nonzero((start_x < edge0) != (end[:, 0] < edge)) >= 5
    assert np.array_equal(end, ctxs[1].snapshot.position)
    assert one["promotions"] >= 20 and one["demotions"] >= 1  # the 6-DOF fleets change during the run
    assert one["los"] >= 10 and one["nmac"] >= 1  # pairs to split between the ranks
    differ = {k: (one[k], two[k]) for k in sorted(set(one) - MACHINE) if not _same(one[k], two[k])}
    assert differ == {}
    assert set(one) == set(two)
    assert logs[1] == logs[2]
    assert two["cpu_per_sim_s"] > 0.0  # every rank's CPU is counted


def test_shard_count_is_checked() -> None:
    with pytest.raises(CorridorError, match="shards"):
        load(CITY, [*SMALL, f"backends.air.params.shards={POOL_GROUPS + 1}"])


# ---- the separation monitor's regions, driven tick by tick ------------------------------------------------
DT = 0.1  # [s]


def _snapshots(tracks: np.ndarray) -> list[WorldSnapshot]:
    """A snapshot per tick of ``tracks`` (ticks, aircraft, 3) [m]: quadcopters."""
    n = tracks.shape[1]
    ids = np.array([f"d{k}" for k in range(n)], dtype=object)
    return [WorldSnapshot(t=k * DT, ids=ids, kind=np.full(n, Kind.UAV, dtype=np.int8),
                          role=np.full(n, Role.OTHER, dtype=np.int8), position=p, velocity=np.zeros((n, 3)),
                          heading=np.zeros(n), size=np.tile([0.45, 0.45, 0.2], (n, 1))) for k, p in enumerate(tracks)]


def _monitor(shard: ShardComm | None) -> tuple[CitySeparation, RunContext]:
    mon = CitySeparation("separation", CitySeparation.Params(backend=None), SimpleNamespace(dt=DT))
    ctx = RunContext(run_seed=0, dt=DT, duration=1.0)
    ctx.shard = shard
    return mon, ctx


def _fly(tracks: np.ndarray, ranks: int) -> tuple[list[dict[str, Any]], list[list[str]]]:
    """The monitor's metrics and event messages per rank (one process when ``ranks`` is 1); the
    ranks tick in turn, then finish together (their collectives over real pipes, one thread each)."""
    if ranks == 1:
        comms: list[ShardComm | None] = [None]
    else:
        import multiprocessing as mp

        a, b = mp.Pipe()
        comms = [ShardComm(0, 2, {1: a}), ShardComm(1, 2, {0: b})]
    mons = [_monitor(c) for c in comms]
    out = _drive(mons, tracks)
    return out, [[e.message for e in ctx.events.events] for _, ctx in mons]


def _drive(runs: list[tuple[Any, RunContext]], tracks: np.ndarray) -> list[dict[str, Any]]:
    """Tick every (monitor, context) on the snapshots of ``tracks`` in turn, then finish them
    together, one thread each (a sharded finish's collectives wait for the other ranks)."""
    for s in _snapshots(tracks):
        for mon, ctx in runs:
            ctx.snapshot, ctx.t = s, s.t
            mon.tick(ctx)
    out: list[dict[str, Any]] = [{} for _ in runs]

    def finish(k: int) -> None:
        out[k] = runs[k][0].finish(runs[k][1])

    threads = [threading.Thread(target=finish, args=(k,)) for k in range(len(runs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    return out


def _tracks(start: np.ndarray, vel: np.ndarray, ticks: int) -> np.ndarray:
    t = np.arange(ticks)[:, None, None] * DT
    return start[None] + vel[None] * t




def _bystanders(x_m: list[float]) -> np.ndarray:
    """Drones far north (they meet nobody) at ``x_m``: with the pair they put the strip edge (the
    median x at the start) at x = 0."""
    return np.array([[x, 3000.0 + 400.0 * k, 60.0] for k, x in enumerate(x_m)])


def test_a_pair_in_los_handed_over_across_the_strip_edge_is_counted_once() -> None:
    # two drones 40 m apart (in LoS, outside NMAC) fly east together across x = 0
    pair = np.array([[-60.0, 0.0, 60.0], [-60.0, 40.0, 60.0]])
    start = np.vstack([pair, _bystanders([-900.0, -700.0, 60.0, 400.0, 700.0, 900.0])])
    vel = np.zeros_like(start)
    vel[:2, 0] = 8.0  # [m/s]
    tracks = _tracks(start, vel, 160)  # 16 s: from x = -60 m to x = +68 m
    assert Strips(start[:, 0], 2).edges[0] == pytest.approx(0.0)
    assert tracks[0, 0, 0] < 0.0 < tracks[-1, 0, 0]  # the pair changes strips (the owner of its lower row)
    one, msgs1 = _fly(tracks, 1)
    two, msgs2 = _fly(tracks, 2)
    assert one[0]["los"] == 1 and one[0]["nmac"] == 0
    for m in two:  # every rank ends with the one-process metrics
        assert {k: m[k] for k in ("los", "nmac", "sep_min_h_m", "sep_min_3d_m", "sep_nn_median_m", "sep_nn_p05_m")} \
            == {k: one[0][k] for k in ("los", "nmac", "sep_min_h_m", "sep_min_3d_m", "sep_nn_median_m", "sep_nn_p05_m")}
    assert sorted(msgs2[0] + msgs2[1]) == sorted(msgs1[0])  # the entry logged once, by one rank


def test_the_halo_sees_a_pair_converging_across_the_strip_edge() -> None:
    # one drone in each strip, head-on across x = 0 at the same altitude: LoS, then NMAC
    pair = np.array([[-80.0, 0.0, 60.0], [80.0, 1.0, 60.0]])
    start = np.vstack([pair, _bystanders([-900.0, -300.0, 300.0, 900.0])])
    assert Strips(start[:, 0], 2).edges[0] == pytest.approx(0.0)
    vel = np.zeros_like(start)
    vel[0, 0], vel[1, 0] = 7.0, -7.0  # [m/s]
    tracks = _tracks(start, vel, 130)  # 13 s: they pass at t = 11.4 s
    one, msgs1 = _fly(tracks, 1)
    two, msgs2 = _fly(tracks, 2)
    assert one[0]["los"] == 1 and one[0]["nmac"] == 1
    assert one[0]["sep_min_3d_m"] == pytest.approx(1.0, abs=1e-6)
    for m in two:
        for k in ("los", "nmac", "sep_min_h_m", "sep_min_3d_m", "sep_nn_median_m", "sep_nn_p05_m"):
            assert m[k] == one[0][k], k
    assert sorted(msgs2[0] + msgs2[1]) == sorted(msgs1[0])


def test_a_collision_across_the_strip_edge_is_counted_once() -> None:
    """The collision monitor in two ranks (each checks the pairs with a row in its strip, on its rows
    within box reach of it): a head-on collision across x = 0, found by both ranks, is one collision
    at the one-process contact time, logged once."""
    from corridor.analysis.monitoring.collisions import CollisionMonitor

    pair = np.array([[-8.0, 0.0, 60.0], [8.0, 0.1, 60.0]])
    start = np.vstack([pair, _bystanders([-900.0, -300.0, 300.0, 900.0])])
    vel = np.zeros_like(start)
    vel[0, 0], vel[1, 0] = 7.0, -7.0  # [m/s]: they meet at t = 1.14 s, between ticks
    tracks = _tracks(start, vel, 20)
    import multiprocessing as mp

    a, b = mp.Pipe()
    runs: list[tuple[CollisionMonitor, RunContext]] = []
    for shard in (None, ShardComm(0, 2, {1: a}), ShardComm(1, 2, {0: b})):
        ctx = RunContext(run_seed=0, dt=DT, duration=2.0)
        ctx.shard = shard
        runs.append((CollisionMonitor("collisions", CollisionMonitor.Params(), None), ctx))
    out = _drive(runs, tracks)
    assert out[0]["collisions"] == 1 and 1.0 < out[0]["first_collision_s"] < 1.2
    assert out[1] == out[0] and out[2] == out[0]
    logs = [[(e.t, e.message) for e in ctx.events.events] for _, ctx in runs]
    assert logs[1] == logs[0] and logs[2] == logs[0]  # every rank logs the union; the merged log keeps one
