"""The engine's air backend: a JSBSim fleet (F450 quadcopters, c172x) behind corridor's ``Backend``.

A scenario lists its aircraft under ``backends.<name>.params.aircraft`` (id, model, start ENU, yaw,
goal / waypoints, cruise speed, role), or lets a generator build them from a few numbers that
``randomize`` can draw:

- ``encounter``: a pairwise encounter of two quadcopters whose straight paths pass the conflict point
  at the same instant (geometry 0 head-on, 1 crossing, 2 overtaking), so with no avoidance the pair
  is a real conflict; optionally a crossing c172x (the piloted intruder UAVs must give way to).
- ``swarm``: N quadcopters on a circle, each flying to the diametrically opposite point, i.e. all of
  them swap positions through the common centre at the same time.

Each tick (period = the scenario's ``dt``) the backend applies the autopilot commands found on the bus
(:class:`AircraftCommand` wrapping an ``autopilot`` command), steps the fleet with its own 120 Hz
JSBSim sub-steps, and exports the fleet's snapshot block. Yaw angles are ENU (CCW from east).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.engine import Backend, Metric, RunContext
from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.vehicles.air.autopilot import Command, HoldCommand, Hover, WaypointCommand

Vec3 = tuple[float, float, float]


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class AircraftSpec(_Frozen):
    """One aircraft of the scenario. Quadcopters with a ``goal_enu`` are the ones avoidance
    controllers govern; a c172x follows ``waypoints_enu`` (or holds its yaw/altitude/speed)."""

    id: str
    model: Literal["F450", "c172x"] = "F450"
    start_enu: Vec3  # [m]
    yaw_deg: float = 0.0  # [deg] ENU, CCW from east
    speed_mps: float = Field(0.0, ge=0.0)  # [m/s] initial speed (c172x: trimmed airspeed, default 50)
    cruise_speed_mps: float = Field(6.0, gt=0.0)  # [m/s] speed towards the goal / along waypoints
    goal_enu: Vec3 | None = None  # [m]
    waypoints_enu: list[Vec3] | None = None  # [m]
    role: Literal["controlled", "piloted", "other"] = "controlled"

    @property
    def is_piloted(self) -> bool:
        return self.model == "c172x" or self.role == "piloted"

    def initial_command(self) -> Command:
        """Quad: straight to the goal at cruise speed (or hover); c172x: waypoints or a hold."""
        if self.waypoints_enu:
            return WaypointCommand(tuple(self.waypoints_enu), self.cruise_speed_mps,
                                   accept_radius_m=2.0 if self.model == "F450" else 60.0)
        if self.goal_enu is not None:
            return WaypointCommand((self.goal_enu,), self.cruise_speed_mps)
        if self.model == "c172x":
            return HoldCommand(np.radians(self.yaw_deg), self.start_enu[2], self.speed_mps or 50.0)
        return Hover()


class EncounterSpec(_Frozen):
    """Two quadcopters meeting at ``conflict_enu`` after ``time_to_conflict_s`` of straight flight.

    A flies along ``course_deg``; B's course is A's plus 180 (head-on), 90 (crossing) or 0
    (overtaking) degrees, plus ``heading_offset_deg``. In the overtaking geometry B is the faster
    one (``overtake_speed_mps``) and starts farther back. ``alt_offset_m`` puts B above/below A.
    """

    geometry: int = Field(0, ge=0, le=2)  # 0 head-on, 1 crossing, 2 overtaking
    conflict_enu: Vec3 = (0.0, 0.0, 60.0)  # [m]
    course_deg: float = 0.0  # [deg] ENU course of A
    heading_offset_deg: float = 0.0  # [deg] added to B's course
    alt_offset_m: float = 0.0  # [m] B's altitude minus A's
    speed_mps: float = Field(6.0, gt=0.0)  # [m/s] cruise of A (and of B unless overtaking)
    overtake_speed_mps: float = Field(7.5, gt=0.0)  # [m/s] B's cruise when overtaking
    overtake_lead_speed_mps: float = Field(3.0, gt=0.0)  # [m/s] A's cruise when overtaking
    time_to_conflict_s: float = Field(25.0, gt=0.0)  # [s] of cruise before the conflict point
    beyond_m: float = Field(120.0, gt=0.0)  # [m] goal distance past the conflict point (faster UAV)
    piloted: bool = True  # add the crossing c172x
    piloted_course_deg: float = 90.0  # [deg] relative to A's course
    piloted_alt_offset_m: float = 30.0  # [m] above the conflict point
    piloted_time_s: float = 25.0  # [s] when the c172x passes over the conflict point
    piloted_speed_mps: float = Field(50.0, gt=0.0)  # [m/s]


class SwarmSpec(_Frozen):
    """``n`` quadcopters evenly spaced on a circle, each flying to the opposite point."""

    n: int = Field(20, ge=2, le=250)
    centre_enu: Vec3 = (0.0, 0.0, 60.0)  # [m]
    radius_m: float = Field(150.0, gt=0.0)
    speed_mps: float = Field(6.0, gt=0.0)  # [m/s]
    alt_jitter_m: float = Field(0.0, ge=0.0)  # [m] +-amplitude of a deterministic altitude pattern


class PatrolSpec(_Frozen):
    """``n`` patrol quadcopters over a ring road (centre at the origin), one sector of ``360 / n`` deg
    each, plus a crossing c172x and an emergency medical drone (both priority traffic, seen through
    ADS-B / Remote ID).  Sector j spans ``offset_deg + j 360 / n`` .. ``+ 360 / n``; its UAV starts at
    ``start_frac`` of the sector.  The c172x passes ``aircraft_alt_offset_m`` above the patrol altitude
    over the ring point at ``aircraft_cross_deg`` at ``aircraft_time_s``, on the course
    ``aircraft_course_deg``.  The medical drone flies from ``medical_radius_m`` outside the ring at
    ``medical_from_deg`` straight over the ring centre to the opposite side, at the patrol altitude."""

    n: int = Field(6, ge=0, le=64)  # 0: no patrol (a road-only variant keeps the backend, empty)
    ring_radius_m: float = Field(1591.5, gt=0.0)  # [m] the road's reference radius
    alt_m: float = Field(60.0, gt=5.0)  # [m] ENU up
    alt_step_m: float = Field(0.0, ge=0.0)  # [m] sector j flies at alt_m + (j % 2) alt_step_m
    speed_mps: float = Field(7.0, gt=0.0)  # [m/s] patrol cruise
    offset_deg: float = 0.0
    start_frac: float = Field(0.5, ge=0.0, le=1.0)
    aircraft: bool = True
    aircraft_cross_deg: float = 45.0  # [deg] ring point the c172x passes over
    aircraft_course_deg: float = 0.0  # [deg] ENU course
    aircraft_time_s: float = Field(300.0, gt=0.0)  # [s] when it passes over that point
    aircraft_alt_offset_m: float = 30.0  # [m] above alt_m
    aircraft_speed_mps: float = Field(50.0, gt=0.0)
    medical: bool = True
    medical_from_deg: float = 200.0  # [deg] where it enters, outside the ring
    medical_radius_m: float = Field(1900.0, gt=0.0)  # [m] start/end distance from the centre
    medical_speed_mps: float = Field(8.0, gt=0.0)

    def sector(self, j: int) -> tuple[float, float]:
        """Sector j's start and end angle [rad] (counter-clockwise)."""
        w = 2.0 * np.pi / self.n
        a = np.radians(self.offset_deg) + j * w
        return float(a), float(a + w)

    def alt(self, j: int) -> float:
        return self.alt_m + (j % 2) * self.alt_step_m


def patrol_aircraft(s: PatrolSpec) -> list[AircraftSpec]:
    """The patrol quads (goal: the far end of their sector), the c172x and the medical drone."""
    out = []
    r = s.ring_radius_m
    for j in range(s.n):
        a0, a1 = s.sector(j)
        a = a0 + s.start_frac * (a1 - a0)
        start = np.array([r * np.cos(a), r * np.sin(a), s.alt(j)])
        goal = np.array([r * np.cos(a1), r * np.sin(a1), s.alt(j)])
        out.append(AircraftSpec(id=f"patrol_{j}", start_enu=tuple(map(float, start)), goal_enu=tuple(map(float, goal)),
                                yaw_deg=float(np.degrees(a) + 90.0), cruise_speed_mps=s.speed_mps))
    if s.aircraft:
        c = np.radians(s.aircraft_cross_deg)
        over = np.array([r * np.cos(c), r * np.sin(c), s.alt_m + s.aircraft_alt_offset_m])
        u = _unit(s.aircraft_course_deg)
        start = over - u * s.aircraft_speed_mps * s.aircraft_time_s
        end = over + u * s.aircraft_speed_mps * 600.0
        out.append(AircraftSpec(id="c172", model="c172x", start_enu=tuple(map(float, start)),
                                yaw_deg=float(s.aircraft_course_deg), speed_mps=s.aircraft_speed_mps,
                                cruise_speed_mps=s.aircraft_speed_mps, waypoints_enu=[tuple(map(float, end))],
                                role="piloted"))
    if s.medical:
        u = _unit(s.medical_from_deg)
        start = u * s.medical_radius_m + np.array([0.0, 0.0, s.alt_m])
        end = -u * s.medical_radius_m + np.array([0.0, 0.0, s.alt_m])
        out.append(AircraftSpec(id="medical", start_enu=tuple(map(float, start)), yaw_deg=float(s.medical_from_deg + 180.0),
                                cruise_speed_mps=s.medical_speed_mps, waypoints_enu=[tuple(map(float, end))],
                                role="piloted"))
    return out


def _unit(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([np.cos(a), np.sin(a), 0.0])


def _quad(id: str, start: np.ndarray, goal: np.ndarray, speed: float) -> AircraftSpec:
    d = goal - start
    return AircraftSpec(id=id, start_enu=tuple(map(float, start)), goal_enu=tuple(map(float, goal)),
                        yaw_deg=float(np.degrees(np.arctan2(d[1], d[0]))), cruise_speed_mps=speed)


def encounter_aircraft(e: EncounterSpec) -> list[AircraftSpec]:
    """The aircraft of one pairwise encounter (see :class:`EncounterSpec`)."""
    c = np.asarray(e.conflict_enu, float)
    rel = {0: 180.0, 1: 90.0, 2: 0.0}[e.geometry]
    v_a, v_b = e.speed_mps, e.speed_mps
    if e.geometry == 2:
        v_a, v_b = e.overtake_lead_speed_mps, e.overtake_speed_mps
    u_a, u_b = _unit(e.course_deg), _unit(e.course_deg + rel + e.heading_offset_deg)
    lift = np.array([0.0, 0.0, e.alt_offset_m])
    # goals: both fly on for the same time after the conflict (the slower one stops shorter), so in
    # the overtaking geometry the two goals are (beyond_m (1 - v_a / v_b)) apart, not one point
    beyond_a = e.beyond_m * v_a / max(v_a, v_b)
    beyond_b = e.beyond_m * v_b / max(v_a, v_b)
    out = [
        _quad("uav_a", c - u_a * v_a * e.time_to_conflict_s, c + u_a * beyond_a, v_a),
        _quad("uav_b", c + lift - u_b * v_b * e.time_to_conflict_s, c + lift + u_b * beyond_b, v_b),
    ]
    if e.piloted:
        u_m = _unit(e.course_deg + e.piloted_course_deg)
        over = c + np.array([0.0, 0.0, e.piloted_alt_offset_m])
        start = over - u_m * e.piloted_speed_mps * e.piloted_time_s
        end = over + u_m * e.piloted_speed_mps * 60.0
        out.append(AircraftSpec(id="c172", model="c172x", start_enu=tuple(map(float, start)),
                                yaw_deg=float(e.course_deg + e.piloted_course_deg),
                                speed_mps=e.piloted_speed_mps, cruise_speed_mps=e.piloted_speed_mps,
                                waypoints_enu=[tuple(map(float, end))], role="piloted"))
    return out


def swarm_aircraft(s: SwarmSpec) -> list[AircraftSpec]:
    """The aircraft of a position swap through the centre (see :class:`SwarmSpec`)."""
    c = np.asarray(s.centre_enu, float)
    out = []
    for k in range(s.n):
        a = 2.0 * np.pi * k / s.n
        r = s.radius_m * np.array([np.cos(a), np.sin(a), 0.0])
        dz = np.array([0.0, 0.0, s.alt_jitter_m * np.sin(3.0 * a)])
        out.append(_quad(f"uav_{k:02d}", c + r + dz, c - r + dz, s.speed_mps))
    return out


_AIR_KINDS = (int(Kind.UAV), int(Kind.AIRCRAFT))  # plain ints: numpy compares IntEnum members slowly


def air_rows(s: WorldSnapshot) -> dict[str, int]:
    """id -> row of the snapshot's aircraft only (``WorldSnapshot.index`` maps every row, thousands
    of road vehicles in a shared scenario, which the UAV components looked up every tick)."""
    rows = np.flatnonzero((s.kind == _AIR_KINDS[0]) | (s.kind == _AIR_KINDS[1]))
    return {str(s.ids[k]): int(k) for k in rows}


@dataclass(frozen=True)
class AircraftCommand:
    """A bus command for the air backend: an ``autopilot`` command addressed to one aircraft."""

    aircraft_id: str
    command: Command


class AirBackend(Backend):
    """JSBSim fleet as an engine backend (registered as ``jsbsim_fleet``)."""

    provides: ClassVar[frozenset[str]] = frozenset({"air"})
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('aircraft', '1',
               'Aircraft and UAVs flown.'),
        Metric('air_commands', '1',
               'Commands applied to the aircraft.'),
        Metric('rtf', '1',
               'Real-time factor: simulated seconds per wall-clock second (a measure of the machine).'),
    )
    period_source: ClassVar[str | None] = "dt"  # [s] the base tick (JSBSim sub-steps at rate_hz inside)

    class Params(_Frozen):
        aircraft: list[AircraftSpec] = Field(default_factory=list)
        encounter: EncounterSpec | None = None
        swarm: SwarmSpec | None = None
        patrol: PatrolSpec | None = None
        rate_hz: float = Field(120.0, gt=0.0)  # [Hz] JSBSim integration rate

        @model_validator(mode="after")
        def _unique_ids(self) -> AirBackend.Params:
            ids = [a.id for a in self.expanded()]
            if len(set(ids)) != len(ids):
                raise ValueError(f"aircraft ids must be unique: {ids}")
            return self

        def expanded(self) -> list[AircraftSpec]:
            """Explicit aircraft, then the encounter's, the swarm's, the patrol's."""
            out = list(self.aircraft)
            if self.encounter is not None:
                out += encounter_aircraft(self.encounter)
            if self.swarm is not None:
                out += swarm_aircraft(self.swarm)
            if self.patrol is not None:
                out += patrol_aircraft(self.patrol)
            return out

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        o = scenario.origin
        self.origin = (o.lat, o.lon, o.alt)
        self.aircraft = params.expanded()
        self.fleet: Any = None
        self.commands_applied = 0
        self._wall_t0: float | None = None

    # ---- lookup helpers used by the link, the controllers and the monitors ------------------------
    def spec(self, aircraft_id: str) -> AircraftSpec:
        return next(a for a in self.aircraft if a.id == aircraft_id)

    def goals(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Aircraft id -> (start, goal) [m] of every aircraft that has a goal."""
        return {a.id: (np.asarray(a.start_enu, float), np.asarray(a.goal_enu, float))
                for a in self.aircraft if a.goal_enu is not None}

    def attitudes(self) -> dict[str, tuple[float, float]]:
        """Aircraft id -> (roll, pitch) [rad] now (JSBSim body Euler angles): the seam through which
        an onboard sensor (a camera's footprint) learns its own attitude; the snapshot carries yaw only."""
        st = self.fleet.state()
        return {str(i): (float(r), float(p)) for i, r, p in zip(st.ids, st.roll, st.pitch, strict=True)}

    # ---- Backend ---------------------------------------------------------------------------------
    def setup(self, ctx: RunContext) -> None:
        from corridor.vehicles.air.jsbsim_fleet import JSBSimFleet

        self.fleet = JSBSimFleet(self.origin, rate_hz=self.params.rate_hz)
        for a in self.aircraft:
            role = Role.CONTROLLED if a.role == "controlled" else Role.OTHER
            self.fleet.add(a.id, a.model, a.start_enu, np.radians(a.yaw_deg), a.speed_mps, role)
            self.fleet.command(a.id, a.initial_command())
        self._wall_t0: float | None = None  # started at the first tick: JSBSim loading excluded

    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        if self.fleet is None:
            return
        for c in commands:
            if isinstance(c, AircraftCommand) and c.aircraft_id in self.fleet.ids:
                self.fleet.command(c.aircraft_id, c.command)
                self.commands_applied += 1

    def tick(self, ctx: RunContext) -> None:
        if self._wall_t0 is None:
            self._wall_t0 = time.perf_counter()
        self.fleet.step(self.period)
        self._check_finite()

    def _check_finite(self) -> None:
        """JSBSim returns NaN once an aircraft hits the ground or leaves its envelope: fail loudly."""
        raw = self.fleet.state().position
        bad = ~np.all(np.isfinite(raw), axis=1)
        if bad.any():
            ids = [self.fleet.ids[i] for i in np.flatnonzero(bad)]
            raise RuntimeError(f"JSBSim state of {', '.join(ids)} is not finite at t={self.fleet.t_s:.1f} s "
                               "(ground impact or loss of control)")

    def snapshot_part(self) -> WorldSnapshot:
        return WorldSnapshot() if self.fleet is None else self.fleet.snapshot_part()

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        """Counts, and ``rtf``: the run's real-time factor, simulated seconds per wall-clock second from
        the first tick to the end (every component's work included, JSBSim model loading excluded).
        Like ``wall_s`` it is a measurement of the machine, not of the scenario: it varies between
        otherwise identical runs."""
        wall_s = time.perf_counter() - self._wall_t0 if self._wall_t0 is not None else float("nan")
        rtf = self.fleet.t_s / wall_s if wall_s > 0.0 else float("nan")
        return {"aircraft": len(self.aircraft), "air_commands": self.commands_applied, "rtf": rtf}
