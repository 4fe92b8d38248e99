"""Multi-fidelity air backend: promotion / demotion events, a hand-over that keeps the recorded
trajectory continuous, multi-rate interpolation, and the parameter checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from corridor.engine import Component, Phase, RunContext, Simulation
from corridor.scenario import validate
from corridor.vehicles.air.fidelity import FidelityParams
from corridor.vehicles.air.mf_backend import MultiFidelityAirBackend


class Trace(Component):
    """Records every tick's snapshot rows (RECORD phase, never changes a trajectory)."""

    phase = Phase.RECORD

    def __init__(self) -> None:
        super().__init__("trace")
        self.t: list[float] = []
        self.pos: list[np.ndarray] = []
        self.vel: list[np.ndarray] = []

    def tick(self, ctx: RunContext) -> None:
        self.t.append(ctx.t)
        self.pos.append(ctx.snapshot.position.copy())
        self.vel.append(ctx.snapshot.velocity.copy())


PAIR = [{"id": "a", "start_enu": (-200, 0, 60), "goal_enu": (400, 0, 60), "cruise_speed_mps": 7},
        {"id": "b", "start_enu": (200, 40, 62), "goal_enu": (-400, 40, 62), "cruise_speed_mps": 7}]


def fly(tmp_path: Path, fidelity: dict[str, Any], duration: float = 60.0, pm_period: float = 0.5,
        aircraft: list[dict[str, Any]] | None = None) -> tuple[Trace, RunContext, dict[str, Any]]:
    params = {"aircraft": aircraft or PAIR, "fidelity": fidelity, "point_mass_period_s": pm_period}
    sc = validate({"name": "t", "duration": duration, "dt": 0.1,
                   "backends": {"air": {"type": "multi_fidelity_fleet", "params": params}}}, "test")
    backend = MultiFidelityAirBackend("air", MultiFidelityAirBackend.Params(**params), sc)
    ctx = RunContext(run_seed=0, dt=0.1, duration=duration, scenario=sc, workdir=tmp_path)
    trace = Trace()
    metrics = Simulation(ctx, [backend, trace]).run()
    return trace, ctx, metrics


MULTI = {"mode": "multi", "promote_radius_m": 100.0, "promote_ttca_s": 8.0, "demote_radius_m": 150.0,
         "min_dwell_s": 2.0}


def test_pair_is_promoted_then_demoted_with_events(tmp_path: Path) -> None:
    trace, ctx, m = fly(tmp_path, MULTI)
    prom, dem = ctx.events.of_kind("promote"), ctx.events.of_kind("demote")
    assert sorted(e.data["uav"] for e in prom) == ["a", "b"] and sorted(e.data["uav"] for e in dem) == ["a", "b"]
    # closing at 14 m/s, passing 40 m apart at t ~ 30.4 s (1.8 s lost accelerating): promoted when
    # they will be within 100 m within 8 s (about 204 m apart, t ~ 16 s); demoted once 150 m apart
    # again after the pass (t ~ 40.7 s) -- the hysteresis
    t_prom, t_dem = prom[0].t, dem[0].t
    assert 14.5 < t_prom < 17.5 and 39.0 < t_dem < 43.0
    assert m["promotions"] == 2 and m["demotions"] == 2
    share = (t_dem - t_prom) / 60.0
    assert m["six_dof_share"] == pytest.approx(share, abs=0.02)


@pytest.mark.parametrize("pm_period", [0.1, 0.5])
def test_hand_over_keeps_the_recorded_trajectory_continuous(tmp_path: Path, pm_period: float) -> None:
    """At every switch the recorded position has no step: its second difference stays below
    0.1 m (a smooth flight at <= 3.5 m/s^2 gives 0.035 m at 0.1 s) and the velocity changes by less
    than 0.5 m/s within one tick."""
    trace, ctx, _ = fly(tmp_path, MULTI, pm_period=pm_period)
    t = np.array(trace.t)
    p, v = np.array(trace.pos), np.array(trace.vel)
    switches = [e.t for e in ctx.events.of_kind("promote") + ctx.events.of_kind("demote")]
    assert len(switches) == 4
    for ts in switches:
        k = int(np.argmin(np.abs(t - ts)))
        window = slice(k - 1, k + 3)
        d2 = np.linalg.norm(np.diff(p[window], n=2, axis=0), axis=2)
        dv = np.linalg.norm(np.diff(v[window], axis=0), axis=2)
        assert d2.max() < 0.1, (ts, d2)
        assert dv.max() < 0.5, (ts, dv)


def test_multi_fidelity_stays_close_to_all_6dof(tmp_path: Path) -> None:
    multi, _, _ = fly(tmp_path, MULTI)
    full, _, m = fly(tmp_path, {"mode": "jsbsim"})
    assert m["six_dof_share"] == pytest.approx(1.0)
    gap = np.linalg.norm(np.array(multi.pos) - np.array(full.pos), axis=2)
    assert gap.max() < 6.0


def test_point_mass_rows_are_interpolated_between_coarse_steps(tmp_path: Path) -> None:
    coarse, _, _ = fly(tmp_path, {"mode": "point_mass"}, duration=20.0, pm_period=1.0)
    fine, _, _ = fly(tmp_path, {"mode": "point_mass"}, duration=20.0, pm_period=0.1)
    p = np.array(coarse.pos)
    assert len(p) == 200  # a row every dt = 0.1 s although the point masses step every 1 s
    step = np.linalg.norm(np.diff(p, axis=0), axis=2)
    assert step.max() < 0.1 * 7.0 + 0.05  # no jumps at the 1 s boundaries
    assert np.linalg.norm(p - np.array(fine.pos), axis=2).max() < 1.5


def test_parameter_checks() -> None:
    with pytest.raises(ValidationError, match="demote_radius_m"):
        FidelityParams(promote_radius_m=200.0, demote_radius_m=100.0)
    sc = validate({"name": "t", "duration": 1.0, "dt": 0.1}, "test")
    with pytest.raises(ValueError, match="whole multiple"):
        MultiFidelityAirBackend("air", MultiFidelityAirBackend.Params(aircraft=PAIR, point_mass_period_s=0.25), sc)


def test_converging_pair_is_demoted_once_it_parts(tmp_path: Path) -> None:
    """``promote_on: converging``: the same head-on pair is promoted at the same boundary (it closes
    from the start) and demoted at its closest approach (t ~ 30 s: the range stops shrinking), not
    once 150 m apart again (t ~ 41 s)."""
    _, ctx, m = fly(tmp_path, {**MULTI, "promote_on": "converging"})
    prom, dem = ctx.events.of_kind("promote"), ctx.events.of_kind("demote")
    assert sorted(e.data["uav"] for e in prom) == ["a", "b"] and sorted(e.data["uav"] for e in dem) == ["a", "b"]
    assert 14.5 < prom[0].t < 17.5
    assert 29.0 < dem[0].t < 32.0
    assert m["six_dof_share"] < (32.0 - 14.5) / 60.0


def test_encounter_pair_stays_6dof_until_beyond_the_demotion_boundary(tmp_path: Path) -> None:
    """``promote_on: encounter``: the head-on pair is promoted as with ``converging`` (t ~ 16 s) but
    flies 6-DOF past its closest approach until 150 m apart (t ~ 41 s), as ``proximity`` does here."""
    _, ctx, m = fly(tmp_path, {**MULTI, "promote_on": "encounter"})
    prom, dem = ctx.events.of_kind("promote"), ctx.events.of_kind("demote")
    assert sorted(e.data["uav"] for e in prom) == ["a", "b"] and sorted(e.data["uav"] for e in dem) == ["a", "b"]
    assert 14.5 < prom[0].t < 17.5
    assert 39.0 < dem[0].t < 43.0
