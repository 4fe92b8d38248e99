"""Autopilot acceptance: F450 hover and position steps, velocity and waypoint modes, c172x holds."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.air.autopilot import (
    HoldCommand,
    PositionCommand,
    QuadCascade,
    QuadMode,
    QuadTargets,
    VelocityCommand,
    WaypointCommand,
)
from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet

ORIGIN = (47.3769, 8.5417, 408.0)


def _trace(fleet: JSBSimFleet, seconds: float, dt_s: float = 0.05) -> np.ndarray:
    """Positions [m] of every aircraft after each tick: shape (ticks, N, 3)."""
    out = []
    for _ in range(round(seconds / dt_s)):
        fleet.step(dt_s)
        out.append(fleet.state().position.copy())
    return np.array(out)


def test_hover_holds_altitude_within_half_a_metre() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (5.0, -3.0, 40.0), heading_rad=0.7)
    settle = _trace(fleet, 5.0)
    hold = _trace(fleet, 20.0)
    assert np.abs(hold[:, 0, 2] - 40.0).max() < 0.5
    assert np.abs(hold[:, 0, :2] - [5.0, -3.0]).max() < 0.5
    assert np.abs(settle[:, 0, 2] - 40.0).max() < 1.0  # the spin-up transient itself is small
    assert fleet.state().yaw[0] == pytest.approx(0.7, abs=0.02)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_20m_step_settles_with_overshoot_at_most_10_percent(axis: int) -> None:
    start = np.array([0.0, 0.0, 30.0])
    goal = start.copy()
    goal[axis] += 20.0
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", start, heading_rad=0.3)
    _trace(fleet, 2.0)
    fleet.command("q", PositionCommand(tuple(goal)))
    p = _trace(fleet, 20.0)[:, 0, :]
    progress = p[:, axis] - start[axis]
    assert progress.max() <= 22.0  # overshoot <= 10 % of the 20 m step
    assert np.abs(p[-40:] - goal).max() < 0.3  # settled at the goal (last 2 s)
    assert progress[round(10.0 / 0.05)] > 19.0  # and not by crawling: within 1 m after 10 s
    others = [k for k in range(3) if k != axis]
    assert np.abs(p[:, others] - start[others]).max() < 1.0  # the other axes are held


def test_velocity_command_tracks_and_saturates() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (0.0, 0.0, 30.0))
    _trace(fleet, 1.0)
    fleet.command("q", VelocityCommand((3.0, -4.0, 0.0)))
    _trace(fleet, 6.0)
    v = fleet.state().velocity[0]
    assert np.allclose(v, [3.0, -4.0, 0.0], atol=0.3)
    fleet.command("q", VelocityCommand((0.0, 0.0, 10.0)))  # beyond the 3 m/s climb limit
    _trace(fleet, 4.0)
    assert fleet.state().velocity[0, 2] == pytest.approx(fleet.quad_gains.max_climb_mps, abs=0.2)


def test_waypoints_are_visited_in_order() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (0.0, 0.0, 20.0))
    wps = ((15.0, 0.0, 20.0), (15.0, 15.0, 25.0), (0.0, 15.0, 25.0))
    fleet.command("q", WaypointCommand(wps, speed_mps=4.0, accept_radius_m=1.0))
    p = _trace(fleet, 30.0)[:, 0, :]
    assert fleet.waypoint_index("q") == 2
    dist = np.linalg.norm(p[:, None, :] - np.array(wps)[None], axis=2)
    first_hit = [int(np.argmax(dist[:, k] < 1.0)) for k in range(3)]
    assert all(dist[:, k].min() < 1.0 for k in range(3))
    assert first_hit[0] < first_hit[1] < first_hit[2]
    assert np.linalg.norm(p[-1] - wps[-1]) < 0.3
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / 0.05
    assert speed.max() < 4.0 * 1.15  # the waypoint speed limit holds (small overshoot of the PI loop)


def test_cascade_is_vectorised_and_tilt_limited() -> None:
    """Pure-numpy check of the cascade: a large error saturates the tilt; rows are independent."""
    ap = QuadCascade()
    tgt = QuadTargets()
    for _ in range(2):
        ap.add_row()
        tgt.append(np.zeros(3), 0.0, np.inf)
    tgt.p_enu[0] = [100.0, 0.0, 0.0]  # far east: pitch forward (nose down) for yaw 0
    sticks = ap.step(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), tgt, 1 / 120)
    assert sticks.elevator[0] < 0.0 and sticks.aileron[0] == pytest.approx(0.0, abs=1e-9)
    assert sticks.elevator[1] == pytest.approx(0.0) and sticks.aileron[1] == pytest.approx(0.0)
    assert sticks.throttle[1] == pytest.approx(ap.gains.hover_throttle)
    # demanded tilt is clipped: at the limit the attitude error is max_tilt, so stick = kp_att * tilt / 0.75
    assert abs(sticks.elevator[0]) == pytest.approx(min(1.0, ap.gains.kp_att * ap.gains.max_tilt_rad / 0.75))


def test_c172_holds_altitude_and_turns_to_commanded_heading() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("c", "c172x", (0.0, 0.0, 300.0), heading_rad=0.0, speed_mps=50.0)
    alts, yaws = [], []
    fleet.command("c", HoldCommand(np.pi / 2, 300.0, 50.0))  # turn left 90 deg: from east to north
    for _ in range(600):
        fleet.step(0.1)
        s = fleet.state()
        alts.append(s.position[0, 2])
        yaws.append(np.arctan2(s.velocity[0, 1], s.velocity[0, 0]))
    alts, yaws = np.array(alts), np.array(yaws)
    assert np.abs(alts - 300.0).max() < 30.0
    assert np.abs(yaws[-100:] - np.pi / 2).max() < np.radians(5.0)  # track within 5 deg for the last 10 s
    assert fleet.state().airspeed[0] == pytest.approx(50.0, abs=3.0)


def test_c172_follows_waypoints() -> None:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("c", "c172x", (0.0, 0.0, 300.0), heading_rad=0.0, speed_mps=50.0)
    wps = ((1500.0, 0.0, 300.0), (1500.0, 1500.0, 350.0))
    fleet.command("c", WaypointCommand(wps, speed_mps=50.0, accept_radius_m=250.0))
    p = _trace(fleet, 90.0, dt_s=0.1)[:, 0, :]
    assert fleet.waypoint_index("c") == 1
    d_last = np.linalg.norm(p[:, :2] - np.array(wps[1][:2]), axis=1)
    assert d_last.min() < 250.0


def test_velocity_mode_needs_no_position_and_matches_the_full_cascade() -> None:
    """With every row in VELOCITY mode the fleet passes no position (the geodetic conversion is skipped)
    and a velocity demand computed once per tick: the sticks are exactly those of the full path."""
    rng = np.random.default_rng(2)
    ap_full, ap_fast, tgt = QuadCascade(), QuadCascade(), QuadTargets()
    for _ in range(4):
        ap_full.add_row()
        ap_fast.add_row()
        tgt.append(rng.normal(0.0, 50.0, 3), 0.3, np.inf)
    tgt.mode[:] = QuadMode.VELOCITY
    tgt.v_enu[:] = rng.normal(0.0, 6.0, (4, 3))
    v_dem = ap_fast.velocity_demand(None, tgt)
    for _ in range(12):  # one tick of sub-steps: the integrators evolve identically
        p, v, e = rng.normal(0.0, 50.0, (4, 3)), rng.normal(0.0, 5.0, (4, 3)), rng.normal(0.0, 0.2, (4, 3))
        full = ap_full.step(p, v, e, tgt, 1 / 120)
        fast = ap_fast.stick_array(None, v, e, tgt, 1 / 120, v_dem)
        assert np.array_equal(np.column_stack([full.aileron, full.elevator, full.rudder, full.throttle]), fast)
    assert np.array_equal(ap_full.integ, ap_fast.integ)
