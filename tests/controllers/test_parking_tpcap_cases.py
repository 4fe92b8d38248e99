"""The planner on TPCAP-format cases built to reproduce how held-out cases broke it: a goal that
clears its nearest obstacle by 0.17 m and cannot be left by the normal search's 0.3 m steps, a
cluttered lot, and the same case planned twice (plans must not depend on the machine's load).

No assertion here reads a clock: the work of a plan is bounded by its `PlanBudget` (a plan that
returns stayed within it) and measured by `Trajectory.expansions`; planning times on this machine
are printed by `benchmarks/parking_plan.py` (see docs/guide/parking.md)."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.parking.check import check
from corridor.controllers.parking.planner import PlanBudget, plan
from tests.controllers import tpcap_cases as tc

COARSE_WORK = 2 * PlanBudget().coarse_expansions  # both coarse searches, no fine search needed


def test_a_tight_parallel_goal_is_planned_and_verified() -> None:
    """Kerb 0.17 m beside the goal footprint, parked cars 0.5 m ahead and behind: every 0.3 m step
    from the goal meets the search margin, so the goal-side search used to be exhausted after a few
    expansions and the case had no path; near the goal the search now takes 0.1 m steps."""
    case = tc.tight_parallel(gap_m=0.17, slot_extra_m=1.0)
    assert tc.clearance(case, case.goal) == pytest.approx(0.17, abs=1e-9)
    tr = plan(case.start, case.goal, case.obstacles)  # within the default budget, else NoSolution
    assert check(case, tr.as_array()) == []
    assert tr.stage == "optimised" and tr.direction_changes() >= 2
    assert 0 < tr.expansions <= COARSE_WORK


@pytest.mark.parametrize("gap_m", [0.17, 0.03])
def test_a_tight_perpendicular_goal_is_planned_and_verified(gap_m: float) -> None:
    """Parked cars beside the goal and the kerb behind it, each ``gap_m`` from its footprint. At
    0.03 m the search's 0.05 m margin exceeded the clearance: the goal-side search was exhausted after
    1 expansion and the case had no path. The margins now shrink to half the ends' clearance (still
    >= 0 and a hard constraint of the optimisation), and the checker (no margin) passes the result."""
    case = tc.tight_perpendicular(gap_m=gap_m)
    assert tc.clearance(case, case.goal) == pytest.approx(gap_m, abs=1e-9)
    tr = plan(case.start, case.goal, case.obstacles)
    assert check(case, tr.as_array()) == []
    assert tr.stage == "optimised"


@pytest.mark.parametrize("seed", [3, 4, 9])
def test_a_cluttered_lot_is_planned_by_the_coarse_searches_and_verified(seed: int) -> None:
    """37 obstacles on 26 m. Seed 3 used to spend every budget without a path (its goal-side search
    needed about 8,700 expansions, drawn into gaps narrower than the car by the holonomic heuristic);
    the heuristic now follows the footprint's centre and rear axle with the clearance each needs."""
    case = tc.cluttered(n=37, seed=seed, size_m=26.0)
    assert len(case.obstacles) == 37
    tr = plan(case.start, case.goal, case.obstacles)
    assert check(case, tr.as_array()) == []
    assert tr.stage == "optimised"
    assert 0 < tr.expansions <= COARSE_WORK


def test_a_path_that_clips_between_checks_does_not_restart_its_search() -> None:
    """Seed 9: the goal-side search's first path (after about 2,000 expansions) clips the
    optimisation's margin between the 0.2 m collision checks of one primitive. A new search with
    denser checks used to start from scratch (about 7,800 expansions in all); the search now cuts
    off that primitive and goes on (about 4,000)."""
    case = tc.cluttered(n=37, seed=9, size_m=26.0)
    tr = plan(case.start, case.goal, case.obstacles)
    assert check(case, tr.as_array()) == []
    assert tr.expansions <= 5000


def test_the_same_case_twice_gives_a_bit_identical_trajectory() -> None:
    case = tc.tight_parallel(gap_m=0.17, slot_extra_m=1.0)
    first = plan(case.start, case.goal, case.obstacles).as_array()
    again = plan(case.start, case.goal, case.obstacles).as_array()
    assert first.shape == again.shape and np.array_equal(first, again)
