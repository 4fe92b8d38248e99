"""UAV separation monitor: closed-form miss distances, per-encounter NMAC/LoS counting, piloted
thresholds, goal metrics — on the engine with the null backend (constant-velocity point masses)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from corridor.analysis.monitoring.separation import SeparationMonitor
from corridor.engine import RunContext, Simulation
from corridor.null_backend import NullBackend
from corridor.snapshot import Kind, Role, WorldSnapshot

SCEN = SimpleNamespace(dt=0.1)


def run_pair(offset_m: tuple[float, float], duration_s: float = 20.0, **params: float) -> tuple[dict, RunContext]:
    """Two UAVs head-on along x at 10 m/s each, closest approach at t = 10 s with the given
    (lateral, vertical) offset."""
    dy, dz = offset_m
    pos = np.array([[-100.0, 0.0, 50.0], [100.0, dy, 50.0 + dz]])
    vel = np.array([[10.0, 0.0, 0.0], [-10.0, 0.0, 0.0]])
    air = NullBackend("air", ["a", "b"], pos, vel, period=0.1, kind=Kind.UAV)
    mon = SeparationMonitor("sep", SeparationMonitor.Params(backend=None, **params), SCEN)
    ctx = RunContext(run_seed=0, dt=0.1, duration=duration_s)
    metrics = Simulation(ctx, [air, mon]).run()
    return metrics, ctx


def test_head_on_miss_distance_and_nmac_closed_form() -> None:
    m, ctx = run_pair((20.0, 0.0))
    assert m["sep_min_h_m"] == pytest.approx(20.0, abs=1e-6)
    assert m["sep_min_3d_m"] == pytest.approx(20.0, abs=1e-6)
    assert m["sep_min_v_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["nmac"] == 1 and m["los"] == 1 and m["nmac_pairs"] == 1
    nmac = ctx.events.of_kind("nmac")
    # enters the 30.48 m cylinder when the 20 m/s closure brings sqrt(dx^2 + 20^2) below 30.48
    t_enter = 10.0 - np.sqrt(30.48**2 - 20.0**2) / 20.0
    assert len(nmac) == 1 and nmac[0].t == pytest.approx(np.ceil(t_enter / 0.1) * 0.1, abs=1e-6)
    t, v = ctx.signals.get("min_sep_h")
    assert v.min() == pytest.approx(20.0, abs=1e-6) and t[np.argmin(v)] == pytest.approx(10.0, abs=1e-6)


def test_vertical_offset_above_nmac_is_los_only() -> None:
    m, _ = run_pair((20.0, 5.0))  # 5 m > 4.572 m (15 ft), < 15.24 m (50 ft)
    assert m["nmac"] == 0 and m["los"] == 1
    assert m["sep_min_3d_m"] == pytest.approx(np.hypot(20.0, 5.0), abs=1e-6)
    assert m["sep_min_v_m"] == pytest.approx(5.0, abs=1e-9)


def test_wide_miss_has_no_event_and_thresholds_come_from_params() -> None:
    m, _ = run_pair((70.0, 0.0))
    assert m["nmac"] == 0 and m["los"] == 0 and np.isnan(m["sep_min_v_m"])
    m2, _ = run_pair((70.0, 0.0), los_h_m=80.0, nmac_h_m=75.0)
    assert m2["nmac"] == 1 and m2["los"] == 1


def _ctx_with(positions: list[list[float]], kinds: list[Kind], t: float) -> RunContext:
    n = len(positions)
    ctx = RunContext(run_seed=0, dt=0.1, duration=100.0, t=t)
    ctx.snapshot = WorldSnapshot(t=t, ids=np.array([f"x{i}" for i in range(n)], dtype=object),
                                 kind=np.array(kinds, dtype=np.int8), role=np.full(n, Role.OTHER, dtype=np.int8),
                                 position=np.array(positions, float), velocity=np.zeros((n, 3)),
                                 heading=np.zeros(n), size=np.tile([0.5, 0.5, 0.2], (n, 1)))
    return ctx


def test_each_entry_into_nmac_counts_once() -> None:
    mon = SeparationMonitor("sep", SeparationMonitor.Params(backend=None), SCEN)
    mon.setup(RunContext(run_seed=0, dt=0.1, duration=10.0))
    # inside, inside, outside, inside again: two pair-encounters
    gaps = [10.0, 12.0, 50.0, 8.0, 9.0]
    for k, g in enumerate(gaps):
        ctx = _ctx_with([[0, 0, 50], [g, 0, 50]], [Kind.UAV, Kind.UAV], 0.1 * k)
        mon.tick(ctx)
    m = mon.finish(ctx)
    assert m["nmac"] == 2 and m["nmac_pairs"] == 1 and m["sep_min_h_m"] == pytest.approx(8.0)


def test_piloted_pairs_use_the_well_clear_volume() -> None:
    mon = SeparationMonitor("sep", SeparationMonitor.Params(backend=None), SCEN)
    mon.setup(RunContext(run_seed=0, dt=0.1, duration=10.0))
    # UAV x0 and aircraft x1: 500 m / 50 m apart: inside 2000 ft / 250 ft well clear -> LoS
    # UAV x0 and UAV x2: 500 m apart: far outside the UAV-UAV volume
    ctx = _ctx_with([[0, 0, 50], [500, 0, 100], [0, 500, 50]], [Kind.UAV, Kind.AIRCRAFT, Kind.UAV], 0.0)
    mon.tick(ctx)
    m = mon.finish(ctx)
    assert m["los"] == 1 and m["nmac"] == 0  # x2-x1 is 707 m apart: outside 609.6 m


def test_time_to_goal_and_path_ratio() -> None:
    mon = SeparationMonitor("sep", SeparationMonitor.Params(backend=None, goal_radius_m=1.0), SCEN)
    mon.setup(RunContext(run_seed=0, dt=0.1, duration=10.0))
    mon.goals = {"x0": (np.array([0.0, 0.0, 50.0]), np.array([30.0, 0.0, 50.0]))}
    # x0 flies a right-angle dog-leg (0,0) -> (15,15) -> (30,0) at 10 s per leg; x1 stays far away
    for k in range(201):
        t = 0.1 * k
        leg = min(t, 10.0) / 10.0, max(t - 10.0, 0.0) / 10.0
        p = [15.0 * leg[0] + 15.0 * leg[1], 15.0 * leg[0] - 15.0 * leg[1], 50.0]
        mon.tick(_ctx_with([p, [0, 900, 50]], [Kind.UAV, Kind.UAV], t))
    m = mon.finish(_ctx_with([p, [0, 900, 50]], [Kind.UAV, Kind.UAV], 20.0))
    # arrives within 1 m of the goal when the remaining 21.2 m leg has < 1 m left: t = 20 - 10/21.21
    assert m["time_to_goal_mean_s"] == pytest.approx(np.ceil((20.0 - 10.0 / np.hypot(15, 15)) / 0.1) * 0.1, abs=1e-6)
    assert m["path_ratio_mean"] == pytest.approx(2.0 * np.hypot(15.0, 15.0) / 30.0, rel=1e-6)
    assert m["goal_reached_frac"] == 1.0


def test_tracks_are_recorded_every_track_period_at_the_true_positions() -> None:
    _, ctx = run_pair((20.0, 5.0), duration_s=5.0, track_period_s=1.0)
    t, e = ctx.signals.get("track_e_a")
    _, n = ctx.signals.get("track_n_b")
    _, u = ctx.signals.get("track_u_b")
    assert np.allclose(t, [0.1, 1.1, 2.1, 3.1, 4.1])  # the first tick after each period
    assert np.allclose(e, -100.0 + 10.0 * t) and np.allclose(n, 20.0) and np.allclose(u, 55.0)
    _, ctx = run_pair((20.0, 0.0), duration_s=1.0, track_period_s=None)
    assert not any(k.startswith("track_") for k in ctx.signals.names())
