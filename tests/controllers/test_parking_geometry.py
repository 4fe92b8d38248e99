"""Footprint collision checks against closed forms and against shapely."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from corridor.controllers.parking.geometry import FootprintChecker, Obstacles, VehicleGeometry, footprint

V = VehicleGeometry()


def square(x0: float, y0: float, side: float = 1.0) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def test_the_footprint_is_the_tpcap_rectangle() -> None:
    fp = footprint(np.array([[0.0, 0.0, 0.0]]), V)[0]
    np.testing.assert_allclose(fp.min(axis=0), [-0.929, -0.971])
    np.testing.assert_allclose(fp.max(axis=0), [2.8 + 0.96, 0.971])
    assert V.min_turn_radius_m == pytest.approx(2.8 / np.tan(0.75))


@pytest.mark.parametrize(("x0", "hit"), [(3.70, True), (3.77, False), (-1.95, False), (-1.9, True)])
def test_obstacle_ahead_and_behind(x0: float, hit: bool) -> None:
    obs = Obstacles([square(x0, -0.5)])
    assert obs.collides(np.array([[0.0, 0.0, 0.0]]), V)[0] == hit


def test_rotation_and_containment() -> None:
    obs = Obstacles([square(-0.5, 3.7)])  # ahead of a car heading +y
    assert obs.collides(np.array([[0.0, 0.0, np.pi / 2]]), V)[0]
    assert not obs.collides(np.array([[0.0, 0.0, 0.0]]), V)[0]
    big = Obstacles([square(-50, -50, 100)])  # the car wholly inside a polygon
    assert big.collides(np.array([[0.0, 0.0, 0.3]]), V)[0]


def test_agrees_with_shapely_on_random_poses() -> None:
    rng = np.random.default_rng(3)
    polys = [square(0, 0, 3), np.array([[6, 0], [9, 1], [7, 2], [8, 4], [5, 3]], float)]  # one non-convex
    poses = rng.uniform([-4, -4, -np.pi], [12, 8, np.pi], size=(500, 3))
    ours = Obstacles(polys).collides(poses, V)
    fps = shapely.polygons(footprint(poses, V))
    union = shapely.union_all([shapely.Polygon(p) for p in polys])
    theirs = shapely.intersects(fps, union)
    assert 50 < ours.sum() < 450
    np.testing.assert_array_equal(ours, theirs)


def test_the_distance_grid_checker_agrees_with_the_exact_test() -> None:
    rng = np.random.default_rng(4)
    polys = [square(0, 0, 3), np.array([[6, 0], [9, 1], [7, 2], [8, 4], [5, 3]], float),
             np.array([[-3, 5], [12, 5], [12, 5.2], [-3, 5.2]])]  # a thin wall
    obs = Obstacles(polys)
    fast = FootprintChecker(obs, V, 0.05, (-6, 14, -6, 10))
    poses = rng.uniform([-6, -6, -np.pi], [14, 10, np.pi], size=(3000, 3))
    np.testing.assert_array_equal(fast(poses), obs.collides(poses, V, 0.05))
