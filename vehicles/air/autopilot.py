"""corridor's own autopilots on top of JSBSim: a quadcopter cascade and a fixed-wing waypoint follower.

The F450 shipped with JSBSim has only body-rate loops (``fcs/aileron|elevator|rudder-cmd-norm`` are
roll/pitch/yaw *rate* demands, 0.75 rad/s at full stick; ``fcs/throttle-cmd-norm`` is the collective).
:class:`QuadCascade` closes position -> velocity -> attitude -> rate around them, vectorised over every
quadcopter of a fleet (struct of arrays, one call per sub-step), with saturations on horizontal speed,
climb / descent rate and tilt. The fleet flies the same equations inside JSBSim
(``jsbsim_data/corridor_quad_cascade.xml``, see ``jsbsim_fleet``); this class is their reference,
checked against the XML sub-step by sub-step in ``tests/vehicles/test_veh_quad_cascade_xml.py``. Modes per aircraft: hover / position (and waypoints, which the fleet
turns into successive positions) / velocity command.

The c172x carries JSBSim's own heading and altitude holds (``ap/heading_hold``, ``ap/altitude_hold``
in ``c172ap.xml``); :class:`FixedWingGuidance` adds corridor's waypoint following (bearing to the
active waypoint), the altitude set-point and an airspeed hold on the throttle (PI), i.e. the piloted
intruder's "pilot".

Commands are small frozen dataclasses; all vectors are in the scenario's ENU frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from corridor.vehicles.geodesy import wrap_pi

G_MPS2 = 9.80665  # [m/s^2]
F450_RATE_PER_STICK = 0.75  # [rad/s] full-stick rate demand of the F450 FCS (pure_gain refRoll_rps)


# ----------------------------------------------------------------------------------------- commands
@dataclass(frozen=True)
class Hover:
    """Hold the current position and yaw (quadcopter)."""


@dataclass(frozen=True)
class PositionCommand:
    """Fly to and hold ``p_enu`` [m]; ``yaw_rad`` (ENU, CCW from east) or None to keep the current yaw."""

    p_enu: tuple[float, float, float]
    yaw_rad: float | None = None


@dataclass(frozen=True)
class VelocityCommand:
    """Fly at ``v_enu`` [m/s] (saturated to the vehicle's limits); ``yaw_rad`` as in PositionCommand."""

    v_enu: tuple[float, float, float]
    yaw_rad: float | None = None


@dataclass(frozen=True)
class WaypointCommand:
    """Visit ``waypoints_enu`` [m] in order at up to ``speed_mps``; a waypoint counts as reached
    inside ``accept_radius_m``. Quadcopters hold the last one; fixed wings keep its heading."""

    waypoints_enu: tuple[tuple[float, float, float], ...]
    speed_mps: float | None = None
    accept_radius_m: float = 2.0


@dataclass(frozen=True)
class HoldCommand:
    """Fixed wing: hold ENU yaw ``yaw_rad`` (track direction), altitude ``up_m`` above the origin and
    true airspeed ``speed_mps``."""

    yaw_rad: float
    up_m: float
    speed_mps: float


Command = Hover | PositionCommand | VelocityCommand | WaypointCommand | HoldCommand


# ------------------------------------------------------------------------------------- quad cascade
class QuadMode(IntEnum):
    """Guidance mode of one quadcopter row in :class:`QuadCascade`."""

    POSITION = 0  # hover and waypoints are position targets
    VELOCITY = 1


@dataclass(frozen=True)
class QuadGains:
    """Gains and limits of the quadcopter cascade (defaults tuned on JSBSim's F450 at 120 Hz)."""

    kp_pos: float = 0.6  # [1/s] position error -> velocity demand
    kp_vel_xy: float = 3.0  # [1/s] horizontal velocity error -> acceleration demand
    # horizontal integrator off by default: it winds up in the speed-saturated transit and costs
    # 5-20 % overshoot on a 20 m step (measured); there is no wind to reject in the default scenes
    ki_vel_xy: float = 0.0  # [1/s^2]
    kp_vel_z: float = 3.0  # [1/s] vertical velocity error -> acceleration demand
    ki_vel_z: float = 1.0  # [1/s^2]
    kp_att: float = 5.0  # [1/s] attitude error -> body-rate demand
    kp_yaw: float = 1.5  # [1/s] yaw error -> yaw-rate demand
    max_speed_xy_mps: float = 8.0  # [m/s]
    max_climb_mps: float = 3.0  # [m/s]
    max_descent_mps: float = 2.0  # [m/s]
    max_tilt_rad: float = 0.35  # [rad] (20 deg)
    max_yaw_rate_rps: float = 0.6  # [rad/s]
    hover_throttle: float = 0.413  # [-] F450 collective at hover (measured: 0.413 at 1.4 kg)
    integ_limit_mps2: float = 2.0  # [m/s^2] anti-windup bound of the integrators


@dataclass
class QuadTargets:
    """Per-row set-points of the cascade (struct of arrays, edited in place by the fleet)."""

    mode: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    p_enu: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [m]
    v_enu: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [m/s]
    yaw_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [rad] ENU
    speed_limit_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [m/s] per row

    def append(self, p_enu: np.ndarray, yaw_rad: float, speed_limit_mps: float) -> None:
        """Add a row that holds ``p_enu`` and ``yaw_rad``."""
        self.mode = np.append(self.mode, np.int8(QuadMode.POSITION))
        self.p_enu = np.vstack([self.p_enu, np.asarray(p_enu, float)[None, :]])
        self.v_enu = np.vstack([self.v_enu, np.zeros((1, 3))])
        self.yaw_rad = np.append(self.yaw_rad, yaw_rad)
        self.speed_limit_mps = np.append(self.speed_limit_mps, speed_limit_mps)


@dataclass(frozen=True)
class QuadSticks:
    """Normalised F450 FCS inputs per row: rate sticks in [-1, 1], collective in [0, 1]."""

    aileron: np.ndarray
    elevator: np.ndarray
    rudder: np.ndarray
    throttle: np.ndarray


def _saturate_norm(v: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """Scale rows of ``v`` (N, k) down so that their norm is at most ``limit`` (direction kept)."""
    norm = np.sqrt(np.einsum("ij,ij->i", v, v))
    scale = np.minimum(1.0, limit / np.maximum(norm, 1e-9))
    return v * scale[:, None]


def _clip(x: np.ndarray, lo: float | np.ndarray, hi: float | np.ndarray) -> np.ndarray:
    """np.clip without its dispatch overhead (the cascade runs 120 times per simulated second)."""
    return np.minimum(np.maximum(x, lo), hi)


class QuadCascade:
    """Position -> velocity -> attitude -> body-rate cascade for N quadcopters at once.

    Outer loops are P (position) and PI (velocity, with clamped integrators); the attitude loop is P on
    Euler angles into the F450's own rate PIDs. The collective has a hover feed-forward corrected for
    tilt. ``step`` takes the fleet's state arrays and returns the sticks; it keeps only integrators.
    """

    def __init__(self, gains: QuadGains | None = None) -> None:
        self.gains = g = gains or QuadGains()
        self.integ = np.zeros((0, 3))  # [m/s^2] velocity-loop integrators (E, N, U)
        self._ki = np.array([g.ki_vel_xy, g.ki_vel_xy, g.ki_vel_z])
        self._kp = np.array([g.kp_vel_xy, g.kp_vel_xy, g.kp_vel_z])

    def add_row(self) -> None:
        self.integ = np.vstack([self.integ, np.zeros((1, 3))])

    def velocity_demand(self, p_enu: np.ndarray | None, tgt: QuadTargets) -> np.ndarray:
        """Velocity demand [m/s] (N, 3) from the mode: P on position error, or the commanded velocity;
        saturated horizontally by norm and vertically by the climb/descent limits. ``p_enu`` may be
        None when no row is in POSITION mode (the position is then not needed)."""
        g = self.gains
        if p_enu is None:
            v = tgt.v_enu
        else:
            v_pos = g.kp_pos * (tgt.p_enu - p_enu)
            v = np.where((tgt.mode == QuadMode.VELOCITY)[:, None], tgt.v_enu, v_pos)
        out = np.empty_like(v)
        out[:, :2] = _saturate_norm(v[:, :2], np.minimum(tgt.speed_limit_mps, g.max_speed_xy_mps))
        out[:, 2] = _clip(v[:, 2], -g.max_descent_mps, g.max_climb_mps)
        return out

    def acceleration_demand(self, v_enu: np.ndarray, v_dem: np.ndarray, dt_s: float) -> np.ndarray:
        """PI velocity loop -> acceleration demand [m/s^2] (N, 3), integrators clamped (anti-windup)."""
        g = self.gains
        err = v_dem - v_enu
        self.integ = _clip(self.integ + self._ki * err * dt_s, -g.integ_limit_mps2, g.integ_limit_mps2)
        return self._kp * err + self.integ

    def step(
        self, p_enu: np.ndarray | None, v_enu: np.ndarray, euler_rad: np.ndarray, tgt: QuadTargets, dt_s: float
    ) -> QuadSticks:
        """One cascade update. ``euler_rad`` is (N, 3): roll phi, pitch theta (JSBSim body convention)
        and ENU yaw. Returns the sticks to write into each F450's FCS."""
        s = self.stick_array(p_enu, v_enu, euler_rad, tgt, dt_s)
        return QuadSticks(aileron=s[:, 0], elevator=s[:, 1], rudder=s[:, 2], throttle=s[:, 3])

    def stick_array(
        self, p_enu: np.ndarray | None, v_enu: np.ndarray, euler_rad: np.ndarray, tgt: QuadTargets, dt_s: float,
        v_dem: np.ndarray | None = None,
    ) -> np.ndarray:
        """:meth:`step` as one (N, 4) array, columns aileron, elevator, rudder, throttle (row-major:
        the fleet writes it into the FDMs in one flat pass). Runs 120 times per simulated second, so
        the attitude and stick stages work on (N, 2) / (N, 4) blocks: the same element-wise
        operations as column by column, in fewer numpy calls. ``v_dem``: the velocity demand when
        the caller already has it (it depends only on the targets when no row is in POSITION mode,
        so the fleet computes it once per tick instead of once per sub-step)."""
        g = self.gains
        if v_dem is None:
            v_dem = self.velocity_demand(p_enu, tgt)
        acc = self.acceleration_demand(v_enu, v_dem, dt_s)
        yaw = euler_rad[:, 2]
        # horizontal acceleration in the heading frame: forward (body x) and right (body y)
        c, s = np.cos(yaw), np.sin(yaw)
        a_fwd = c * acc[:, 0] + s * acc[:, 1]
        a_right = s * acc[:, 0] - c * acc[:, 1]
        tilt = np.empty((len(yaw), 2))
        tilt[:, 0] = np.arctan2(a_right, G_MPS2)
        tilt[:, 1] = -np.arctan2(a_fwd, G_MPS2)
        tilt = _saturate_norm(tilt, g.max_tilt_rad)
        rates = np.empty((len(yaw), 4))
        rates[:, :2] = g.kp_att * (tilt - euler_rad[:, :2])  # roll, pitch rate demands [rad/s]
        # JSBSim's r is nose-right (heading increasing) = ENU yaw decreasing
        rates[:, 2] = -_clip(g.kp_yaw * wrap_pi(tgt.yaw_rad - yaw), -g.max_yaw_rate_rps, g.max_yaw_rate_rps)
        cos_pt = np.cos(euler_rad[:, :2])
        lift = np.maximum(cos_pt[:, 0] * cos_pt[:, 1], 0.5)
        rates[:, :3] *= 1.0 / F450_RATE_PER_STICK
        rates[:, 3] = g.hover_throttle * (1.0 + acc[:, 2] / G_MPS2) / lift
        return _clip(rates, _STICK_LO, _STICK_HI)


_STICK_LO = np.array([-1.0, -1.0, -1.0, 0.0])  # aileron, elevator, rudder [-], throttle [0, 1]
_STICK_HI = np.array([1.0, 1.0, 1.0, 1.0])


# --------------------------------------------------------------------------------- fixed wing (c172)
@dataclass(frozen=True)
class FixedWingGains:
    """Airspeed hold and waypoint guidance of the c172x (heading/altitude holds are JSBSim's)."""

    kp_speed: float = 0.08  # [1/(m/s)] throttle per airspeed error
    ki_speed: float = 0.02  # [1/(m s)]
    throttle_trim: float = 0.65  # [-] feed-forward
    default_speed_mps: float = 50.0  # [m/s] (~97 kt, a c172 cruise)


@dataclass(frozen=True)
class FixedWingDemand:
    """What the c172x's own holds receive: true heading [deg], altitude AGL [ft], throttle [0, 1]."""

    heading_deg: float
    altitude_agl_ft: float
    throttle: float


class FixedWingGuidance:
    """One c172x's pilot: waypoints -> heading to the active waypoint; holds -> set-points.

    ``update`` takes ENU position [m], true airspeed [m/s] and returns the demand for JSBSim's holds.
    """

    def __init__(self, gains: FixedWingGains | None = None) -> None:
        self.gains = gains or FixedWingGains()
        self.command: Command = HoldCommand(0.0, 300.0, self.gains.default_speed_mps)
        self.wp_index = 0
        self._integ = 0.0  # [-] throttle integrator

    def set_command(self, cmd: Command) -> None:
        if not isinstance(cmd, HoldCommand | WaypointCommand):
            raise TypeError(f"fixed wing accepts HoldCommand or WaypointCommand, got {type(cmd).__name__}")
        self.command = cmd
        self.wp_index = 0

    def _targets(self, p_enu: np.ndarray) -> tuple[float, float, float]:
        """(ENU yaw [rad], up [m], speed [m/s]) from the active command."""
        cmd = self.command
        if isinstance(cmd, HoldCommand):
            return cmd.yaw_rad, cmd.up_m, cmd.speed_mps
        assert isinstance(cmd, WaypointCommand)
        wps = cmd.waypoints_enu
        while self.wp_index < len(wps) - 1 and np.hypot(
            *(np.asarray(wps[self.wp_index][:2]) - p_enu[:2])
        ) < cmd.accept_radius_m:
            self.wp_index += 1
        wp = np.asarray(wps[self.wp_index], float)
        d = wp[:2] - p_enu[:2]
        yaw = float(np.arctan2(d[1], d[0]))
        return yaw, float(wp[2]), cmd.speed_mps or self.gains.default_speed_mps

    def update(self, p_enu: np.ndarray, airspeed_mps: float, dt_s: float) -> FixedWingDemand:
        g = self.gains
        yaw, up_m, speed = self._targets(p_enu)
        err = speed - airspeed_mps
        self._integ = float(np.clip(self._integ + g.ki_speed * err * dt_s, -0.5, 0.5))
        thr = float(np.clip(g.throttle_trim + g.kp_speed * err + self._integ, 0.0, 1.0))
        heading_deg = float(np.degrees(np.mod(0.5 * np.pi - yaw, 2.0 * np.pi)))
        return FixedWingDemand(heading_deg, up_m / 0.3048, thr)
