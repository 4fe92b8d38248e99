"""A collision and the safety specification must not disagree (issue 18, item 5).

An overtaking run whose MPC never found a valid plan (every period fell back to the emergency input)
braked the ego to a standstill in its lane; the SUMO follower ran into it (``collisions=1``) while
``spec.safety`` was satisfied: the spec names only the lead and the oncoming cars. The ego now records
``clearance``, its smallest box clearance to *any* other vehicle, so the signals record every contact;
and ``evaluate_specs`` no longer invents samples (values copied back to t = 0, zeros for missing
signals, interpolation across gaps).
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from corridor.analysis.monitoring.stl_specs import evaluate_specs
from corridor.controllers.overtaking.controller import box_clearance
from corridor.controllers.overtaking.mpc import OvertakingMpc
from corridor.engine import Signals
from corridor.run import simulate
from corridor.scenario import load
from corridor.stl import STLSignalError
from corridor.vehicles.ground.bicycle import BicycleParams
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "overtaking.yaml"
CLEARANCE_SPEC = "G(clearance > 0)"


# ---- evaluate_specs: resampling never invents a measurement ---------------------------------------------
def specs_of(signals: dict[str, tuple[np.ndarray, np.ndarray]], formula: str) -> dict:
    recorded = Signals()
    for name, (t, v) in signals.items():
        for ti, vi in zip(t, v, strict=True):
            recorded.record(name, float(ti), float(vi))
    sc = SimpleNamespace(specs=[SimpleNamespace(name="s", formula=formula)], dt=0.1, duration=100.0)
    return evaluate_specs(sc, SimpleNamespace(signals=recorded))  # type: ignore[arg-type]


def test_spec_starts_at_the_first_sample_and_interpolates_only_between_neighbours() -> None:
    t = 60.0 + 0.2 * np.arange(101)  # recorded every 0.2 s from 60 s to 80 s
    ok = specs_of({"x": (t, 1.0 + 0.1 * np.arange(101))}, "G(x > 0) & F[0,0.1](x < 1.05)")
    assert ok["spec.s.satisfied"] and ok["spec.s.space"] == pytest.approx(0.05)  # t = 0 is 60 s, x = 1.0
    gap = (t < 65.0) | (t > 75.0)  # ten seconds missing: not interpolated across
    r = specs_of({"x": (t[gap], np.ones(gap.sum()))}, "G(x > 0)")
    assert not r["spec.s.satisfied"] and math.isnan(r["spec.s.space"])
    r = specs_of({"x": (t, np.ones(101)), "y": (t[t >= 70.0], np.ones((t >= 70.0).sum()))}, "G(x > 0 & y > 0)")
    assert not r["spec.s.satisfied"]  # y starts 10 s after x: unknown there, not its first value copied


def test_spec_reading_a_signal_never_recorded_is_an_error_not_zeros() -> None:
    with pytest.raises(STLSignalError, match="'y' is not recorded"):
        specs_of({"x": (np.arange(5.0), np.ones(5))}, "G(y < 1)")


# ---- the ego's clearance to everyone -------------------------------------------------------------------
def test_box_clearance_is_the_gap_to_the_nearest_box_and_negative_on_contact() -> None:
    ego = BicycleParams()
    state = np.array([[0.0, 0.0, 0.0, 10.0]])  # rear axle at x = 0, body centre at wheelbase / 2
    xc = 0.5 * ego.wheelbase_m
    size = np.array([[4.5, 1.8]])
    behind = np.array([[xc - 0.5 * (ego.length_m + 4.5) - 2.0, 0.0]])  # 2 m bumper gap behind
    assert box_clearance(state, ego, behind, np.zeros(1), size)[0] == pytest.approx(2.0)
    touching = behind + [[2.3, 0.0]]
    assert box_clearance(state, ego, touching, np.zeros(1), size)[0] == pytest.approx(-0.3)
    beside = np.array([[xc, 3.5]])  # same x, next lane: lateral gap 3.5 - 1.8
    assert box_clearance(state, ego, beside, np.array([math.pi]), size)[0] == pytest.approx(1.7)
    assert box_clearance(state, ego, np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)))[0] == 1.0e3


# ---- an overtaking run whose every plan fails --------------------------------------------------------------
@pytest.fixture(scope="module")
def fallback_run() -> tuple[dict, object, object]:
    """Every MPC solve reported failed: the ego plays the emergency input every period (the NaN weight of
    the issue had that effect; scenario parameters now refuse NaN, any fallback does the same)."""
    real = OvertakingMpc.solve
    patch = pytest.MonkeyPatch()
    patch.setattr(OvertakingMpc, "solve", lambda self, *a, **k: dataclasses.replace(real(self, *a, **k), ok=False))
    try:
        sc, _ = load(SCENARIO)
        metrics, ctx, _ = simulate(sc, 0)
    finally:
        patch.undo()
    return metrics, ctx, sc


def test_fallback_collision_is_recorded_by_the_spec_signals(fallback_run) -> None:
    metrics, ctx, sc = fallback_run
    assert metrics["fallbacks"] > 100 and metrics["collisions"] >= 1  # the follower runs into the ego
    t, clearance = ctx.signals.get("clearance")
    first = metrics["first_collision_s"]
    assert clearance[np.argmin(np.abs(t - first))] <= 0.0  # contact at the reported time
    assert np.all(clearance[t < first - 0.5] > 0.0)  # and none before it
    extended = [*sc.specs, type(sc.specs[0])(name="contact", formula=CLEARANCE_SPEC)]
    result = evaluate_specs(sc.model_copy(update={"specs": extended}), ctx)
    assert not result["spec.contact.satisfied"] and result["spec.contact.space"] <= 0.0


def test_fallback_collision_violates_the_scenario_safety_spec(fallback_run) -> None:
    metrics, _, _ = fallback_run
    assert metrics["collisions"] >= 1
    assert not metrics["spec.safety.satisfied"]
