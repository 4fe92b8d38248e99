"""The parking planner on the four given TPCAP cases, far from the origin, and on infeasible cases."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from corridor.controllers.parking import planner as planner_module
from corridor.controllers.parking import profile
from corridor.controllers.parking.case import Case, read_case
from corridor.controllers.parking.check import check
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, Obstacles
from corridor.controllers.parking.planner import InputError, NoSolution, PlanBudget, Trajectory, plan
from corridor.controllers.parking.search import hybrid_astar, merge
from tests.conftest import TEST_DATA

DATA = TEST_DATA / "tpcap"


def solve(case: Case, **kw: float) -> Trajectory:
    return plan(case.start, case.goal, case.obstacles, **kw)


@pytest.mark.parametrize("name", ["Case1", "Case2", "Case10", "Case17"])
def test_given_cases_pass_the_independent_check(name: str) -> None:
    case = read_case(DATA / f"{name}.csv")
    tr = solve(case)
    assert tr.stage == "optimised"
    assert check(case, tr.as_array()) == []
    assert (tr.x[0], tr.y[0], tr.theta[0]) == pytest.approx(case.start, abs=1e-9)  # exactly the start state
    assert tr.v[0] == tr.steer[0] == 0.0
    assert np.max(np.diff(tr.t)) <= 0.1 + 1e-9
    assert tr.length_m() > np.hypot(case.goal[0] - case.start[0], case.goal[1] - case.start[1]) - 1e-6
    assert tr.direction_changes() >= 0 and tr.search_time_s > 0


def test_a_case_far_from_the_origin_solves_identically() -> None:
    case = read_case(DATA / "Case17.csv")
    shift = np.array([1e9, -1e9])
    far = Case(start=(case.start[0] + shift[0], case.start[1] + shift[1], case.start[2]),
               goal=(case.goal[0] + shift[0], case.goal[1] + shift[1], case.goal[2]),
               obstacles=tuple(p + shift for p in case.obstacles))
    near, away = solve(case), solve(far)
    assert len(near.t) == len(away.t)
    np.testing.assert_allclose(away.x - shift[0], near.x, atol=1e-5)
    np.testing.assert_allclose(away.y - shift[1], near.y, atol=1e-5)
    np.testing.assert_allclose(away.theta, near.theta, atol=1e-6)
    assert check(far, away.as_array()) == []


def test_the_fallback_time_parametrisation_meets_every_limit() -> None:
    """The stop-and-steer search path (used when the optimisation fails) passes the checker as is,
    and is slower than the optimised trajectory."""
    case = read_case(DATA / "Case2.csv")
    origin = np.array(case.start[:2])
    polys = [p - origin for p in case.obstacles]
    start = (0.0, 0.0, case.start[2])
    goal = (case.goal[0] - origin[0], case.goal[1] - origin[1], case.goal[2])
    obs = Obstacles(polys)
    segs = merge(hybrid_astar(start, goal, obs, TPCAP_VEHICLE, (-40, 40, -40, 40)))
    st = profile.sample(profile.phases(segs, TPCAP_VEHICLE), start, TPCAP_VEHICLE, 0.1)
    rows = np.column_stack([st[k] for k in ("t", "x", "y", "theta", "v", "a", "steer")])
    rows[:, 1:3] += origin
    assert check(case, rows) == []
    assert rows[-1, 0] > solve(case).duration_s


def walls_around(x: float, y: float, half: float = 6.0, thick: float = 0.5) -> list[np.ndarray]:
    def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return [box(x - half, y - half, x + half, y - half + thick), box(x - half, y + half - thick, x + half, y + half),
            box(x - half, y - half, x - half + thick, y + half), box(x + half - thick, y - half, x + half, y + half)]


def test_goal_inside_an_obstacle_has_no_solution() -> None:
    block = np.array([[18.0, -2.0], [24.0, -2.0], [24.0, 2.0], [18.0, 2.0]])
    with pytest.raises(NoSolution, match="goal pose collides") as err:
        plan((0.0, 0.0, 0.0), (20.0, 0.0, 0.0), [block])
    assert "\n" not in str(err.value)


def test_enclosed_goal_has_no_solution() -> None:
    with pytest.raises(NoSolution) as err:
        plan((0.0, 0.0, 0.0), (20.0, 0.0, 0.0), walls_around(20.0, 0.0))
    assert "\n" not in str(err.value) and "no" in str(err.value)


def test_trajectory_counts_direction_changes_and_length() -> None:
    t = np.arange(9) * 0.1
    v = np.array([1.0, 1.0, 0.0, -1.0, -1.0, 0.0, 0.05, -1.0, 0.0])  # the 5 mm run forward is not counted
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * 0.1)])
    tr = Trajectory(t, x, x * 0, t * 0, v, t * 0, t * 0, 0.1, 0.2)
    assert tr.direction_changes() == 1
    assert tr.direction_changes(min_run_m=0.001) == 3
    assert tr.length_m() == pytest.approx(0.2 + 0.2 + 0.005 + 0.1)


def test_a_budget_too_small_is_named_in_the_reason() -> None:
    case = read_case(DATA / "Case10.csv")
    with pytest.raises(NoSolution, match="within 3 expansions") as err:
        plan(case.start, case.goal, case.obstacles, budget=PlanBudget(coarse_expansions=3, fine_expansions=3))
    assert "\n" not in str(err.value)


def test_plans_do_not_depend_on_the_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """The same case twice gives a bit-identical trajectory, also when the clock runs 1000 times
    faster (a loaded machine): no decision reads the clock."""
    case = read_case(DATA / "Case1.csv")
    first = plan(case.start, case.goal, case.obstacles).as_array()
    real = time.perf_counter
    monkeypatch.setattr(time, "perf_counter", lambda: 1000.0 * real())
    again = plan(case.start, case.goal, case.obstacles).as_array()
    assert first.shape == again.shape and np.array_equal(first, again)


def test_no_planner_module_reads_the_clock_to_decide() -> None:
    """Only the planner's timing report reads the clock; the search, optimisation and warm starts
    never do, and IPOPT gets no wall-time cap."""
    src = Path(planner_module.__file__).parent
    for name in ("search.py", "optimise.py", "warm_start.py", "profile.py", "heuristic.py", "geometry.py"):
        text = (src / name).read_text()
        assert "perf_counter" not in text and "time.time" not in text and "max_wall_time" not in text, name
    body = (src / "planner.py").read_text()
    assert body.count("perf_counter") == 4  # t0, the search's end, the optimisation's end, the one-row case


def test_goal_equal_to_start_is_a_one_row_trajectory() -> None:
    case = read_case(DATA / "Case17.csv")
    tr = plan(case.start, case.start, case.obstacles)
    assert tr.as_array().shape == (1, 7)
    assert (tr.x[0], tr.y[0], tr.theta[0], tr.v[0]) == (*case.start, 0.0)
    same = Case(start=case.start, goal=case.start, obstacles=case.obstacles)
    assert check(same, tr.as_array()) == []


@pytest.mark.parametrize("goal, bound", [((100_000.0, 0.0, 0.0), "MAX_GRID_CELLS"), ((10.0, 0.0, 0.0), "MAX_GRID_CELLS")])
def test_a_huge_search_area_is_refused_before_any_grid(goal: tuple[float, float, float], bound: str) -> None:
    far_obstacle = [np.array([[5000.0, 5000.0], [5001.0, 5000.0], [5001.0, 5001.0]])]
    with pytest.raises(InputError, match=bound) as err:
        plan((0.0, 0.0, 0.0), goal, far_obstacle if goal[0] == 10.0 else [])
    assert "\n" not in str(err.value)


def test_a_tiny_output_step_is_refused() -> None:
    with pytest.raises(InputError, match="dt"):
        plan((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), [], dt_s=1e-9)
