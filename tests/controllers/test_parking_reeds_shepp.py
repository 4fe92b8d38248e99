"""Reeds–Shepp paths against closed forms, symmetries and their own end poses."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.parking import reeds_shepp as rs

R = 3.0  # [m] turning radius


def shortest(goal: tuple[float, float, float], start: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> float:
    return float(rs.shortest_lengths(np.array(start), np.array(goal), R)[0])


@pytest.mark.parametrize("d", [0.5, 5.0, 17.3])
def test_straight_line_forward_and_back(d: float) -> None:
    assert shortest((d, 0.0, 0.0)) == pytest.approx(d)
    back = rs.paths((0.0, 0.0, 0.0), (-d, 0.0, 0.0), R)[0]
    assert back.length_m == pytest.approx(d)
    assert sum(back.lengths_m) == pytest.approx(-d)  # all in reverse


@pytest.mark.parametrize("dth", [0.3, 1.0, np.pi / 2])
def test_pure_turn_has_length_r_dtheta(dth: float) -> None:
    left = (R * np.sin(dth), R * (1 - np.cos(dth)), dth)
    right = (R * np.sin(dth), -R * (1 - np.cos(dth)), -dth)
    assert shortest(left) == pytest.approx(R * dth)
    assert shortest(right) == pytest.approx(R * dth)
    p = rs.paths((0.0, 0.0, 0.0), left, R)[0]
    turned = sum(abs(L) for ch, L in zip(p.word, p.lengths_m) if ch == "L")
    assert turned == pytest.approx(R * dth) and min(p.lengths_m) > -1e-9  # one left arc, forward


def test_length_is_invariant_to_the_frame_and_symmetric() -> None:
    rng = np.random.default_rng(1)
    goals = rng.uniform([-12, -12, -np.pi], [12, 12, np.pi], size=(200, 3))
    base = rs.shortest_lengths(np.zeros_like(goals), goals, R)
    mirrored = rs.shortest_lengths(np.zeros_like(goals), goals * [1, -1, -1], R)
    flipped = rs.shortest_lengths(np.zeros_like(goals), goals * [-1, 1, -1], R)
    np.testing.assert_allclose(mirrored, base, rtol=1e-9)
    np.testing.assert_allclose(flipped, base, rtol=1e-9)
    assert np.all(base >= np.hypot(goals[:, 0], goals[:, 1]) - 1e-9)
    # moving both poses by one rigid motion changes nothing
    c, s = np.cos(0.7), np.sin(0.7)
    starts = np.tile([5.0, -2.0, 0.7], (200, 1))
    moved = np.column_stack([5 + c * goals[:, 0] - s * goals[:, 1], -2 + s * goals[:, 0] + c * goals[:, 1],
                             goals[:, 2] + 0.7])
    np.testing.assert_allclose(rs.shortest_lengths(starts, moved, R), base, rtol=1e-9)


def test_every_path_ends_at_the_goal_and_the_shortest_matches() -> None:
    rng = np.random.default_rng(2)
    for goal in rng.uniform([-10, -10, -np.pi], [10, 10, np.pi], size=(60, 3)):
        paths = rs.paths((1.0, 2.0, 0.3), tuple(goal), R)
        assert paths, goal
        end = rs.sample((1.0, 2.0, 0.3), paths[0], R, step_m=0.05)[0][-1]
        assert np.hypot(*(end[:2] - goal[:2])) < 1e-6
        assert abs((end[2] - goal[2] + np.pi) % (2 * np.pi) - np.pi) < 1e-6
        assert paths[0].length_m == pytest.approx(shortest(tuple(goal), (1.0, 2.0, 0.3)), rel=1e-9)
