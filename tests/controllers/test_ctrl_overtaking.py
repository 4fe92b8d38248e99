"""Closed-loop overtaking in the pure-Python world: safety, outcomes, modes, event-triggered re-planning.

Runs are deterministic per seed (the world and the controller own their generators).  The 20-seed
batch is marked slow; the default selection keeps a few seeds so the file stays well under a minute.
"""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.overtaking.controller import OvertakingParams, _transitions
from corridor.controllers.overtaking.sim import OvertakingRun, OvertakingWorldParams, run_overtaking

PARAMS = OvertakingParams()
WORLD = OvertakingWorldParams(duration_s=25.0)
# a driver who speeds up by 8 m/s when overtaken, with oncoming traffic just far enough to start a pass
HOSTILE = OvertakingWorldParams(duration_s=25.0, lead_reacts_prob=1.0, lead_reaction_mps=8.0,
                                lead_speed_mps=(15.0, 17.0), oncoming_first_m=(330.0, 360.0),
                                oncoming_gap_m=(500.0, 600.0))
EDGES = {(t.src, t.dst) for t in _transitions(OvertakingParams())}


def _check_safe(run: OvertakingRun) -> None:
    assert not run.collided, f"seed {run.seed}: collision"
    assert run.space_robustness_m > 0.0, f"seed {run.seed}: safety spec violated ({run.space_robustness_m:.2f} m)"
    assert run.outcome in ("passed", "aborted", "stayed")
    if run.final_mode == "follow":  # a finished run ends in its own lane
        assert abs(run.ego_states[-1, 1]) < 0.5
    else:  # or is still inside a pass, which must then be within its deadline
        assert run.final_mode in ("pass", "return", "abort")
    for ev in run.events.of_kind("mode"):
        assert (ev.data["src"], ev.data["dst"]) in EDGES


@pytest.fixture(scope="module")
def runs() -> list[OvertakingRun]:
    return [run_overtaking(seed, PARAMS, WORLD) for seed in range(3)]


def test_runs_are_safe(runs: list[OvertakingRun]) -> None:
    for run in runs:
        _check_safe(run)


def test_passes_complete_within_deadline(runs: list[OvertakingRun]) -> None:
    passed = [r for r in runs if r.outcome == "passed"]
    assert passed, "no run completed an overtake: the controller is safe only by never passing"
    for r in passed:
        assert 0.0 < r.completion_time_s <= PARAMS.deadline_s + PARAMS.period_s
        jumps = [(e.data["src"], e.data["dst"]) for e in r.events.of_kind("mode")]
        assert jumps.index(("decide", "pass")) < jumps.index(("pass", "return"))


def test_solve_time_recorded(runs: list[OvertakingRun]) -> None:
    for r in runs:
        assert len(r.solve_times_s) == r.replans > 0
        assert np.all(np.asarray(r.solve_times_s) > 0.0)


def test_hostile_lead_forces_a_safe_abort() -> None:
    hostile = [run_overtaking(seed, PARAMS, HOSTILE) for seed in (1,)]
    for r in hostile:
        _check_safe(r)
    assert any(r.outcome == "aborted" for r in hostile)
    for r in hostile:
        if r.outcome == "aborted":
            ab = [e for e in r.events.of_kind("mode") if e.data["dst"] == "abort"]
            assert ab and ab[0].message.endswith("gap closed")


def test_event_triggered_replans_less_than_every_step() -> None:
    world = OvertakingWorldParams(duration_s=12.0)
    ev = run_overtaking(0, PARAMS, world)
    every = run_overtaking(0, PARAMS.model_copy(update={"replan": "every_step"}), world)
    _check_safe(ev)
    _check_safe(every)
    assert every.replans >= every.steps  # one solve per period (plus decision solves)
    assert ev.replans < 0.5 * every.replans
    assert ev.outcome == every.outcome == "passed"


def test_same_seed_same_run() -> None:
    world = OvertakingWorldParams(duration_s=6.0)
    a, b = run_overtaking(7, PARAMS, world), run_overtaking(7, PARAMS, world)
    np.testing.assert_array_equal(a.ego_states, b.ego_states)
    assert [e.message for e in a.events.events] == [e.message for e in b.events.events]


@pytest.mark.slow
def test_twenty_seeds_safe_and_event_triggered_saves_solves() -> None:
    runs = [run_overtaking(seed, PARAMS, OvertakingWorldParams()) for seed in range(20)]
    for r in runs:
        _check_safe(r)
    assert sum(r.outcome == "passed" for r in runs) >= 10
    hostile = [run_overtaking(seed, PARAMS, HOSTILE) for seed in range(20)]
    for r in hostile:
        _check_safe(r)
    every = [run_overtaking(seed, PARAMS.model_copy(update={"replan": "every_step"}), OvertakingWorldParams())
             for seed in range(5)]
    for r in every:
        _check_safe(r)
    ratio = np.mean([r.replans for r in runs[:5]]) / np.mean([r.replans for r in every])
    assert ratio < 0.5


def test_pass_enter_boundary_decides_and_its_crossing_is_located(runs: list[OvertakingRun]) -> None:
    """The follow -> decide jump is the ``pass_enter`` boundary: its crossing time is located inside
    the period before the jump, and a range of 1 m (theta from the params) never lets it fire."""
    jumps = [e for r in runs for e in r.events.of_kind("mode") if e.data["dst"] == "decide"]
    assert jumps and all(e.data["boundary"] == "pass_enter" for e in jumps)
    assert all(e.t - PARAMS.period_s - 1e-9 <= e.data["t_cross"] <= e.t for e in jumps)
    timid = OvertakingParams(boundaries={"pass_enter": {"range_m": 1.0, "speed_margin_mps": 3.0}})
    run = run_overtaking(0, timid, WORLD)
    assert run.outcome == "stayed" and not run.events.of_kind("mode")
