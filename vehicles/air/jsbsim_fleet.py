"""A fleet of JSBSim aircraft (F450 quadcopters, c172x light aircraft) in the scenario's ENU frame.

Each aircraft is one ``jsbsim.FGFDMExec`` stepped at ``rate_hz`` (120 Hz, JSBSim's default). The
fleet converts between JSBSim's geodetic state and the local ENU frame (``geodesy.Origin``) and
exports a ``WorldSnapshot`` block. The quadcopters' cascade (position -> velocity -> attitude ->
the F450's rate loops) runs inside JSBSim as FCS components (``jsbsim_data/corridor_quad_cascade.xml``,
loaded through ``jsbsim_models.aircraft_dir``; the same equations as ``autopilot.QuadCascade``, its
tested reference), so each aircraft runs a step's sub-steps in a row and Python writes its targets
and reads its state once per step. The c172x's guidance (``autopilot.FixedWingGuidance``) runs in
Python every ``_fw_every`` sub-steps.

JSBSim notes (discovered from the data dir, ``jsbsim.get_default_root_dir()``):

- F450 rate loops are gated by ``fcs/ScasEngage`` (0 by default): set to 1. Sticks
  ``fcs/aileron|elevator|rudder-cmd-norm`` demand body rates p, q, r (0.75 rad/s at 1.0; positive =
  right wing down, nose up, nose right); ``fcs/throttle-cmd-norm`` is the collective (hover 0.413).
- JSBSim 1.3 prints a start-up banner, and the F450 a "YOU HAVE AN INCOMPATIBLE CFG FILE" record
  and 16 "Failed to tie property" records, regardless of ``set_debug_level(0)``. In jsbsim >= 1.3
  every record goes through a thread-local ``jsbsim.FGLogger`` whose default prints to Python's
  ``sys.stdout``; the fleet installs :class:`JSBSimLogSink`, which forwards the records to the
  ``logging`` logger ``corridor.vehicles.jsbsim`` at DEBUG (FATAL at WARNING). Loading also runs with
  fd 1 and 2 redirected to /dev/null (``quiet_fds``) for anything written by C/C++ directly.
- the ground is ``ic/terrain-elevation-ft``: it is set to the origin's height so that ENU up equals
  height above ground, and the aircraft starts at ``ic/h-sl-ft`` (ellipsoidal height of its ENU point).
- c172x: JSBSim's own ``ap/heading_hold`` (``ap/heading_setpoint`` true heading [deg]) and
  ``ap/altitude_hold`` (``ap/altitude_setpoint`` [ft AGL]); the engine is started with
  ``propulsion/set-running`` = -1, then a simple trim (``simulation/do_simple_trim``) at the IC speed.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import jsbsim
import numpy as np

from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.vehicles.air.autopilot import (
    Command,
    FixedWingGuidance,
    HoldCommand,
    Hover,
    PositionCommand,
    QuadGains,
    QuadMode,
    QuadTargets,
    VelocityCommand,
    WaypointCommand,
)
from corridor.vehicles.air.jsbsim_models import aircraft_dir, patched
from corridor.vehicles.geodesy import (
    FT_PER_M,
    M_PER_FT,
    Origin,
    enu_yaw_from_heading,
    heading_from_enu_yaw,
    metres_per_degree,
)

MODELS = ("F450", "c172x")
SIZE_M = {"F450": (0.45, 0.45, 0.2), "c172x": (8.3, 11.0, 2.7)}  # (length, width, height) [m]
KIND = {"F450": Kind.UAV, "c172x": Kind.AIRCRAFT}

# state read each sub-step: geodetic position, NED velocity, Euler angles, true airspeed
_STATE_PROPS = (
    "position/lat-geod-deg", "position/long-gc-deg", "position/h-sl-ft",
    "velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps",
    "attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad", "velocities/vt-fps",
)
_VEL_COLS = [4, 3, 5]  # v-east, v-north, v-down columns of _STATE_PROPS
_VEL_SIGN_M_PER_FT = np.array([1.0, 1.0, -1.0]) * M_PER_FT
# the cascade's inputs (jsbsim_data/corridor_quad_cascade.xml), written once per step in this order
_QUAD_CMD = tuple("corridor/cmd/" + p for p in (
    "velocity-mode", "v-e-mps", "v-n-mps", "v-u-mps", "err0-e-m", "err0-n-m", "err0-u-m",
    "ref-lat-deg", "ref-lon-deg", "ref-h-m", "m-per-deg-lat", "m-per-deg-lon", "speed-limit-mps", "yaw-rad",
))
# QuadGains field -> the cascade's gain property (max_speed_xy_mps enters through speed-limit-mps)
_QUAD_GAINS = {f: "corridor/gain/" + f.replace("_", "-") for f in (
    "kp_pos", "kp_vel_xy", "ki_vel_xy", "kp_vel_z", "ki_vel_z", "kp_att", "kp_yaw", "max_climb_mps",
    "max_descent_mps", "max_tilt_rad", "max_yaw_rate_rps", "hover_throttle", "integ_limit_mps2",
)}
_C172_INPUTS = ("ap/heading_setpoint", "ap/altitude_setpoint", "fcs/throttle-cmd-norm")


_LOG = logging.getLogger("corridor.vehicles.jsbsim")


class JSBSimLogSink(jsbsim.FGLogger):
    """JSBSim log records -> Python ``logging`` (DEBUG; FATAL as WARNING), one line group per record."""

    def __init__(self) -> None:
        super().__init__()
        self._parts: list[str] = []
        self._level = jsbsim.LogLevel.INFO

    def set_level(self, level: jsbsim.LogLevel) -> None:
        self._level = level
        self._parts = []

    def file_location(self, filename: str, line: int) -> None:
        self._parts.append(f"{filename}:{line}: ")

    def message(self, message: str) -> None:
        self._parts.append(message)

    def format(self, format: jsbsim.LogFormat) -> None:
        """Colour/emphasis hints are meaningless in a log file: ignored."""

    def flush(self) -> None:
        text = "".join(self._parts).strip()
        self._parts = []
        if text:
            level = logging.WARNING if self._level == jsbsim.LogLevel.FATAL else logging.DEBUG
            _LOG.log(level, "[%s] %s", jsbsim.LogLevel(self._level).name, text)


@contextlib.contextmanager
def quiet_fds() -> Iterator[None]:
    """Send fd 1 and 2 to /dev/null for the duration (C/C++ writes included), then restore them.

    libc's stdio buffers are flushed before restoring, so buffered C output does not leak afterwards.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    libc = ctypes.CDLL(None)
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        libc.fflush(None)
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


@dataclass(frozen=True)
class FleetState:
    """Struct-of-arrays state of the fleet in ENU: position [m], velocity [m/s], yaw [rad] (CCW from
    east), roll/pitch [rad] (JSBSim body Euler angles), true airspeed [m/s]."""

    ids: np.ndarray
    model: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    yaw: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    airspeed: np.ndarray


class JSBSimFleet:
    """A set of JSBSim aircraft stepped together; positions in the ENU frame around ``origin``.

    ``origin`` is (lat [deg], lon [deg], h [m]); ``rate_hz`` the JSBSim integration rate; ``root`` the
    JSBSim data directory (default: the one shipped in the jsbsim wheel).
    """

    def __init__(
        self,
        origin: tuple[float, float, float],
        rate_hz: float = 120.0,
        root: str | None = None,
        quad_gains: QuadGains | None = None,
    ) -> None:
        self.origin = Origin(*origin)
        self.rate_hz = float(rate_hz)
        self.root = root or jsbsim.get_default_root_dir()
        self.t_s = 0.0  # [s] simulated time
        self.ids: list[str] = []
        self.models: list[str] = []
        self.roles: list[int] = []
        self._fdms: list[jsbsim.FGFDMExec] = []
        self._nodes: list[list[jsbsim.FGPropertyNode]] = []  # per aircraft: state nodes (_STATE_PROPS order)
        # hot path (120 Hz x every aircraft): flat lists of bound methods, no per-call attribute lookups
        self._runs: list[Callable[[], bool]] = []  # FGFDMExec.run of every aircraft
        self._getters: list[Callable[[], float]] = []  # state nodes' get_double_value, row-major
        self._raw = np.zeros((0, len(_STATE_PROPS)))
        self._quad_rows: list[int] = []  # fleet row of each quad-cascade row
        self._cmd_setters: list[Callable[[float], None]] = []  # quads' cascade inputs, row-major (_QUAD_CMD)
        self._quad_wp: dict[int, tuple[WaypointCommand, int]] = {}  # quad row -> (command, index)
        self.quad_targets = QuadTargets()
        self.quad_gains = quad_gains or QuadGains()
        self._fw_rows: list[int] = []
        self._fw_in: list[list[jsbsim.FGPropertyNode]] = []
        self._fw_guidance: list[FixedWingGuidance] = []
        self._fw_every = max(1, round(self.rate_hz / 10.0))  # fixed-wing guidance at ~10 Hz
        self._substep = 0
        self._log_sink = JSBSimLogSink()

    # ------------------------------------------------------------------------------------ spawning
    def _new_fdm(self, model: str) -> jsbsim.FGFDMExec:
        """Create and load one FGFDMExec without any console output."""
        jsbsim.set_logger(self._log_sink)  # thread-local: set by the thread that builds the FDMs
        with quiet_fds():
            fdm = jsbsim.FGFDMExec(self.root)
            fdm.set_debug_level(0)
            if patched(model):  # corridor's copy with its FCS system (jsbsim_models.py)
                fdm.set_aircraft_path(aircraft_dir(self.root))
            if not fdm.load_model(model):
                raise RuntimeError(f"JSBSim could not load model {model!r} from {self.root}")
        fdm.set_dt(1.0 / self.rate_hz)
        return fdm

    def _set_ic(self, fdm: jsbsim.FGFDMExec, enu_m: np.ndarray, heading_rad: float, speed_mps: float) -> None:
        lat, lon, h = self.origin.to_geodetic(enu_m)
        fdm["ic/lat-geod-deg"] = float(lat)
        fdm["ic/long-gc-deg"] = float(lon)
        fdm["ic/terrain-elevation-ft"] = self.origin.h_m * FT_PER_M
        fdm["ic/h-sl-ft"] = float(h) * FT_PER_M
        fdm["ic/psi-true-deg"] = float(np.degrees(heading_from_enu_yaw(heading_rad)))
        fdm["ic/vt-fps"] = speed_mps * FT_PER_M

    def add(
        self,
        id: str,
        model: str,
        enu_m: np.ndarray | tuple[float, float, float],
        heading_rad: float = 0.0,
        speed_mps: float = 0.0,
        role: Role = Role.OTHER,
    ) -> None:
        """Spawn aircraft ``id`` of ``model`` ("F450" or "c172x") at ``enu_m`` [m] with ENU yaw
        ``heading_rad``. A quadcopter starts hovering there; a c172x starts trimmed in level flight at
        ``speed_mps`` (default 50 m/s), engine running, holding its heading and altitude."""
        if model not in MODELS:
            raise ValueError(f"unknown model {model!r}; expected one of {MODELS}")
        if id in self.ids:
            raise ValueError(f"duplicate aircraft id {id!r}")
        enu = np.asarray(enu_m, dtype=float)
        fdm = self._new_fdm(model)
        if model == "c172x":
            speed_mps = speed_mps or 50.0
        self._set_ic(fdm, enu, heading_rad, speed_mps)
        with quiet_fds():
            if not fdm.run_ic():
                raise RuntimeError(f"JSBSim initial conditions failed for {id!r}")
            if model == "F450":
                fdm["fcs/ScasEngage"] = 1.0
            else:
                self._start_c172(fdm, enu, heading_rad, speed_mps)
        row = len(self.ids)
        self.ids.append(id)
        self.models.append(model)
        self.roles.append(int(role))
        self._fdms.append(fdm)
        pm = fdm.get_property_manager()
        self._nodes.append([pm.get_node(p) for p in _STATE_PROPS])
        self._runs.append(fdm.run)
        self._getters.extend(n.get_double_value for n in self._nodes[-1])
        self._raw = np.vstack([self._raw, self._read_row(row)[None, :]])
        if model == "F450":
            self._add_quad(row, pm, enu, heading_rad)
        else:
            self._add_fixed_wing(row, pm, enu, heading_rad, speed_mps)

    def _start_c172(self, fdm: jsbsim.FGFDMExec, enu: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        """Engine on, mixture rich, trimmed level flight, JSBSim heading/altitude holds engaged."""
        fdm["propulsion/set-running"] = -1
        fdm["fcs/mixture-cmd-norm"] = 1.0
        fdm["fcs/throttle-cmd-norm"] = 0.65
        fdm["simulation/do_simple_trim"] = 1
        fdm["ap/heading_setpoint"] = float(np.degrees(heading_from_enu_yaw(yaw_rad)))
        fdm["ap/altitude_setpoint"] = enu[2] * FT_PER_M
        fdm["ap/heading_hold"] = 1
        fdm["ap/altitude_hold"] = 1

    def _add_quad(self, row: int, pm: jsbsim.FGPropertyManager, enu: np.ndarray, yaw_rad: float) -> None:
        self._quad_rows.append(row)
        for name, prop in _QUAD_GAINS.items():
            pm.get_node(prop).set_double_value(float(getattr(self.quad_gains, name)))
        self._cmd_setters.extend(pm.get_node(p).set_double_value for p in _QUAD_CMD)
        self.quad_targets.append(enu, yaw_rad, np.inf)

    def _add_fixed_wing(self, row: int, pm: jsbsim.FGPropertyManager, enu: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        guidance = FixedWingGuidance()
        guidance.set_command(HoldCommand(yaw_rad, float(enu[2]), speed_mps))
        self._fw_rows.append(row)
        self._fw_in.append([pm.get_node(p) for p in _C172_INPUTS])
        self._fw_guidance.append(guidance)

    # ------------------------------------------------------------------------------------ commands
    def command(self, id: str, cmd: Command) -> None:
        """Give aircraft ``id`` a new command (see ``autopilot.py``); it applies from the next sub-step."""
        row = self.ids.index(id)
        if self.models[row] == "c172x":
            self._fw_guidance[self._fw_rows.index(row)].set_command(cmd)
            return
        q = self._quad_rows.index(row)
        self._quad_wp.pop(q, None)
        tgt = self.quad_targets
        tgt.speed_limit_mps[q] = np.inf
        yaw = getattr(cmd, "yaw_rad", None)
        tgt.yaw_rad[q] = self._yaw(row) if yaw is None else yaw
        if isinstance(cmd, Hover):
            tgt.mode[q], tgt.p_enu[q] = QuadMode.POSITION, self._enu(row)
        elif isinstance(cmd, PositionCommand):
            tgt.mode[q], tgt.p_enu[q] = QuadMode.POSITION, cmd.p_enu
        elif isinstance(cmd, VelocityCommand):
            tgt.mode[q], tgt.v_enu[q] = QuadMode.VELOCITY, cmd.v_enu
        elif isinstance(cmd, WaypointCommand):
            tgt.mode[q], tgt.p_enu[q] = QuadMode.POSITION, cmd.waypoints_enu[0]
            tgt.speed_limit_mps[q] = cmd.speed_mps or np.inf
            self._quad_wp[q] = (cmd, 0)
        else:
            raise TypeError(f"quadcopter cannot follow {type(cmd).__name__}")

    def waypoint_index(self, id: str) -> int:
        """Index of the active waypoint of ``id`` (0 if it is not following waypoints)."""
        row = self.ids.index(id)
        if self.models[row] == "c172x":
            return self._fw_guidance[self._fw_rows.index(row)].wp_index
        return self._quad_wp.get(self._quad_rows.index(row), (None, 0))[1]

    # ------------------------------------------------------------------------------------ stepping
    def step(self, dt_s: float) -> None:
        """Advance every aircraft by ``n = round(dt_s * rate_hz)`` JSBSim sub-steps.

        The quads' cascade runs inside JSBSim (``jsbsim_data/corridor_quad_cascade.xml``), so each
        aircraft runs its sub-steps in a row (one aircraft's data stays in the CPU caches) and Python
        writes its targets once per step. Fixed wings get their guidance every ``_fw_every``
        sub-steps: the step is cut into segments at those instants (one segment per step at the
        default 120 Hz / 0.1 s)."""
        n = round(dt_s * self.rate_hz)
        jsbsim.set_logger(self._log_sink)  # the stepping thread may differ from the building one
        self._write_quad_targets()
        done = 0
        while done < n:
            k = self._substep + done
            if self._fw_rows and k % self._fw_every == 0:
                if done:
                    self._read_all()
                self._control_fixed_wing(self._fw_every / self.rate_hz)
            seg = min(n - done, self._fw_every - k % self._fw_every) if self._fw_rows else n
            for run in self._runs:
                for _ in range(seg):
                    run()
            done += seg
        self._read_all()
        self._substep += n
        self.t_s += n / self.rate_hz
        self._advance_quad_waypoints()

    def _write_quad_targets(self) -> None:
        """Every quad's targets into its cascade inputs (``_QUAD_CMD`` order); position-mode rows get
        the error to their target at the current state and that state as the linearisation point."""
        if not self._quad_rows:
            return
        tgt, g = self.quad_targets, self.quad_gains
        raw = self._raw if len(self._quad_rows) == len(self.ids) else self._raw[self._quad_rows]
        vel_mode = tgt.mode == QuadMode.VELOCITY
        err0 = np.zeros_like(tgt.p_enu)
        pos = ~vel_mode
        if pos.any():
            err0[pos] = tgt.p_enu[pos] - self._enu_rows(raw[pos])
        m_lat, m_lon = metres_per_degree(raw[:, 0], raw[:, 2] * M_PER_FT)
        cols = np.column_stack([
            vel_mode.astype(float), tgt.v_enu, err0, raw[:, 0], raw[:, 1], raw[:, 2] * M_PER_FT, m_lat, m_lon,
            np.minimum(tgt.speed_limit_mps, g.max_speed_xy_mps), tgt.yaw_rad,
        ])
        for set_value, value in zip(self._cmd_setters, cols.ravel().tolist(), strict=True):
            set_value(value)

    def _control_fixed_wing(self, dt_s: float) -> None:
        raw = self._raw[self._fw_rows]
        p = self._enu_rows(raw)
        for k, (guidance, nodes) in enumerate(zip(self._fw_guidance, self._fw_in, strict=True)):
            d = guidance.update(p[k], raw[k, 9] * M_PER_FT, dt_s)
            nodes[0].set_double_value(d.heading_deg)
            nodes[1].set_double_value(d.altitude_agl_ft)
            nodes[2].set_double_value(d.throttle)

    def _advance_quad_waypoints(self) -> None:
        """Move each waypoint-following quad to its next waypoint once inside the acceptance radius."""
        if not self._quad_wp:
            return
        p = self._enu_rows(self._raw[self._quad_rows])
        for q, (cmd, i) in list(self._quad_wp.items()):
            if i < len(cmd.waypoints_enu) - 1 and np.linalg.norm(p[q] - cmd.waypoints_enu[i]) < cmd.accept_radius_m:
                self._quad_wp[q] = (cmd, i + 1)
                self.quad_targets.p_enu[q] = cmd.waypoints_enu[i + 1]

    # ------------------------------------------------------------------------------------ reading
    def _read_row(self, row: int) -> np.ndarray:
        return np.array([n.get_double_value() for n in self._nodes[row]])

    def _read_all(self) -> None:
        self._raw = np.array([get() for get in self._getters]).reshape(-1, len(_STATE_PROPS))

    def _enu_rows(self, raw: np.ndarray) -> np.ndarray:
        return self.origin.to_enu(raw[:, 0], raw[:, 1], raw[:, 2] * M_PER_FT)

    @staticmethod
    def _vel_rows(raw: np.ndarray) -> np.ndarray:
        return raw[:, _VEL_COLS] * _VEL_SIGN_M_PER_FT  # NED [ft/s] -> ENU [m/s]

    @staticmethod
    def _euler_rows(raw: np.ndarray) -> np.ndarray:
        out = raw[:, 6:9].copy()
        out[:, 2] = enu_yaw_from_heading(raw[:, 8])
        return out

    def _enu(self, row: int) -> np.ndarray:
        return self._enu_rows(self._raw[row : row + 1])[0]

    def _yaw(self, row: int) -> float:
        return float(enu_yaw_from_heading(self._raw[row, 8]))

    def state(self) -> FleetState:
        """Current fleet state in ENU (rows in the order aircraft were added)."""
        raw = self._raw.reshape(-1, len(_STATE_PROPS))
        euler = self._euler_rows(raw)
        return FleetState(
            ids=np.array(self.ids, dtype=object),
            model=np.array(self.models, dtype=object),
            position=self._enu_rows(raw).reshape(-1, 3),
            velocity=self._vel_rows(raw),
            yaw=euler[:, 2],
            roll=euler[:, 0],
            pitch=euler[:, 1],
            airspeed=raw[:, 9] * M_PER_FT,
        )

    def snapshot_part(self) -> WorldSnapshot:
        """This fleet's block of the world snapshot (kind UAV for F450, AIRCRAFT for c172x)."""
        s = self.state()
        return WorldSnapshot(
            t=self.t_s,
            ids=s.ids,
            kind=np.array([KIND[m] for m in self.models], dtype=np.int8),
            role=np.array(self.roles, dtype=np.int8),
            position=s.position,
            velocity=s.velocity,
            heading=s.yaw,
            size=np.array([SIZE_M[m] for m in self.models], dtype=float).reshape(-1, 3),
        )

    def get_property(self, id: str, name: str) -> float:
        """Read any JSBSim property of aircraft ``id`` (diagnostics, tests)."""
        return float(self._fdms[self.ids.index(id)][name])
