"""The F450's performance envelope as corridor's 6-DOF model flies it: measured, not assumed.

:func:`measure_envelope` flies one JSBSim F450 under corridor's quad cascade (``JSBSimFleet``, the
same autopilot every 6-DOF UAV flies) through step commands and reads what it achieves:

- ``max_speed_h_mps``: steady horizontal speed for a 20 m/s velocity command (the cascade's speed
  limit binds, not the airframe),
- ``max_climb_mps`` / ``max_descent_mps``: steady vertical speed for +-10 m/s commands,
- ``max_accel_h_mps2``: the largest horizontal acceleration in the 0 -> max-speed step (0.1 s samples),
- ``tau_h_s`` / ``tau_v_s``: time to 63 % of the final speed change (first-order time constants;
  horizontal: of a 1 m/s step, small enough that the tilt limit does not saturate it),
- ``max_turn_rate_rps``: the largest course rate in a 90 degree velocity turn at full speed,
- ``max_yaw_rate_rps``: the largest yaw rate for a 90 degree yaw command,
- ``drag_per_m``: c in a_drag = c v^2, from the steady pitch at full speed (g tan|theta| / v^2),
- ``integ_u_hover_mps2`` / ``integ_u_per_m``: the cascade's vertical integrator in steady flight,
  a + b v^2 (hover and full speed), the state a hand-over to JSBSim starts it with.

The point-mass model (:mod:`corridor.vehicles.air.point_mass_fleet`) takes the speed, climb, drag
and integrator figures as its limits, and models the horizontal response as the cascade's tilt loop
(tilt limit, tilt-rate limit, attitude gain): ``measure_envelope("point_mass")`` flies the same
manoeuvres with the point mass, and ``tests/vehicles/test_veh_point_mass_fleet.py`` checks that both
measure the same envelope. ``python -m corridor.vehicles.air.f450_envelope`` prints both.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from types import SimpleNamespace
from typing import Literal

import numpy as np

ORIGIN = (47.3769, 8.5417, 408.0)  # (lat [deg], lon [deg], h [m]) any origin: the envelope is local
DT_S = 0.1  # [s] sample period


@dataclass(frozen=True)
class Envelope:
    """Measured limits and time constants of the F450 under corridor's cascade."""

    max_speed_h_mps: float  # [m/s]
    max_climb_mps: float  # [m/s]
    max_descent_mps: float  # [m/s]
    max_accel_h_mps2: float  # [m/s^2]
    tau_h_s: float  # [s]
    tau_v_s: float  # [s]
    max_turn_rate_rps: float  # [rad/s]
    max_yaw_rate_rps: float  # [rad/s]
    drag_per_m: float  # [1/m]
    integ_u_hover_mps2: float  # [m/s^2]
    integ_u_per_m: float  # [1/m]


def _fly(fleet, cmd, seconds: float) -> np.ndarray:
    """Command ``cmd`` to aircraft "q" and record (t, vE, vN, vU, yaw) every DT_S for ``seconds``."""
    fleet.command("q", cmd)
    rows = []
    for _ in range(round(seconds / DT_S)):
        fleet.step(DT_S)
        s = fleet.state()
        rows.append([fleet.t_s, *s.velocity[0], s.yaw[0]])
    return np.array(rows)


def _tau(t: np.ndarray, x: np.ndarray, x0: float, x1: float) -> float:
    """Time [s] from t[0] - DT_S until x first covers 63 % of the way from x0 to x1."""
    frac = (x - x0) / (x1 - x0)
    k = int(np.argmax(frac >= 1.0 - np.exp(-1.0)))
    return float(t[k] - t[0] + DT_S)


class _PointMassProbe:
    """The point-mass F450 behind the few calls of ``JSBSimFleet`` the manoeuvres use."""

    def __init__(self) -> None:
        from corridor.vehicles.air.point_mass_fleet import PointMassFleet

        self.pm = PointMassFleet()

    @property
    def t_s(self) -> float:
        return self.pm.t_s

    def add(self, id: str, model: str, enu_m: tuple[float, float, float]) -> None:
        self.pm.add(id, enu_m)

    def command(self, id: str, cmd: object) -> None:
        self.pm.command(id, cmd)

    def step(self, dt_s: float) -> None:
        self.pm.step(dt_s)

    def state(self) -> SimpleNamespace:
        roll, pitch = self.pm.attitude()
        return SimpleNamespace(velocity=self.pm.vel.copy(), yaw=self.pm.yaw.copy(), roll=roll, pitch=pitch)

    def get_property(self, id: str, name: str) -> float:
        assert name == "corridor/integ-u-mps2", name
        return float(self.pm.integ_u(np.array([self.pm.row(id)]))[0])


def measure_envelope(model: Literal["jsbsim", "point_mass"] = "jsbsim") -> Envelope:
    """Fly the step manoeuvres (about 80 s simulated, well under a second of CPU) with corridor's
    6-DOF F450 (``jsbsim``) or the point-mass model (``point_mass``)."""
    from corridor.vehicles.air.autopilot import VelocityCommand
    from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet

    fleet = JSBSimFleet(ORIGIN) if model == "jsbsim" else _PointMassProbe()
    fleet.add("q", "F450", (0.0, 0.0, 80.0))
    _fly(fleet, VelocityCommand((0.0, 0.0, 0.0), 0.0), 30.0)
    integ_hover = fleet.get_property("q", "corridor/integ-u-mps2")
    small = _fly(fleet, VelocityCommand((1.0, 0.0, 0.0), 0.0), 6.0)
    tau_h = _tau(small[:, 0], small[:, 1], 0.0, float(np.mean(small[-10:, 1])))
    _fly(fleet, VelocityCommand((0.0, 0.0, 0.0), 0.0), 6.0)
    acc = _fly(fleet, VelocityCommand((20.0, 0.0, 0.0), 0.0), 20.0)
    v_max = float(np.mean(np.hypot(acc[-20:, 1], acc[-20:, 2])))
    drag = 9.80665 * float(np.tan(abs(fleet.state().pitch[0]))) / v_max**2
    integ_per_m = (fleet.get_property("q", "corridor/integ-u-mps2") - integ_hover) / v_max**2
    a_max = float(np.max(np.hypot(*np.diff(acc[:, 1:3], axis=0).T)) / DT_S)
    turn = _fly(fleet, VelocityCommand((0.0, 20.0, 0.0), 0.0), 10.0)
    course = np.unwrap(np.arctan2(turn[:, 2], turn[:, 1]))
    turn_rate = float(np.max(np.abs(np.diff(course))) / DT_S)
    _fly(fleet, VelocityCommand((0.0, 0.0, 0.0), 0.0), 8.0)
    climb = _fly(fleet, VelocityCommand((0.0, 0.0, 10.0), 0.0), 8.0)
    v_climb = float(np.mean(climb[-10:, 3]))
    tau_v = _tau(climb[:, 0], climb[:, 3], 0.0, v_climb)
    descent = _fly(fleet, VelocityCommand((0.0, 0.0, -10.0), 0.0), 8.0)
    yaw = _fly(fleet, VelocityCommand((0.0, 0.0, 0.0), 0.5 * np.pi), 6.0)
    yaw_rate = float(np.max(np.abs(np.diff(np.unwrap(yaw[:, 4])))) / DT_S)
    return Envelope(v_max, v_climb, float(-np.mean(descent[-10:, 3])), a_max, tau_h, tau_v, turn_rate, yaw_rate,
                    drag, integ_hover, integ_per_m)


if __name__ == "__main__":
    js, pm = asdict(measure_envelope("jsbsim")), asdict(measure_envelope("point_mass"))
    print(f"{'':20s} {'6-DOF':>10s} {'point mass':>10s}")
    for k, v in js.items():
        print(f"{k:20s} {v:10.6f} {pm[k]:10.6f}")
