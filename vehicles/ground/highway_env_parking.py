"""highway-env's parking lot (``parking-v0``) as a corridor backend: its lot, its kinematics, its verdict.

The backend owns one ``highway_env.envs.parking_env.ParkingEnv`` (nothing else imports highway-env):
the lot of 2 x 14 bays (4 m wide, 8 m deep, both rows facing an aisle 20 m wide), the walls, the ego
at the lot centre with a random heading, a random goal bay and ``vehicles_count`` parked cars in
random bays, all drawn by highway-env itself from a seed derived from corridor's run seed (stream
``<name>``), so the same run seed gives the same lot.  Each period it applies the last
``ParkingInput`` (acceleration [m/s^2], steering [rad], mapped to highway-env's normalised
``ContinuousAction``) and runs ``env.step``: ``simulation_frequency_hz / policy_frequency_hz`` Euler
steps of highway-env's kinematic bicycle (centre of the box, slip angle ``beta = atan(tan(delta)/2)``,
``lf = lr = LENGTH / 2``).  That model is exactly a rear-point bicycle of wheelbase ``LENGTH`` whose
no-slip point is the rear edge of the box (``ParkingLot.wheelbase_m``; yaw rate ``v cos(beta)
tan(delta) / LENGTH``), which is how a planner must see it.

What the rest of corridor sees (no consumer touches highway-env):

* the snapshot: the ego (role ``CONTROLLED``), the parked cars, the walls and any pedestrian-sized
  obstacle (kind ``OBSTACLE``) as boxes; a ``RoadFrame`` whose ``tables.landmarks`` is the typed
  ``ParkingLot`` (bays, goal bay, walls, the vehicle's geometry), whose ``lane`` is the bay each
  vehicle stands in (-1: the aisle) and whose ``events.collisions`` are highway-env's own ``crashed``
  reports (the collision monitor counts them beside its box check);
* ``finish``: highway-env's own success criterion (``ParkingEnv._is_success``: weighted distance of
  the ego's position and heading to the goal, ``> -success_goal_reward``) at the end of the run
  (``he_success``) and whether it held at any step (``he_success_any``: when an RL episode ends).

A scene change for re-planning: with ``intruder_t_s`` a pedestrian-sized obstacle appears in the
aisle in front of the goal bay at that time (a highway-env ``Obstacle``, so highway-env checks it too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.engine import Backend, Metric, RunContext
from corridor.snapshot import Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot

EGO_ID = "ego"
HEIGHT_M = 1.5  # [m] box height of cars in the snapshot (highway-env is planar)


@dataclass(frozen=True)
class ParkingInput:
    """Longitudinal acceleration [m/s^2] and front steering angle [rad] of the lot's ego ``vid``."""

    vid: str
    accel_mps2: float
    steer_rad: float


@dataclass(frozen=True)
class ParkingLot:
    """The lot as typed landmarks (ENU metres = highway-env's x/y; headings in rad, CCW from x).

    Bays: centre, heading (pointing from the aisle into the bay: nose-in is highway-env's goal),
    length (depth) and width; ``occupied``: a parked car stood there at the start.  ``walls``: (4, 2)
    corner arrays.  The ego: ``vehicle_length_m`` x ``vehicle_width_m`` box, bicycle of wheelbase
    ``wheelbase_m`` with its no-slip point ``rear_offset_m`` behind the box centre, steering within
    ``max_steer_rad``, acceleration within ``max_accel_mps2``."""

    bay_centres: np.ndarray  # (n, 2) [m]
    bay_heading: np.ndarray  # (n,) [rad]
    bay_length_m: float
    bay_width_m: float
    occupied: np.ndarray  # (n,) bool
    goal_bay: int
    walls: tuple[np.ndarray, ...]
    vehicle_length_m: float
    vehicle_width_m: float
    wheelbase_m: float
    rear_offset_m: float
    max_steer_rad: float
    max_accel_mps2: float
    kind: str = "highway_env_parking_lot"
    lane_width_m: float = 4.0  # [m] = bay width (the Landmarks convention)

    @property
    def goal_centre(self) -> np.ndarray:
        return self.bay_centres[self.goal_bay]

    @property
    def goal_heading(self) -> float:
        return float(self.bay_heading[self.goal_bay])

    def bay_polygon(self, k: int) -> np.ndarray:
        return box_corners(self.bay_centres[k], float(self.bay_heading[k]), self.bay_length_m, self.bay_width_m)

    def outlines(self) -> dict[str, list[np.ndarray]]:
        """Polygons to draw (a recorder's view of the lot): every bay, the goal bay, the walls."""
        bays = [self.bay_polygon(k) for k in range(len(self.bay_centres))]
        return {"bays": bays, "goal_bay": [bays[self.goal_bay]], "walls": list(self.walls)}

    def bay_of(self, xy: np.ndarray) -> np.ndarray:
        """Bay index per point (-1: none), by the bays' rectangles."""
        xy = np.atleast_2d(xy)
        d = xy[:, None, :] - self.bay_centres[None, :, :]
        c, s = np.cos(self.bay_heading), np.sin(self.bay_heading)
        along, across = d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c
        inside = (np.abs(along) <= 0.5 * self.bay_length_m) & (np.abs(across) <= 0.5 * self.bay_width_m)
        return np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)


def box_corners(centre: np.ndarray, heading: float, length: float, width: float) -> np.ndarray:
    """(4, 2) corners of an oriented box, counter-clockwise."""
    c, s = math.cos(heading), math.sin(heading)
    local = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]) * [length, width]
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(centre, dtype=float)


class HighwayEnvParking(Backend):
    """highway-env's ``parking-v0`` lot driven by ``ParkingInput`` commands (see the module doc)."""

    provides: ClassVar[frozenset[str]] = frozenset({"road", "parking_lot"})
    period_source: ClassVar[str | None] = "period_s"
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('he_success', '1',
               "highway-env's own success criterion at the end of the run."),
        Metric('he_success_any', '1',
               "highway-env's success criterion met at any time."),
        Metric('he_success_first_s', 's',
               "First time highway-env's success criterion was met (NaN: never)."),
        Metric('he_crashed', '1',
               '1 if highway-env reported the ego crashed.', safety_event=True),
    )

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        vehicles_count: int = Field(10, ge=0, le=26)  # parked cars (highway-env's ``vehicles_count``)
        policy_frequency_hz: float = Field(10.0, gt=0.0, le=100.0)  # [Hz] commands (= 1 / period)
        simulation_frequency_hz: float = Field(20.0, gt=0.0, le=1000.0)  # [Hz] highway-env's Euler step
        success_goal_reward: float = Field(0.12, gt=0.0)  # highway-env's success threshold
        start_jitter_m: tuple[float, float] = (0.0, 0.0)  # [m] ego start moved by U(-jx, jx), U(-jy, jy)
        intruder_t_s: float | None = Field(None, ge=0.0)  # [s] a pedestrian-sized obstacle appears
        intruder_size_m: float = Field(0.6, gt=0.0, le=3.0)  # [m] its square side
        intruder_offset_m: tuple[float, float] = (2.0, 5.0)  # [m] lateral offset range from the bay axis

        @model_validator(mode="after")
        def _whole_substeps(self) -> HighwayEnvParking.Params:
            n = self.simulation_frequency_hz / self.policy_frequency_hz
            if abs(n - round(n)) > 1e-9 or round(n) < 1:
                raise ValueError("simulation_frequency_hz must be a whole multiple of policy_frequency_hz")
            return self

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.period_s = 1.0 / params.policy_frequency_hz
        self.env: Any = None
        self.lot: ParkingLot | None = None
        self.tables = RoadTables()
        self._u = np.zeros(2)
        self._collisions: list[tuple[float, str, str, str]] = []
        self._crashed_seen: set[str] = set()
        self.he_success = False
        self.he_success_any = False
        self.he_success_first_s = math.nan
        self._t = 0.0
        self._intruder: Any = None

    # ------------------------------------------------------------------ set-up
    def setup(self, ctx: RunContext) -> None:
        from highway_env.envs.parking_env import ParkingEnv

        p = self.p
        config = {"vehicles_count": p.vehicles_count, "policy_frequency": p.policy_frequency_hz,
                  "simulation_frequency": p.simulation_frequency_hz, "duration": 10.0 * ctx.duration + 10.0,
                  "success_goal_reward": p.success_goal_reward, "offscreen_rendering": True}
        self.env = ParkingEnv(config=config)
        seed = int(ctx.rng(self.name).integers(2**31 - 1))
        self.env.reset(seed=seed)
        self._rng = ctx.rng(f"{self.name}.intruder")
        jx, jy = p.start_jitter_m
        if jx > 0.0 or jy > 0.0:  # highway-env starts the ego at the lot centre: move it along the aisle
            start = ctx.rng(f"{self.name}.start")
            self.env.vehicle.position = self.env.vehicle.position + [start.uniform(-jx, jx), start.uniform(-jy, jy)]
        self.lot = self._read_lot()
        for v in [*self.env.road.vehicles, *self.env.road.objects]:  # parked cars and walls never move:
            v.check_collisions = v is self.env.vehicle  # no checks among them (the ego is checked against all)
        self.tables.landmarks = self.lot  # the static part handed out before setup holds these tables
        for k in range(len(self.lot.bay_centres)):
            self.tables.add_lane(f"bay{k}", 0.0)
        for v in self._vehicles():
            self.tables.add_vehicle(self._vid(v), length=float(v.LENGTH), width=float(v.WIDTH), route=-1,
                                    role=int(Role.CONTROLLED if v is self.env.vehicle else Role.OTHER),
                                    connected=v is self.env.vehicle, speed_factor=1.0, max_speed=float(v.MAX_SPEED),
                                    depart_s=0.0, depart_delay_s=0.0)

    def _vehicles(self) -> list[Any]:
        return list(self.env.road.vehicles)

    def _vid(self, v: Any) -> str:
        if v is self.env.vehicle:
            return EGO_ID
        return f"parked{self.env.road.vehicles.index(v)}"

    def _read_lot(self) -> ParkingLot:
        env = self.env
        lanes = env.road.network.lanes_list()
        ego = env.vehicle
        centres = np.array([lane.position(lane.length / 2, 0) for lane in lanes])
        heading = np.array([lane.heading for lane in lanes])
        goal = np.hypot(*(centres - ego.goal.position).T).argmin()
        walls = tuple(np.asarray(o.polygon()[:4]) for o in env.road.objects if o is not ego.goal)
        occ = np.zeros(len(lanes), dtype=bool)
        for v in env.road.vehicles:
            if v is not ego:
                occ[np.hypot(*(centres - v.position).T).argmin()] = True
        steer = float(env.action_type.steering_range[1])
        return ParkingLot(bay_centres=centres, bay_heading=heading, bay_length_m=float(lanes[0].length),
                          bay_width_m=float(lanes[0].width), occupied=occ, goal_bay=int(goal), walls=walls,
                          vehicle_length_m=float(ego.LENGTH), vehicle_width_m=float(ego.WIDTH),
                          wheelbase_m=float(ego.LENGTH), rear_offset_m=0.5 * float(ego.LENGTH),
                          max_steer_rad=steer, max_accel_mps2=float(env.action_type.acceleration_range[1]))

    # ------------------------------------------------------------------ the step
    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        for c in commands:
            if isinstance(c, ParkingInput) and c.vid == EGO_ID:
                self._u = np.array([c.accel_mps2, c.steer_rad], dtype=float)

    def tick(self, ctx: RunContext) -> None:
        at = self.env.action_type
        a_max, s_max = float(at.acceleration_range[1]), float(at.steering_range[1])
        action = np.clip([self._u[0] / a_max, self._u[1] / s_max], -1.0, 1.0)
        appeared = self._maybe_intruder(ctx)
        if appeared or not self._standstill():  # a new object is checked by highway-env at once
            self._env_step(action)
        self._t = ctx.t + self.period
        self.he_success = self.is_success()
        if self.he_success and not self.he_success_any:
            self.he_success_any, self.he_success_first_s = True, self._t
        self._collisions = []
        for v in self._vehicles():
            vid = self._vid(v)
            if v.crashed and vid not in self._crashed_seen and v is self.env.vehicle:
                self._crashed_seen.add(vid)
                self._collisions.append((self._t, vid, self._crash_partner(v), "highway-env crashed"))

    def is_success(self) -> bool:
        """highway-env's own criterion, ``ParkingEnv._is_success(achieved_goal, desired_goal)``, on the
        goal observation built as its ``KinematicsGoalObservation.observe`` builds it (the ego's and
        the goal's ``to_dict()`` features over the scales) without the pandas round trip."""
        ot = self.env.observation_type_parking
        v = self.env.vehicle
        ego, goal = v.to_dict(), v.goal.to_dict()
        achieved = np.array([ego[f] for f in ot.features], dtype=float) / ot.scales
        desired = np.array([goal[f] for f in ot.features], dtype=float) / ot.scales
        return bool(self.env._is_success(achieved, desired))

    def _standstill(self) -> bool:
        """Nothing would move this step: the ego stands (|v| < 1e-6 m/s) and is not told to accelerate
        by more than 1e-6 m/s over the step, and every other vehicle is parked.  The step is then not
        integrated (its motion would stay below a micrometre); a parked lot at the end of a run costs
        nothing."""
        v = self.env.vehicle
        return (abs(v.speed) < 1e-6 and abs(self._u[0]) * self.period < 1e-6 and not v.crashed
                and all(o.speed == 0.0 for o in self.env.road.vehicles))

    def _env_step(self, action: np.ndarray) -> None:
        """``AbstractEnv.step`` without what a run does not use (the reward, the RL observation and
        termination flags, rendering: four observations per step): the action, then the frames of
        ``road.act(); road.step(1 / simulation_frequency)``, as ``AbstractEnv._simulate`` does."""
        env = self.env
        env.time += 1.0 / env.config["policy_frequency"]
        env.action_type.act(action)
        frames = int(env.config["simulation_frequency"] // env.config["policy_frequency"])
        for _ in range(frames):
            env.road.act()
            env.road.step(1.0 / env.config["simulation_frequency"])
            env.steps += 1

    def _crash_partner(self, ego: Any) -> str:
        """The entity the ego touches (the nearest one), named as in the snapshot."""
        part = self.snapshot_part()
        d = np.hypot(*(part.position[:, :2] - ego.position).T)
        d[part.ids == EGO_ID] = np.inf
        return str(part.ids[int(np.argmin(d))])

    def _maybe_intruder(self, ctx: RunContext) -> bool:
        p = self.p
        if p.intruder_t_s is None or self._intruder is not None or ctx.t + 1e-9 < p.intruder_t_s:
            return False
        from highway_env.vehicle.objects import Obstacle

        lot = self.lot
        c, h = lot.goal_centre, lot.goal_heading
        aisle = c - (0.5 * lot.bay_length_m + 3.0) * np.array([math.cos(h), math.sin(h)])
        side = self._rng.choice([-1.0, 1.0]) * self._rng.uniform(*p.intruder_offset_m)
        pos = aisle + side * np.array([-math.sin(h), math.cos(h)])
        ob = Obstacle(self.env.road, pos)
        ob.LENGTH = ob.WIDTH = p.intruder_size_m
        ob.diagonal = math.sqrt(2.0) * p.intruder_size_m
        self.env.road.objects.append(ob)
        self._intruder = ob
        ctx.events.emit(ctx.t, self.name, "scene", f"a pedestrian-sized obstacle appears at "
                        f"({pos[0]:.1f}, {pos[1]:.1f})", x=float(pos[0]), y=float(pos[1]))
        return True

    # ------------------------------------------------------------------ snapshot
    def snapshot_part(self) -> WorldSnapshot:
        if self.env is None:
            return WorldSnapshot()
        vs = self._vehicles()
        lot = self.lot
        ids = [self._vid(v) for v in vs]
        pos = np.array([[*v.position, 0.0] for v in vs])
        vel = np.array([[*v.velocity, 0.0] for v in vs])
        hdg = np.array([v.heading for v in vs])
        size = np.array([[v.LENGTH, v.WIDTH, HEIGHT_M] for v in vs])
        kind = [Kind.CAR] * len(vs)
        role = [Role.CONTROLLED if v is self.env.vehicle else Role.OTHER for v in vs]
        obs = [o for o in self.env.road.objects if o is not self.env.vehicle.goal]
        for k, o in enumerate(obs):
            ids.append("intruder" if o is self._intruder else f"wall{k}")
            pos = np.vstack([pos, [*o.position, 0.0]])
            vel = np.vstack([vel, np.zeros(3)])
            hdg = np.append(hdg, o.heading)
            # highway-env's side walls reach into the end walls (0.5 m each end): cut 0.55 m off each
            # end of every wall's snapshot box, so walls do not collide with each other (the cut
            # pieces lie behind the other walls, out of the ego's reach)
            length = o.LENGTH if o is self._intruder else o.LENGTH - 1.1
            size = np.vstack([size, [length, o.WIDTH, HEIGHT_M if o is self._intruder else 1.0]])
            kind.append(Kind.OBSTACLE)
            role.append(Role.OTHER)
        n_v = len(vs)
        road = RoadFrame(source=self.name, tables=self.tables, t=self._t,
                         uid=np.arange(n_v, dtype=np.int64), lane=lot.bay_of(pos[:n_v, :2]).astype(np.int64),
                         lane_pos=np.zeros(n_v), accel=np.zeros(n_v), distance=np.full(n_v, np.nan),
                         events=RoadEvents(collisions=tuple(self._collisions)))
        # vehicles first: the road frame's rows are the first n_v rows of this part
        return WorldSnapshot(ids=np.array(ids, dtype=object), kind=np.array(kind, dtype=np.int8),
                             role=np.array(role, dtype=np.int8), position=pos, velocity=vel, heading=hdg,
                             size=size, road=road)

    def static_part(self) -> WorldSnapshot:
        return WorldSnapshot(road=RoadFrame(source=self.name, tables=self.tables))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"he_success": int(self.he_success), "he_success_any": int(self.he_success_any),
                "he_success_first_s": self.he_success_first_s, "he_crashed": int(bool(self._crashed_seen))}

    def metric_columns(self) -> frozenset[str]:
        return frozenset({"he_success", "he_success_any", "he_success_first_s", "he_crashed"})

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None
