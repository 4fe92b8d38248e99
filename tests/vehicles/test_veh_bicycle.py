"""The kinematic bicycle against closed forms, and the CasADi path against the numpy path."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from corridor.vehicles.ground.bicycle import BicycleParams, f, integrate, rk4_step

P = BicycleParams()


def test_straight_line_20mps_for_2s_is_40m() -> None:
    xs = integrate(np.array([0.0, 0.0, 0.0, 20.0]), np.zeros((20, 2)), 0.1, P)
    assert xs[-1] == pytest.approx([40.0, 0.0, 0.0, 20.0], abs=1e-9)


def test_constant_acceleration_matches_closed_form() -> None:
    xs = integrate(np.array([0.0, 0.0, 0.0, 10.0]), np.tile([2.0, 0.0], (30, 1)), 0.1, P)
    t = 3.0
    assert xs[-1, 0] == pytest.approx(10.0 * t + 0.5 * 2.0 * t**2, rel=1e-12)
    assert xs[-1, 3] == pytest.approx(16.0, rel=1e-12)


@pytest.mark.parametrize("delta", [0.05, 0.2, -0.3])
def test_constant_steer_circle_radius_is_wheelbase_over_tan_delta(delta: float) -> None:
    v = 10.0
    xs = integrate(np.array([0.0, 0.0, 0.0, v]), np.tile([0.0, delta], (400, 1)), 0.05, P, substeps=2)
    radius = P.wheelbase_m / np.tan(delta)  # signed: left turn positive
    centre = np.array([0.0, radius])
    dist = np.hypot(xs[:, 0] - centre[0], xs[:, 1] - centre[1])
    assert np.max(np.abs(dist - abs(radius))) < 1e-4 * abs(radius)
    yaw_rate = v * np.tan(delta) / P.wheelbase_m
    assert xs[-1, 2] == pytest.approx(yaw_rate * 20.0, rel=1e-9)


def test_casadi_and_numpy_paths_agree() -> None:
    x = ca.SX.sym("x", 4)
    u = ca.SX.sym("u", 2)
    step = ca.Function("step", [x, u], [rk4_step(x, u, 0.2, P)])
    rng = np.random.default_rng(3)
    for _ in range(20):
        x0 = rng.uniform([-50, -2, -0.5, 0], [50, 5, 0.5, 30])
        u0 = rng.uniform([-6, -0.35], [3, 0.35])
        assert np.asarray(step(x0, u0)).ravel() == pytest.approx(rk4_step(x0, u0, 0.2, P), abs=1e-10)
        assert np.asarray(ca.Function("f", [x, u], [f(x, u, P)])(x0, u0)).ravel() == pytest.approx(f(x0, u0, P))


def test_params_are_frozen_and_strict() -> None:
    with pytest.raises(ValueError):
        BicycleParams(wheelbase=3.0)  # type: ignore[call-arg]
    with pytest.raises(ValueError):
        P.wheelbase_m = 3.0  # type: ignore[misc]
