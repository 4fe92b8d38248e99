"""A point-mass quadcopter fleet, vectorised over every aircraft (struct of arrays, BlueSky style).

Each row is an F450 reduced to a point with a first-order velocity response: the autopilot's
velocity demand (the same P-on-position / commanded-velocity law and saturations as
``autopilot.QuadCascade.velocity_demand``) is followed with time constants ``tau_h_s`` (horizontal)
and ``tau_v_s`` (vertical), the horizontal acceleration saturated at ``max_accel_h_mps2``, speeds at
the measured maxima. Drag (``drag_per_m`` v^2) against the P velocity loop leaves the cascade's
steady error: the point mass flies v = v_demand - (c / kp_vel_xy) |v| v, so 8 m/s commanded is 7.86
m/s flown, as in JSBSim. A heading (course) change is a change of the velocity vector, so the turn rate
is bounded by ``max_accel_h_mps2 / speed``. Yaw follows its target at ``max_yaw_rate_rps``. Roll and
pitch are those of a quad producing the current horizontal acceleration (``atan(a / g)``, the
cascade's tilt law), so a hand-over to JSBSim can start with a consistent attitude.

The limits are the F450's as corridor's 6-DOF model flies them, measured by
:func:`corridor.vehicles.air.f450_envelope.measure_envelope` (the defaults below; the test re-measures
them). One step of ``dt_s`` uses the exact first-order decay of the velocity error, the acceleration
clamp on top, and trapezoidal position integration, so a coarse step (0.5 s) stays on the
fine-step trajectory.

The fleet takes the autopilot's commands (``Hover``, ``PositionCommand``, ``VelocityCommand``,
``WaypointCommand``) per aircraft, and whole-fleet velocity commands (:meth:`command_velocities`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.vehicles.air.autopilot import (
    G_MPS2,
    Command,
    Hover,
    PositionCommand,
    VelocityCommand,
    WaypointCommand,
)
from corridor.vehicles.geodesy import wrap_pi

F450_SIZE_M = (0.45, 0.45, 0.2)  # [m] length, width, height (as jsbsim_fleet.SIZE_M["F450"])


@dataclass(frozen=True)
class PointMassLimits:
    """F450 limits under corridor's cascade, measured by ``f450_envelope.measure_envelope``
    (``python -m corridor.vehicles.air.f450_envelope``); ``kp_pos`` is the cascade's position gain."""

    max_speed_h_mps: float = 8.0  # [m/s] the cascade's command limit (7.86 m/s flown: drag droop)
    max_climb_mps: float = 3.0  # [m/s]
    max_descent_mps: float = 2.03  # [m/s]
    max_accel_h_mps2: float = 3.5  # [m/s^2]
    tau_h_s: float = 0.5  # [s] (unsaturated: a 1 m/s step)
    tau_v_s: float = 0.2  # [s]
    max_yaw_rate_rps: float = 0.6  # [rad/s]
    drag_per_m: float = 0.00673  # [1/m] a_drag = c v^2
    integ_u_hover_mps2: float = 0.0636  # [m/s^2] the cascade's vertical integrator, a + b v^2 (hand-over)
    integ_u_per_m: float = 0.000394  # [1/m]
    kp_pos: float = 0.6  # [1/s] the cascade's gains (QuadGains)
    kp_vel_xy: float = 3.0  # [1/s]
    kp_yaw: float = 1.5  # [1/s]


class PmMode:
    POSITION = 0
    VELOCITY = 1


def _grow(a: np.ndarray, row: np.ndarray | float) -> np.ndarray:
    return np.concatenate([a, np.asarray(row, dtype=a.dtype).reshape((1, *a.shape[1:]))])


class PointMassFleet:
    """Point-mass F450s in the scenario's ENU frame; commands as ``JSBSimFleet.command`` takes them
    (``add``, ``command``, ``step``, ``snapshot_part``, ``ids``, ``t_s``)."""

    def __init__(self, limits: PointMassLimits | None = None) -> None:
        self.limits = limits or PointMassLimits()
        self.t_s = 0.0  # [s]
        self.ids: list[str] = []
        self.roles = np.zeros(0, dtype=np.int8)
        self.pos = np.zeros((0, 3))  # [m] ENU
        self.vel = np.zeros((0, 3))  # [m/s] ENU
        self.acc = np.zeros((0, 3))  # [m/s^2] over the last step
        self.yaw = np.zeros(0)  # [rad] ENU
        self.mode = np.zeros(0, dtype=np.int8)
        self.p_tgt = np.zeros((0, 3))  # [m]
        self.v_tgt = np.zeros((0, 3))  # [m/s]
        self.yaw_tgt = np.zeros(0)  # [rad]
        self.speed_limit = np.zeros(0)  # [m/s]
        self._wp: dict[int, tuple[WaypointCommand, int]] = {}
        self._row: dict[str, int] = {}

    # ------------------------------------------------------------------------------------ spawning
    def add(self, id: str, enu_m: np.ndarray | tuple[float, float, float], yaw_rad: float = 0.0,
            v_enu: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0), role: Role = Role.OTHER) -> int:
        """Spawn a quad at ``enu_m`` [m] with velocity ``v_enu`` [m/s]; it holds that position."""
        if id in self._row:
            raise ValueError(f"duplicate aircraft id {id!r}")
        p = np.asarray(enu_m, float)
        self._row[id] = len(self.ids)
        self.ids.append(id)
        self.roles = _grow(self.roles, int(role))
        self.pos, self.vel = _grow(self.pos, p), _grow(self.vel, np.asarray(v_enu, float))
        self.acc = _grow(self.acc, np.zeros(3))
        self.yaw, self.yaw_tgt = _grow(self.yaw, yaw_rad), _grow(self.yaw_tgt, yaw_rad)
        self.mode = _grow(self.mode, PmMode.POSITION)
        self.p_tgt, self.v_tgt = _grow(self.p_tgt, p), _grow(self.v_tgt, np.zeros(3))
        self.speed_limit = _grow(self.speed_limit, np.inf)
        return self._row[id]

    def row(self, id: str) -> int:
        return self._row[id]

    # ------------------------------------------------------------------------------------ commands
    def command(self, id: str, cmd: Command) -> None:
        """Give aircraft ``id`` an autopilot command (as ``JSBSimFleet.command`` does for a quad)."""
        q = self._row[id]
        self._wp.pop(q, None)
        self.speed_limit[q] = np.inf
        yaw = getattr(cmd, "yaw_rad", None)
        self.yaw_tgt[q] = self.yaw[q] if yaw is None else yaw
        if isinstance(cmd, Hover):
            self.mode[q], self.p_tgt[q] = PmMode.POSITION, self.pos[q]
        elif isinstance(cmd, PositionCommand):
            self.mode[q], self.p_tgt[q] = PmMode.POSITION, cmd.p_enu
        elif isinstance(cmd, VelocityCommand):
            self.mode[q], self.v_tgt[q] = PmMode.VELOCITY, cmd.v_enu
        elif isinstance(cmd, WaypointCommand):
            self.mode[q], self.p_tgt[q] = PmMode.POSITION, cmd.waypoints_enu[0]
            self.speed_limit[q] = cmd.speed_mps or np.inf
            self._wp[q] = (cmd, 0)
        else:
            raise TypeError(f"point-mass quadcopter cannot follow {type(cmd).__name__}")

    def command_velocities(self, rows: np.ndarray, v_enu: np.ndarray) -> None:
        """Velocity commands [m/s] (k, 3) for ``rows`` at once (yaw kept)."""
        for q in np.asarray(rows).tolist():
            self._wp.pop(q, None)
        self.mode[rows] = PmMode.VELOCITY
        self.v_tgt[rows] = v_enu
        self.speed_limit[rows] = np.inf
        self.yaw_tgt[rows] = self.yaw[rows]

    def current_command(self, q: int) -> Command:
        """Row ``q``'s active command, as an autopilot command another fleet can take over (waypoints:
        the remaining ones)."""
        yaw = float(self.yaw_tgt[q])
        if self.mode[q] == PmMode.VELOCITY:
            return VelocityCommand(tuple(map(float, self.v_tgt[q])), yaw)
        if q in self._wp:
            cmd, i = self._wp[q]
            return WaypointCommand(cmd.waypoints_enu[i:], cmd.speed_mps, cmd.accept_radius_m)
        return PositionCommand(tuple(map(float, self.p_tgt[q])), yaw)

    def set_state(self, q: int, p_enu: np.ndarray, v_enu: np.ndarray, yaw_rad: float, roll_rad: float,
                  pitch_rad: float) -> None:
        """Take over a state (a 6-DOF aircraft handing back): the acceleration is the one the attitude
        produces (inverse of :meth:`attitude`)."""
        self.pos[q], self.vel[q], self.yaw[q] = p_enu, v_enu, yaw_rad
        a_right, a_fwd = G_MPS2 * np.tan(roll_rad), -G_MPS2 * np.tan(pitch_rad)
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        self.acc[q] = np.array([c * a_fwd + s * a_right, s * a_fwd - c * a_right, 0.0]) - self.drag_acc([q])[0]

    def waypoint_index(self, id: str) -> int:
        return self._wp.get(self._row[id], (None, 0))[1]

    # ------------------------------------------------------------------------------------ dynamics
    def velocity_demand(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The cascade's velocity demand [m/s] (k, 3): P on position or the command, saturated."""
        lim = self.limits
        v = np.where((self.mode[rows] == PmMode.VELOCITY)[:, None], self.v_tgt[rows],
                     lim.kp_pos * (self.p_tgt[rows] - self.pos[rows]))
        h = np.hypot(v[:, 0], v[:, 1])
        cap = np.minimum(self.speed_limit[rows], lim.max_speed_h_mps)
        scale = np.minimum(1.0, cap / np.maximum(h, 1e-9))
        out = v * np.column_stack([scale, scale, np.ones_like(scale)])
        out[:, 2] = np.clip(v[:, 2], -lim.max_descent_mps, lim.max_climb_mps)
        return out

    def step(self, dt_s: float, rows: np.ndarray | slice = slice(None)) -> None:
        """Advance ``rows`` (default: all) by ``dt_s`` [s]; ``t_s`` advances only for a full step."""
        lim = self.limits
        v0 = self.vel[rows]
        dv = self.velocity_demand(rows) - v0
        dv[:, :2] -= (lim.drag_per_m / lim.kp_vel_xy) * np.hypot(v0[:, 0], v0[:, 1])[:, None] * v0[:, :2]
        dv[:, :2] *= 1.0 - np.exp(-dt_s / lim.tau_h_s)
        dv[:, 2] *= 1.0 - np.exp(-dt_s / lim.tau_v_s)
        dh = np.hypot(dv[:, 0], dv[:, 1])
        clamp = np.minimum(1.0, lim.max_accel_h_mps2 * dt_s / np.maximum(dh, 1e-12))
        dv[:, :2] *= clamp[:, None]
        v1 = v0 + dv
        self.acc[rows] = dv / dt_s
        self.pos[rows] = self.pos[rows] + 0.5 * (v0 + v1) * dt_s
        self.vel[rows] = v1
        yaw_rate = np.clip(lim.kp_yaw * wrap_pi(self.yaw_tgt[rows] - self.yaw[rows]),
                           -lim.max_yaw_rate_rps, lim.max_yaw_rate_rps)
        self.yaw[rows] = wrap_pi(self.yaw[rows] + yaw_rate * dt_s)
        if isinstance(rows, slice):
            self.t_s += dt_s
        self._advance_waypoints()

    def _advance_waypoints(self) -> None:
        for q, (cmd, i) in list(self._wp.items()):
            if i < len(cmd.waypoints_enu) - 1 and np.linalg.norm(self.pos[q] - cmd.waypoints_enu[i]) < cmd.accept_radius_m:
                self._wp[q] = (cmd, i + 1)
                self.p_tgt[q] = cmd.waypoints_enu[i + 1]

    def attitude(self, rows: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """(roll, pitch) [rad] of a quad producing the last step's horizontal acceleration plus the
        drag it overcomes (JSBSim body convention, the cascade's tilt law: roll = atan(a_right / g),
        pitch = -atan(a_fwd / g))."""
        a, yaw = self.acc[rows] + self.drag_acc(rows), self.yaw[rows]
        c, s = np.cos(yaw), np.sin(yaw)
        a_fwd, a_right = c * a[:, 0] + s * a[:, 1], s * a[:, 0] - c * a[:, 1]
        return np.arctan2(a_right, G_MPS2), -np.arctan2(a_fwd, G_MPS2)

    def drag_acc(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """[m/s^2] (k, 3) horizontal thrust that balances the drag: c |v_h| v_h."""
        v = self.vel[rows].copy()
        v[:, 2] = 0.0
        return self.limits.drag_per_m * np.hypot(v[:, 0], v[:, 1])[:, None] * v

    def integ_u(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """[m/s^2] the vertical integrator the cascade holds in this steady flight (hand-over)."""
        lim = self.limits
        return lim.integ_u_hover_mps2 + lim.integ_u_per_m * np.sum(self.vel[rows, :2] ** 2, axis=1)

    # ------------------------------------------------------------------------------------ reading
    def snapshot_part(self) -> WorldSnapshot:
        n = len(self.ids)
        return WorldSnapshot(t=self.t_s, ids=np.array(self.ids, dtype=object), kind=np.full(n, Kind.UAV, dtype=np.int8),
                             role=self.roles.copy(), position=self.pos.copy(), velocity=self.vel.copy(),
                             heading=self.yaw.copy(), size=np.tile(F450_SIZE_M, (n, 1)).astype(float))
