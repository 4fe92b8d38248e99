"""The planner on TPCAP-format cases built to reproduce how held-out cases broke it: a goal that
clears its nearest obstacle by 0.17 m and cannot be left by the normal search's 0.3 m steps, a
cluttered lot, and the same case planned twice (plans must not depend on the machine's load)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from corridor.controllers.parking.check import check
from corridor.controllers.parking.planner import plan
from tests.controllers import tpcap_cases as tc

WALL_S = 10.0  # [s] every case within this here (the machine is shared: the plan is timed once)


def test_a_tight_parallel_goal_is_planned_and_verified() -> None:
    """Kerb 0.17 m beside the goal footprint, parked cars 0.5 m ahead and behind: every 0.3 m step
    from the goal meets the search margin, so the goal-side search used to be exhausted after a few
    expansions and the case had no path; near the goal the search now takes 0.1 m steps."""
    case = tc.tight_parallel(gap_m=0.17, slot_extra_m=1.0)
    assert tc.clearance(case, case.goal) == pytest.approx(0.17, abs=1e-9)
    t0 = time.perf_counter()
    tr = plan(case.start, case.goal, case.obstacles)
    wall = time.perf_counter() - t0
    assert check(case, tr.as_array()) == []
    assert tr.stage == "optimised" and tr.direction_changes() >= 2
    assert wall < 2 * WALL_S  # a loose bound: the tight bound is the benchmark's (see docs/guide/parking.md)


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


def test_a_cluttered_lot_is_planned_and_verified() -> None:
    case = tc.cluttered(n=37, seed=4, size_m=26.0)
    assert len(case.obstacles) == 37
    t0 = time.perf_counter()
    tr = plan(case.start, case.goal, case.obstacles)
    wall = time.perf_counter() - t0
    assert check(case, tr.as_array()) == []
    assert wall < 2 * WALL_S


def test_the_same_case_twice_gives_a_bit_identical_trajectory() -> None:
    case = tc.tight_parallel(gap_m=0.17, slot_extra_m=1.0)
    first = plan(case.start, case.goal, case.obstacles).as_array()
    again = plan(case.start, case.goal, case.obstacles).as_array()
    assert first.shape == again.shape and np.array_equal(first, again)
