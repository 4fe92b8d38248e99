"""The quad cascade inside JSBSim (jsbsim_data/corridor_quad_cascade.xml) against its Python reference
(``autopilot.QuadCascade``): the same sticks from the same state, sub-step by sub-step; and the
closed forms of the discretisation (integrator step, hover collective)."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.air.autopilot import PositionCommand, QuadCascade, VelocityCommand
from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet
from corridor.vehicles.geodesy import Origin, metres_per_degree

ORIGIN = (47.3769, 8.5417, 408.0)
_STICKS = ("fcs/aileron-cmd-norm", "fcs/elevator-cmd-norm", "fcs/rudder-cmd-norm", "fcs/throttle-cmd-norm")
_INTEG = ("corridor/integ-e-mps2", "corridor/integ-n-mps2", "corridor/integ-u-mps2")


def _fleet() -> JSBSimFleet:
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("climb", "F450", (0.0, 0.0, 40.0), heading_rad=0.3)
    fleet.add("far", "F450", (30.0, 0.0, 40.0), heading_rad=-2.0)
    fleet.add("turn", "F450", (-30.0, 10.0, 60.0), heading_rad=3.0)
    fleet.command("climb", VelocityCommand((2.0, -1.0, 2.5)))
    fleet.command("far", PositionCommand((230.0, 80.0, 35.0), yaw_rad=1.0))  # saturated speed and tilt
    fleet.command("turn", VelocityCommand((-4.0, 3.0, -1.0), yaw_rad=-2.9))  # yaw error across +-pi
    return fleet


def test_jsbsim_cascade_gives_the_python_reference_sticks_at_every_substep() -> None:
    fleet, ref = _fleet(), QuadCascade()
    for _ in fleet.ids:
        ref.add_row()
    h = 1.0 / fleet.rate_hz
    worst = 0.0
    for k in range(360):  # 3 s, one sub-step per fleet step so that every intermediate state is seen
        ref.integ = np.array([[fleet.get_property(i, p) for p in _INTEG] for i in fleet.ids])
        fleet.step(h)
        s = fleet.state()
        euler = np.column_stack([s.roll, s.pitch, s.yaw])
        want = ref.stick_array(s.position, s.velocity, euler, fleet.quad_targets, h)
        got = np.array([[fleet.get_property(i, p) for p in _STICKS] for i in fleet.ids])
        worst = max(worst, float(np.abs(got - want).max()))
        if k in (1, 120, 359):  # the integrators advance as the reference's do
            integ = np.array([[fleet.get_property(i, p) for p in _INTEG] for i in fleet.ids])
            assert integ == pytest.approx(ref.integ, abs=1e-7)
    # position mode: the error is linearised around the state at the last target write (< 1e-6 m here)
    assert worst < 1e-6
    assert fleet.state().velocity[0] == pytest.approx([2.0, -1.0, 2.5], abs=0.3)


def test_hover_collective_is_the_feed_forward_plus_the_integrator() -> None:
    """Holding a position the vertical acceleration demand is kp_v (kp_p e_z - v_z) + integ_u, and the
    collective must be hover x (1 + a_u / g) / (cos phi cos theta) (the tilt-corrected feed-forward)."""
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (0.0, 0.0, 50.0))
    for _ in range(100):
        fleet.step(0.1)
    g = fleet.quad_gains
    s = fleet.state()
    assert np.abs(s.velocity[0]).max() < 0.02
    integ_u = fleet.get_property("q", "corridor/integ-u-mps2")
    err_u = g.kp_pos * (50.0 - s.position[0, 2]) - s.velocity[0, 2]
    acc_u = g.kp_vel_z * err_u + integ_u
    lift = np.cos(s.roll[0]) * np.cos(s.pitch[0])
    want = g.hover_throttle * (1.0 + acc_u / 9.80665) / lift
    assert fleet.get_property("q", "fcs/throttle-cmd-norm") == pytest.approx(want, abs=1e-4)
    # the integrator found the model's own hover collective (the gain's 0.413 is a feed-forward)
    assert 0.38 < fleet.get_property("q", "fcs/throttle-cmd-norm") < 0.45


def test_integrator_is_forward_euler_and_clamped() -> None:
    """One sub-step with a constant vertical error e: integ' = clip(integ + ki e h, +-limit)."""
    fleet = JSBSimFleet(ORIGIN)
    fleet.add("q", "F450", (0.0, 0.0, 50.0))
    fleet.command("q", VelocityCommand((0.0, 0.0, 3.0)))
    g, h = fleet.quad_gains, 1.0 / fleet.rate_hz
    before = fleet.get_property("q", "corridor/integ-u-mps2")
    fleet.step(h)
    err = g.max_climb_mps - fleet.state().velocity[0, 2]
    assert fleet.get_property("q", "corridor/integ-u-mps2") == pytest.approx(before + g.ki_vel_z * err * h, abs=1e-12)
    for _ in range(400):  # a climb demand it cannot meet in time would wind up: the clamp holds
        fleet.step(0.1)
    assert abs(fleet.get_property("q", "corridor/integ-u-mps2")) <= g.integ_limit_mps2 + 1e-12


def test_metres_per_degree_matches_the_enu_conversion() -> None:
    o = Origin(*ORIGIN)
    m_lat, m_lon = metres_per_degree(np.array([ORIGIN[0]]), np.array([ORIGIN[2]]))
    d = 1e-5  # [deg]
    north = o.to_enu(ORIGIN[0] + d, ORIGIN[1], ORIGIN[2])[1]
    east = o.to_enu(ORIGIN[0], ORIGIN[1] + d, ORIGIN[2])[0]
    assert m_lat[0] * d == pytest.approx(north, rel=1e-6)
    assert m_lon[0] * d == pytest.approx(east, rel=1e-6)


def test_leaving_out_the_unused_sensors_changes_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """corridor's F450 copy omits SensorGps/SensorBaro and keeps only the IMU's yaw gyro: the flight
    is bit-identical with the full sensor set."""
    from corridor.vehicles.air import jsbsim_fleet, jsbsim_models

    def flight(omit: tuple[str, ...], reduce_imu: bool = True) -> list[float]:
        monkeypatch.setattr(jsbsim_fleet, "aircraft_dir",
                            lambda root: jsbsim_models.aircraft_dir(root, omit, reduce_imu))
        fleet = JSBSimFleet(ORIGIN)
        fleet.add("q", "F450", (0.0, 0.0, 40.0), heading_rad=0.4)
        fleet.command("q", VelocityCommand((3.0, -2.0, 1.0), yaw_rad=-1.0))
        for _ in range(50):
            fleet.step(0.1)
        s = fleet.state()
        return [*s.position[0], *s.velocity[0], s.yaw[0], s.roll[0], s.pitch[0]]

    assert jsbsim_models.UNUSED_SYSTEMS == ("SensorBaro", "SensorGps")
    assert flight((), reduce_imu=False) == flight(jsbsim_models.UNUSED_SYSTEMS)
