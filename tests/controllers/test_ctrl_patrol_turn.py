"""Sector patrol: a UAV that converges to its goal without overshoot still turns at the sector ends."""

from __future__ import annotations

import math

from corridor.controllers.uav.components import patrol_target

A0, A1 = 0.0, math.radians(60.0)
R_M = 1591.5
LOOK, TURN = 60.0 / R_M, 10.0 / R_M


def _patrol(turn_rad: float, steps: int, gain: float = 0.1) -> tuple[list[float], int]:
    """A first-order tracker (moves ``gain`` of the way to its goal each step): angles and turns."""
    theta, d, turns, seen = A0 + 0.01, 1.0, 0, []
    for _ in range(steps):
        goal, d_new = patrol_target(theta, A0, A1, d, LOOK, turn_rad)
        turns += int(d_new != d)
        d = d_new
        theta += gain * (goal - theta)
        seen.append(theta)
    return seen, turns


def test_turn_tolerance_keeps_a_converging_tracker_patrolling():
    seen, turns = _patrol(TURN, 3000)
    assert turns >= 4  # end to end and back, repeatedly
    assert max(seen) > A1 - 2 * TURN and min(seen[300:]) < A0 + 2 * TURN  # both ends visited


def test_without_tolerance_it_stalls_at_the_end():
    """The defect this guards against: the clipped goal sits on the end, the tracker never reaches it."""
    seen, turns = _patrol(0.0, 400)  # reaches the end region after ~280 steps
    assert turns == 0 and 0.0 < A1 - seen[-1] < 1e-3


def test_goal_is_lookahead_ahead_and_clipped():
    goal, d = patrol_target(math.radians(30.0), A0, A1, 1.0, LOOK, TURN)
    assert d == 1.0 and math.isclose(goal, math.radians(30.0) + LOOK)
    goal, d = patrol_target(A1 - 0.5 * TURN, A0, A1, 1.0, LOOK, TURN)
    assert d == -1.0 and math.isclose(goal, A1 - 0.5 * TURN - LOOK)
    goal, d = patrol_target(math.radians(-10.0), A0, A1, -1.0, LOOK, TURN)  # behind the start: unwrapped
    assert d == 1.0 and goal == A0
