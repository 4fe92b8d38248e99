"""A point-mass quadcopter fleet, vectorised over every aircraft (struct of arrays, BlueSky style).

Each row is an F450 reduced to a point that flies corridor's quad cascade (``autopilot.QuadCascade``)
without the rotors: the autopilot's velocity demand (P on position or the commanded velocity, the
speed / climb saturations) gives a horizontal acceleration demand (P velocity loop, ``kp_vel_xy``), that
a tilt (roll, pitch: ``atan(a / g)``, at most ``max_tilt_rad``); the tilt follows its demand as the
cascade's attitude loop moves it (``kp_att``, at most ``max_tilt_rate_rps`` per body axis: the F450's
full-stick rate), and the thrust along the tilt accelerates the point against the drag ``drag_per_m``
v^2 (so 8 m/s commanded is 7.86 m/s flown, as in JSBSim). The tilt loop is the lag of a real quad: it
tilts before it accelerates (about 0.27 s from hover to a cruise command); a first-order velocity
response without it flew 1.5 m ahead of the 6-DOF F450 after every start. The vertical speed follows
its demand as a second-order system (natural frequency and damping ``wn_climb_rps`` / ``zeta_climb``
while the speed error asks for more thrust, ``wn_descent_rps`` / ``zeta_descent`` while it asks for
less: the 6-DOF F450's climb and descent steps, fitted at 120 Hz; the thrust cannot pull down harder
than free fall):
the rotors' thrust change lags a few hundredths of a second, then the climb rate rises and settles
within 0.5 s, where a first-order lag with the same 63 % time (``tau_v_s``) starts at once and is
still 8 % short after 0.5 s. The thrust's vertical part scales the horizontal acceleration (a quad
turns harder while it climbs). Yaw follows its target at ``max_yaw_rate_rps``. A hand-over to JSBSim
starts from the modelled attitude.

The speed, climb, drag and integrator figures are the F450's as corridor's 6-DOF model flies them,
measured by :func:`corridor.vehicles.air.f450_envelope.measure_envelope`; the tilt loop's constants are
the cascade's. ``measure_envelope("point_mass")`` measures the same envelope on this model (the test
compares both). One step of ``dt_s`` is integrated in sub-steps of at most ``max_substep_s``, so a
coarse step (0.5 s) stays on the fine-step trajectory.

The fleet takes the autopilot's commands (``Hover``, ``PositionCommand``, ``VelocityCommand``,
``WaypointCommand``) per aircraft, and whole-fleet velocity commands (:meth:`command_velocities`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

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
    tau_v_s: float = 0.2  # [s] time to 63 % of a climb step (an envelope figure; the response is the second order below)
    # vertical speed response, second order: natural frequency and damping while the thrust rises
    # (fitted at 120 Hz to the 6-DOF F450's +1, +2 m/s steps at cruise and hover -> full climb: rms 0.018
    # of the step) and while it falls (-1, -2 m/s steps at cruise: rms 0.024)
    wn_climb_rps: float = 9.5  # [rad/s]
    zeta_climb: float = 0.775
    wn_descent_rps: float = 7.5  # [rad/s]
    zeta_descent: float = 0.725
    max_yaw_rate_rps: float = 0.6  # [rad/s]
    drag_per_m: float = 0.00673  # [1/m] a_drag = c v^2
    integ_u_hover_mps2: float = 0.0636  # [m/s^2] the cascade's vertical integrator, a + b v^2 (hand-over)
    integ_u_per_m: float = 0.000394  # [1/m]
    kp_pos: float = 0.6  # [1/s] the cascade's gains (QuadGains)
    kp_vel_xy: float = 3.0  # [1/s]
    kp_yaw: float = 1.5  # [1/s]
    kp_att: float = 5.0  # [1/s] tilt error -> tilt rate (QuadGains)
    max_tilt_rad: float = 0.35  # [rad] (QuadGains)
    max_tilt_rate_rps: float = 0.75  # [rad/s] per axis: full stick (autopilot.F450_RATE_PER_STICK)
    max_substep_s: float = 0.05  # [s] integration sub-step (not a property of the F450)


def _demand(lim: PointMassLimits, by_pos: np.ndarray, pos: np.ndarray, p_tgt: np.ndarray, v_tgt: np.ndarray,
            cap: np.ndarray) -> np.ndarray:
    """The cascade's velocity demand [m/s] (k, 3): P on position where ``by_pos``, else the commanded
    velocity; horizontal norm saturated at ``cap`` [m/s], vertical at the climb / descent limits."""
    v = np.where(by_pos[:, None], lim.kp_pos * (p_tgt - pos), v_tgt)
    scale = np.minimum(1.0, cap / np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9))
    out = v * scale[:, None]
    out[:, 2] = np.clip(v[:, 2], -lim.max_descent_mps, lim.max_climb_mps)
    return out


@lru_cache(maxsize=16)
def _vertical_zoh(wn_rps: float, zeta: float, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact step ``h_s`` of the second-order vertical response v'' = wn^2 (v_d - v) - 2 zeta wn v' on
    the state (v, v') with the demand v_d held: (Phi (2, 2), Gamma (2,)), new state = Phi x + Gamma v_d."""
    m = np.zeros((3, 3))
    m[:2, :2] = [[0.0, 1.0], [-wn_rps**2, -2.0 * zeta * wn_rps]]
    m[1, 2] = wn_rps**2
    e = expm(m * h_s)
    return e[:2, :2].copy(), e[:2, 2].copy()


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
        self.tilt = np.zeros((0, 2))  # [rad] roll, pitch (JSBSim body convention)
        self.acc_v = np.zeros(0)  # [m/s^2] vertical acceleration (the second-order climb response's state)
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
        self.tilt = _grow(self.tilt, np.zeros(2))
        self.acc_v = _grow(self.acc_v, 0.0)
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
        """Take over a state (a 6-DOF aircraft handing back), its attitude included (the vertical
        acceleration starts at 0)."""
        self.pos[q], self.vel[q], self.yaw[q] = p_enu, v_enu, yaw_rad
        self.tilt[q] = (roll_rad, pitch_rad)
        self.acc_v[q] = 0.0

    def waypoint_index(self, id: str) -> int:
        return self._wp.get(self._row[id], (None, 0))[1]

    # ------------------------------------------------------------------------------------ dynamics
    def velocity_demand(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The cascade's velocity demand [m/s] (k, 3): P on position or the command, saturated."""
        cap = np.minimum(self.speed_limit[rows], self.limits.max_speed_h_mps)
        return _demand(self.limits, self.mode[rows] != PmMode.VELOCITY, self.pos[rows], self.p_tgt[rows],
                       self.v_tgt[rows], cap)

    def step(self, dt_s: float, rows: np.ndarray | slice = slice(None), waypoints: bool = True) -> None:
        """Advance ``rows`` (default: all) by ``dt_s`` [s]; ``t_s`` advances only for a full step.
        Integrated in sub-steps of at most ``max_substep_s`` (the attitude loop's time scale); each
        row's step depends on its own state and targets only. ``waypoints``: then advance the
        waypoint commands (a step split over processes does it once every part is in)."""
        lim = self.limits
        n_sub = max(1, int(np.ceil(dt_s / lim.max_substep_s - 1e-9)))
        h = dt_s / n_sub
        pos, vel, tilt, yaw, acc_v = self.pos[rows], self.vel[rows], self.tilt[rows], self.yaw[rows], self.acc_v[rows]
        mode, p_tgt, v_tgt = self.mode[rows], self.p_tgt[rows], self.v_tgt[rows]
        cap = np.minimum(self.speed_limit[rows], lim.max_speed_h_mps)
        yaw_tgt = self.yaw_tgt[rows]
        by_pos = mode != PmMode.VELOCITY
        phi_up, gamma_up = _vertical_zoh(lim.wn_climb_rps, lim.zeta_climb, h)
        phi_dn, gamma_dn = _vertical_zoh(lim.wn_descent_rps, lim.zeta_descent, h)
        for _ in range(n_sub):
            vd = _demand(lim, by_pos, pos, p_tgt, v_tgt, cap)
            c, s = np.cos(yaw), np.sin(yaw)
            a_e, a_n = lim.kp_vel_xy * (vd[:, 0] - vel[:, 0]), lim.kp_vel_xy * (vd[:, 1] - vel[:, 1])
            tilt_dem = np.column_stack([np.arctan2(s * a_e - c * a_n, G_MPS2), -np.arctan2(c * a_e + s * a_n, G_MPS2)])
            norm = np.hypot(tilt_dem[:, 0], tilt_dem[:, 1])
            tilt_dem *= np.minimum(1.0, lim.max_tilt_rad / np.maximum(norm, 1e-12))[:, None]
            tilt = tilt + h * np.clip(lim.kp_att * (tilt_dem - tilt), -lim.max_tilt_rate_rps, lim.max_tilt_rate_rps)
            up = vd[:, 2] >= vel[:, 2]  # the thrust rises (climb response) or falls (descent response)
            phi = np.where(up[:, None, None], phi_up, phi_dn)
            gamma = np.where(up[:, None], gamma_up, gamma_dn)
            vz1 = phi[:, 0, 0] * vel[:, 2] + phi[:, 0, 1] * acc_v + gamma[:, 0] * vd[:, 2]
            az1 = phi[:, 1, 0] * vel[:, 2] + phi[:, 1, 1] * acc_v + gamma[:, 1] * vd[:, 2]
            dvz = np.maximum(vz1 - vel[:, 2], -G_MPS2 * h)  # thrust >= 0: at most free fall
            acc_v = np.maximum(az1, -G_MPS2)
            lift = G_MPS2 + dvz / h  # [m/s^2] the thrust's vertical part (climbing: more, descending: less)
            a_right, a_fwd = lift * np.tan(tilt[:, 0]), -lift * np.tan(tilt[:, 1])
            v_h = np.hypot(vel[:, 0], vel[:, 1])
            v1 = vel.copy()
            v1[:, 0] += h * (c * a_fwd + s * a_right - lim.drag_per_m * v_h * vel[:, 0])
            v1[:, 1] += h * (s * a_fwd - c * a_right - lim.drag_per_m * v_h * vel[:, 1])
            v1[:, 2] += dvz
            pos = pos + 0.5 * h * (vel + v1)
            vel = v1
            yaw_rate = np.clip(lim.kp_yaw * wrap_pi(yaw_tgt - yaw), -lim.max_yaw_rate_rps, lim.max_yaw_rate_rps)
            yaw = wrap_pi(yaw + yaw_rate * h)
        self.pos[rows], self.vel[rows], self.tilt[rows], self.yaw[rows] = pos, vel, tilt, yaw
        self.acc_v[rows] = acc_v
        if isinstance(rows, slice):
            self.t_s += dt_s
        if waypoints:
            self.advance_waypoints()

    def state_rows(self, rows: np.ndarray) -> np.ndarray:
        """(k, 10) what ``step`` changes in ``rows``: position, velocity, tilt, yaw and the vertical
        acceleration (the second-order climb response's state: without it a rank that did not step a
        row would continue it from a stale acceleration and the ranks' fleets would part)."""
        return np.column_stack([self.pos[rows], self.vel[rows], self.tilt[rows], self.yaw[rows], self.acc_v[rows]])

    def set_state_rows(self, rows: np.ndarray, st: np.ndarray) -> None:
        """Take ``state_rows`` of ``rows`` (stepped elsewhere)."""
        self.pos[rows], self.vel[rows], self.tilt[rows], self.yaw[rows] = st[:, 0:3], st[:, 3:6], st[:, 6:8], st[:, 8]
        self.acc_v[rows] = st[:, 9]

    def advance_waypoints(self) -> None:
        for q, (cmd, i) in list(self._wp.items()):
            if i < len(cmd.waypoints_enu) - 1 and np.linalg.norm(self.pos[q] - cmd.waypoints_enu[i]) < cmd.accept_radius_m:
                self._wp[q] = (cmd, i + 1)
                self.p_tgt[q] = cmd.waypoints_enu[i + 1]

    def attitude(self, rows: np.ndarray | slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """(roll, pitch) [rad]: the modelled tilt (JSBSim body convention; the thrust's horizontal
        acceleration is g tan(roll) to the right, -g tan(pitch) forward)."""
        t = self.tilt[rows]
        return t[:, 0].copy(), t[:, 1].copy()

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
