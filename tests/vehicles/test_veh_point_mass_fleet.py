"""The point-mass F450: its limits are the 6-DOF model's (re-measured), its response follows the
6-DOF trajectory, closed-form checks of the first-order response, and the snapshot block."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest

from corridor.snapshot import Kind
from corridor.vehicles.air.autopilot import Hover, VelocityCommand, WaypointCommand
from corridor.vehicles.air.f450_envelope import measure_envelope
from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet
from corridor.vehicles.air.point_mass_fleet import PointMassFleet, PointMassLimits


def steady_speed(lim: PointMassLimits) -> float:
    """[m/s] v = v_max - (c / kp) v^2 solved for v: the speed the drag droop leaves."""
    a = lim.drag_per_m / lim.kp_vel_xy
    return (-1.0 + np.sqrt(1.0 + 4.0 * a * lim.max_speed_h_mps)) / (2.0 * a)


def test_default_limits_are_the_measured_f450_envelope() -> None:
    env, lim = asdict(measure_envelope()), PointMassLimits()
    for name in ("max_climb_mps", "max_descent_mps", "max_accel_h_mps2", "tau_h_s", "tau_v_s", "max_yaw_rate_rps"):
        assert getattr(lim, name) == pytest.approx(env[name], rel=0.08, abs=0.05), name
    for name in ("drag_per_m", "integ_u_hover_mps2", "integ_u_per_m"):
        assert getattr(lim, name) == pytest.approx(env[name], rel=0.15), name
    assert steady_speed(lim) == pytest.approx(env["max_speed_h_mps"], abs=0.02)


@pytest.mark.parametrize("dt_pm", [0.1, 0.5])
def test_point_mass_follows_the_6dof_f450(dt_pm: float) -> None:
    """Speed step, 90 degree turn with a climb, then waypoints: within 2.5 m of JSBSim all along."""
    plan = [(VelocityCommand((20.0, 0.0, 0.0), 0.0), 10.0), (VelocityCommand((0.0, 20.0, 1.0), 0.0), 8.0),
            (WaypointCommand(((60.0, 120.0, 70.0),), 6.0), 20.0)]
    js = JSBSimFleet((47.3769, 8.5417, 408.0))
    js.add("q", "F450", (0.0, 0.0, 60.0))
    pm = PointMassFleet()
    pm.add("q", (0.0, 0.0, 60.0))
    every, err = round(dt_pm / 0.1), []
    for cmd, seconds in plan:
        js.command("q", cmd)
        pm.command("q", cmd)
        for k in range(round(seconds / 0.1)):
            js.step(0.1)
            if (k + 1) % every == 0:
                pm.step(dt_pm)
                err.append(np.linalg.norm(js.state().position[0] - pm.pos[0]))
    assert max(err) < 2.5
    assert err[-1] < 1.5


def test_first_order_response_closed_form() -> None:
    """Unsaturated vertical step: v(t) = v_c (1 - exp(-t / tau_v)), at any step size."""
    lim = PointMassLimits(tau_v_s=1.0, max_climb_mps=5.0)
    for dt in (0.1, 0.5, 2.0):
        pm = PointMassFleet(lim)
        pm.add("q", (0.0, 0.0, 50.0))
        pm.command("q", VelocityCommand((0.0, 0.0, 2.0)))
        for _ in range(round(2.0 / dt)):
            pm.step(dt)
        assert pm.vel[0, 2] == pytest.approx(2.0 * (1.0 - np.exp(-2.0)), rel=1e-9)


def test_speed_acceleration_and_turn_limits() -> None:
    pm = PointMassFleet()
    pm.add("a", (0.0, 0.0, 50.0))
    pm.add("b", (0.0, 100.0, 50.0), v_enu=(7.0, 0.0, 0.0))
    pm.command_velocities(np.array([0, 1]), np.array([[30.0, 0.0, 9.0], [0.0, 7.0, 0.0]]))
    lim, v_prev = pm.limits, pm.vel.copy()
    for _ in range(250):
        pm.step(0.1)
        a_h = np.hypot(*(pm.vel - v_prev)[:, :2].T) / 0.1
        assert np.all(a_h <= lim.max_accel_h_mps2 + 1e-9)
        v_prev = pm.vel.copy()
    assert np.hypot(*pm.vel[0, :2]) == pytest.approx(steady_speed(lim), rel=1e-3)
    assert pm.vel[0, 2] == pytest.approx(lim.max_climb_mps, rel=1e-6)
    v_b = (-1.0 + np.sqrt(1.0 + 4.0 * lim.drag_per_m / lim.kp_vel_xy * 7.0)) / (2.0 * lim.drag_per_m / lim.kp_vel_xy)
    assert pm.vel[1] == pytest.approx([0.0, v_b, 0.0], abs=1e-3)


def test_hover_holds_and_snapshot_block() -> None:
    pm = PointMassFleet()
    pm.add("a", (5.0, 6.0, 40.0), yaw_rad=1.0)
    pm.command("a", Hover())
    for _ in range(50):
        pm.step(0.5)
    s = pm.snapshot_part()
    assert s.position[0] == pytest.approx([5.0, 6.0, 40.0])
    assert s.kind[0] == Kind.UAV and s.heading[0] == pytest.approx(1.0)
    assert pm.t_s == pytest.approx(25.0)
