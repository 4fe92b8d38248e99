"""The SUMO backend (libsumo): builds the network and demand, steps SUMO, reads state by
subscriptions into the world snapshot, applies external-control commands.

libsumo allows one simulation per process; the batch runner gives each run its own process.
SUMO x/y [m] are used as the scenario's local ENU east/north (the generated networks are planar).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from corridor.engine import Backend, RunContext
from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.traffic import commands as cmd
from corridor.traffic.demand import FlowDef, VehicleTypeDef, write_routes
from corridor.traffic.network import BuiltNetwork, build_network
from corridor.traffic.road_spec import RoadSpec

_VARS: tuple[int, ...] = ()  # filled at first start (libsumo constants)


def sumo_binary() -> str:
    import sumo

    return str(Path(sumo.SUMO_HOME) / "bin" / "sumo")


@dataclass
class VehicleInfo:
    """Static facts of one vehicle, taken once when it departs."""

    flow: str
    route: str
    role: int
    connected: bool
    length: float  # [m]
    width: float  # [m]
    depart_s: float
    depart_delay_s: float
    freeflow_s: float  # free-flow travel time of its route at its desired speed
    speed_factor: float = 1.0  # its multiplier of the speed limit (the driver's desired speed)
    max_speed: float = math.inf  # [m/s] its vehicle type's top speed
    arrive_s: float = math.nan


def vtype_attrs(vt: Any) -> dict[str, str | float]:
    attrs: dict[str, str | float] = {
        "carFollowModel": vt.car_following, "accel": vt.accel, "decel": vt.decel,
        "emergencyDecel": vt.emergency_decel, "sigma": vt.sigma, "tau": vt.tau, "length": vt.length,
        "width": vt.width, "minGap": vt.min_gap, "maxSpeed": vt.max_speed, "speedFactor": vt.speed_factor,
        "speedDev": vt.speed_dev,
    }
    attrs.update(vt.lc)
    attrs.update(vt.extra)
    return attrs


def yaw_from_sumo_angle(angle_deg: np.ndarray) -> np.ndarray:
    """SUMO angle: degrees clockwise from north -> ENU yaw: radians counter-clockwise from east."""
    return np.radians(90.0 - np.asarray(angle_deg, dtype=float))


class SumoBackend(Backend):
    """Road traffic in SUMO.  Exposes lane-frame arrays aligned with its snapshot rows for road
    monitors (``uid``, ``lane_id``, ``lane_code``, ``lane_pos``, ``accel``) and per-vehicle facts in
    ``info``; ``n_uids`` is the number of vehicles departed so far.

    SUMO-side modules (detectors, ramp meters) may use ``libsumo`` (the module, valid between setup
    and close) for reads, and send writes as commands with an ``apply_to_sumo(libsumo)`` method."""

    Params = RoadSpec  # ``backends.road.params`` (or the ``road:`` shorthand)

    def __init__(self, name: str, params: RoadSpec, scenario: Any, network: BuiltNetwork | None = None,
                 cache_dir: Path | None = None) -> None:
        super().__init__(name)
        self.scenario = scenario
        self.road = params
        self.period = self.road.sumo.step_length
        self.net = network or build_network(self.road.network.type, self.road.network.params, cache_dir)
        self.info: dict[str, VehicleInfo] = {}
        self.active: list[str] = []
        self.controlled: set[str] = set()
        self._lc_mode0: dict[str, int] = {}  # original lane-change modes of vehicles a controller changed
        self.collisions: list[tuple[float, str, str, str]] = []  # (t, collider, victim, type)
        self.new_collisions: list[tuple[float, str, str, str]] = []
        self.teleports: list[tuple[float, str]] = []
        self.commands_ignored = 0
        # called right before each simulationStep: externally integrated vehicles (the ego bicycle)
        # place themselves here, so SUMO moves everyone to the same time instant
        self.pre_step: list[Callable[[RunContext], None]] = []
        self._part = WorldSnapshot()
        # per-vehicle integer ids (uid: order of departure) index static per-uid arrays, so monitors
        # can keep vectorised per-vehicle state (np arrays indexed by uid) instead of Python sets
        self._uid_of: dict[str, int] = {}
        self._length, self._width = np.zeros(0), np.zeros(0)
        self._role = np.zeros(0, dtype=np.int8)
        self._lane_codes: dict[str, int] = {}
        self.uid = np.zeros(0, dtype=np.int64)
        self.lane_id = np.zeros(0, dtype=object)
        self.lane_code = np.zeros(0, dtype=np.int64)  # small integer per lane id
        self.lane_pos = np.zeros(0)
        self.accel = np.zeros(0)
        self._started = False

    # ------------------------------------------------------------------ set-up
    def setup(self, ctx: RunContext) -> None:
        import libsumo

        self._ls = self.libsumo = libsumo
        self._rng = ctx.rng("sumo.demand")  # the stream's name predates the backend entry's name (road)
        self._flow_of = {fid: fl for fid, fl in self.road.demand.flows.items()}
        routes_file = self._write_demand(ctx)
        seed = int(np.random.SeedSequence(ctx.run_seed, spawn_key=(7,)).generate_state(1)[0] % 2**31)
        libsumo.start(self._args(routes_file, seed, ctx.duration))
        self._started = True
        self._vars = (libsumo.VAR_POSITION, libsumo.VAR_SPEED, libsumo.VAR_ANGLE,
                      libsumo.VAR_ACCELERATION, libsumo.VAR_LANE_ID, libsumo.VAR_LANEPOSITION)
        libsumo.simulation.subscribe([libsumo.VAR_DEPARTED_VEHICLES_IDS, libsumo.VAR_ARRIVED_VEHICLES_IDS,
                                      libsumo.VAR_TELEPORT_STARTING_VEHICLES_IDS])
        self._route_ff = {r: self._route_lanes(edges) for r, edges in self.net.routes.items()}

    def _write_demand(self, ctx: RunContext) -> Path:
        d = self.road.demand
        vtypes = [VehicleTypeDef(n, vtype_attrs(vt)) for n, vt in d.vehicle_types.items()]
        flows = [FlowDef(fid, fl.route, fl.vtype, fl.rate_profile(ctx.duration, d.scale),
                         depart_lane=fl.depart_lane, depart_speed=fl.depart_speed, arrivals=fl.arrivals)
                 for fid, fl in d.flows.items()]
        for fl in flows:
            if fl.route not in self.net.routes:
                raise ValueError(f"road.demand.flows.{fl.id}.route: unknown route {fl.route!r}; "
                                 f"the network has {', '.join(sorted(self.net.routes))}")
        return write_routes(Path(ctx.workdir) / "routes.rou.xml", self.net.routes, vtypes, flows, ctx.duration)

    def _args(self, routes_file: Path, seed: int, duration: float) -> list[str]:
        o = self.road.sumo
        args = [sumo_binary(), "-n", str(self.net.net_file), "-r", str(routes_file),
                "--step-length", f"{o.step_length}", "--seed", str(seed), "--end", f"{duration}",
                "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
                "--collision.action", o.collision_action, "--collision.mingap-factor", "0",
                "--collision.check-junctions", str(o.collision_check_junctions).lower(),
                "--time-to-teleport", f"{o.time_to_teleport}"]
        if self.net.additional_files:
            args += ["-a", ",".join(str(p) for p in self.net.additional_files)]
        return args + list(o.extra_args)

    def _route_lanes(self, edges: tuple[str, ...]) -> list[tuple[float, float]]:
        """(length [m], speed limit [m/s]) of each edge of a route (first lane)."""
        lane = self._ls.lane
        return [(lane.getLength(f"{e}_0"), lane.getMaxSpeed(f"{e}_0")) for e in edges]

    # ------------------------------------------------------------------ the tick
    def tick(self, ctx: RunContext) -> None:
        ls = self._ls
        for hook in self.pre_step:
            hook(ctx)
        ls.simulationStep()
        t = ls.simulation.getTime()
        sim = ls.simulation.getSubscriptionResults()
        for vid in sim.get(ls.VAR_DEPARTED_VEHICLES_IDS, ()):
            self._on_depart(vid, t)
        for vid in sim.get(ls.VAR_ARRIVED_VEHICLES_IDS, ()):
            if vid in self.info:
                self.info[vid].arrive_s = t
            self.controlled.discard(vid)
        for vid in sim.get(ls.VAR_TELEPORT_STARTING_VEHICLES_IDS, ()):
            self.teleports.append((t, vid))
            ctx.events.emit(t, self.name, "teleport", f"{vid} teleported (jam or stuck merge)", vid=vid)
        self.new_collisions = [(t, c.collider, c.victim, c.type) for c in ls.simulation.getCollisions()]
        self.collisions.extend(self.new_collisions)
        self._read_state(ls.vehicle.getAllSubscriptionResults())

    def _on_depart(self, vid: str, t: float) -> None:
        ls = self._ls
        ls.vehicle.subscribe(vid, self._vars)
        flow = vid.split(".", 1)[0]  # vehicle ids are <flow>.<step>.<n> (flow names have no dots)
        spec = self._flow_of.get(flow)
        route = spec.route if spec else ls.vehicle.getRouteID(vid)
        vt = self.road.demand.vehicle_types[spec.vtype] if spec else None
        connected = bool(spec and self._rng.random() < spec.connected_share)
        desired = ls.vehicle.getSpeedFactor(vid)
        vmax = vt.max_speed if vt else 50.0
        ff = sum(length / min(vmax, lim * desired) for length, lim in self._route_ff.get(route, []))
        info = VehicleInfo(
            flow=flow, route=route, role=int(Role.RAMP if route == "ramp" else Role.MAINLINE),
            connected=connected, length=vt.length if vt else ls.vehicle.getLength(vid),
            width=vt.width if vt else ls.vehicle.getWidth(vid),  # vehicles added by id, not by a flow
            depart_s=t, depart_delay_s=ls.vehicle.getDepartDelay(vid), freeflow_s=ff,
            speed_factor=desired, max_speed=vmax)
        self.info[vid] = info
        k = self._uid_of[vid] = len(self._uid_of)
        if k >= len(self._length):  # grow the per-uid static arrays geometrically
            grow = max(256, len(self._length))
            self._length = np.concatenate([self._length, np.zeros(grow)])
            self._width = np.concatenate([self._width, np.zeros(grow)])
            self._role = np.concatenate([self._role, np.zeros(grow, dtype=np.int8)])
        self._length[k], self._width[k], self._role[k] = info.length, info.width, info.role

    def _read_state(self, res: dict[str, dict[int, Any]]) -> None:
        ls = self._ls
        ids = list(res)
        n = len(ids)
        self.active = ids
        if n == 0:
            self._part = WorldSnapshot()
            self.uid = np.zeros(0, dtype=np.int64)
            self.lane_id, self.lane_pos, self.accel = np.zeros(0, dtype=object), np.zeros(0), np.zeros(0)
            self.lane_code = np.zeros(0, dtype=np.int64)
            return
        rows = list(res.values())
        P, S, A, ACC, LP = ls.VAR_POSITION, ls.VAR_SPEED, ls.VAR_ANGLE, ls.VAR_ACCELERATION, ls.VAR_LANEPOSITION
        num = np.array([(*r[P], r[S], r[A], r[ACC], r[LP]) for r in rows], dtype=float)  # one pass
        lanes = [r[ls.VAR_LANE_ID] for r in rows]
        uidx = self._uid_of
        uid = np.fromiter((uidx[v] for v in ids), dtype=np.int64, count=n)
        speed, yaw = num[:, 2], yaw_from_sumo_angle(num[:, 3])
        length, width = self._length[uid], self._width[uid]
        cos, sin = np.cos(yaw), np.sin(yaw)
        pos = np.zeros((n, 3))
        pos[:, 0] = num[:, 0] - 0.5 * length * cos  # SUMO reports the front bumper; store the centre
        pos[:, 1] = num[:, 1] - 0.5 * length * sin
        vel = np.zeros((n, 3))
        vel[:, 0], vel[:, 1] = speed * cos, speed * sin
        role = self._role[uid].copy()
        if self.controlled:
            role[[k for k, v in enumerate(ids) if v in self.controlled]] = Role.CONTROLLED
        self._part = WorldSnapshot(
            t=0.0, ids=np.array(ids, dtype=object), kind=np.full(n, Kind.CAR, dtype=np.int8), role=role,
            position=pos, velocity=vel, heading=yaw, size=np.column_stack([length, width, np.full(n, 1.5)]))
        self.uid = uid
        self.lane_id = np.array(lanes, dtype=object)
        codes = self._lane_codes
        self.lane_code = np.fromiter((codes.setdefault(ln, len(codes)) for ln in lanes), dtype=np.int64, count=n)
        self.lane_pos = num[:, 5]
        self.accel = num[:, 4]

    def snapshot_part(self) -> WorldSnapshot:
        return self._part

    @property
    def n_uids(self) -> int:
        return len(self._uid_of)

    # ------------------------------------------------------------------ commands
    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        v = self._ls.vehicle
        live = set(self.active)
        for c in commands:
            if hasattr(c, "apply_to_sumo"):  # commands of other SUMO-side modules (ramp meters, ...)
                c.apply_to_sumo(self._ls)
                continue
            vid = getattr(c, "vid", None)
            if vid is None or not isinstance(c, cmd.SetSpeed | cmd.SetAccel | cmd.ChangeLane |
                                                 cmd.MoveToXY | cmd.Release | cmd.SetLaneChangeMode):
                continue
            if vid not in live:
                self.commands_ignored += 1
                continue
            if isinstance(c, cmd.Release):
                v.setSpeed(vid, -1)
                v.setSpeedMode(vid, 31)
                if vid in self._lc_mode0:
                    v.setLaneChangeMode(vid, self._lc_mode0.pop(vid))
                self.controlled.discard(vid)
                continue
            if isinstance(c, cmd.SetLaneChangeMode):
                self._lc_mode0.setdefault(vid, v.getLaneChangeMode(vid))
                v.setLaneChangeMode(vid, c.mode)
                continue
            self.controlled.add(vid)
            if isinstance(c, cmd.SetSpeed):
                if c.speed_mode is not None:
                    v.setSpeedMode(vid, c.speed_mode)
                v.setSpeed(vid, max(0.0, c.speed_mps))
            elif isinstance(c, cmd.SetAccel):
                if c.speed_mode is not None:
                    v.setSpeedMode(vid, c.speed_mode)
                v.setAcceleration(vid, c.accel_mps2, c.duration_s)
            elif isinstance(c, cmd.ChangeLane):
                v.changeLane(vid, c.lane_index, c.duration_s)
            elif isinstance(c, cmd.MoveToXY):
                v.setSpeed(vid, max(0.0, c.speed_mps))
                v.moveToXY(vid, c.edge, c.lane, c.x, c.y, 90.0 - math.degrees(c.yaw_rad), c.keep_route)

    # ------------------------------------------------------------------ metrics
    def _measured(self, warmup_s: float) -> list[tuple[str, VehicleInfo]]:
        """Vehicles that departed after the warm-up and arrived (the ones metrics are taken over)."""
        return [(v, i) for v, i in self.info.items() if not math.isnan(i.arrive_s) and i.depart_s >= warmup_s]

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        arrived = self._measured(ctx.scenario.warmup)
        return {
            "vehicles_departed": len(self.info),
            "vehicles_arrived": len([i for i in self.info.values() if not math.isnan(i.arrive_s)]),
            "vehicles_measured": len(arrived),
            "teleports": len(self.teleports),
            "merge_failures": sum(1 for _, vid in self.teleports
                                  if vid in self.info and self.info[vid].role == Role.RAMP),
        }

    def departed_uids(self, warmup_s: float, role: int) -> np.ndarray:
        """uids of the vehicles of ``role`` that departed after the warm-up (arrived or not)."""
        return np.array([self._uid_of[v] for v, i in self.info.items()
                         if i.depart_s >= warmup_s and i.role == role], dtype=np.int64)

    def measured_uids(self, warmup_s: float) -> np.ndarray:
        """uids of the vehicles that departed after the warm-up and arrived."""
        return np.array([self._uid_of[v] for v, _ in self._measured(warmup_s)], dtype=np.int64)

    def delays(self, warmup_s: float, unfinished: bool = False) -> dict[str, np.ndarray]:
        """Travel-time delay [s] (incl. insertion delay) per arrived vehicle, by role.

        ``unfinished``: also count, with their delay so far (a lower bound), the vehicles that
        entered the demand after the warm-up but had not arrived when the run ended — those still
        on the road (elapsed time minus the free-flow time of the distance covered) and those still
        waiting to be inserted (their insertion delay).  Without them a control that jams the road
        would look better the fewer vehicles it lets through.
        """
        out: dict[str, list[float]] = {"mainline": [], "ramp": []}
        for _, i in self._measured(warmup_s):
            d = (i.arrive_s - i.depart_s) + i.depart_delay_s - i.freeflow_s
            out["ramp" if i.role == Role.RAMP else "mainline"].append(d)
        if unfinished and self._started:
            for role, d in self._unfinished_delays(warmup_s):
                out[role].append(d)
        return {k: np.asarray(v) for k, v in out.items()}

    def _unfinished_delays(self, warmup_s: float) -> list[tuple[str, float]]:
        ls = self._ls
        t = ls.simulation.getTime()
        out = []
        for vid in self.active:
            i = self.info.get(vid)
            if i is None or i.depart_s < warmup_s or not math.isnan(i.arrive_s):
                continue
            route_len = sum(length for length, _ in self._route_ff.get(i.route, [])) or 1.0
            done = min(ls.vehicle.getDistance(vid) / route_len, 1.0)
            role = "ramp" if i.role == Role.RAMP else "mainline"
            out.append((role, (t - i.depart_s) + i.depart_delay_s - i.freeflow_s * done))
        for vid in ls.simulation.getPendingVehicles():
            wait = ls.vehicle.getDepartDelay(vid)
            if t - wait >= warmup_s:
                spec = self._flow_of.get(vid.split(".", 1)[0])
                out.append(("ramp" if spec is not None and spec.route == "ramp" else "mainline", wait))
        return out

    def backlog(self) -> int:
        """Vehicles due to depart that SUMO could not insert yet (the road at the origin is full)."""
        return len(self._ls.simulation.getPendingVehicles()) if self._started else 0

    def close(self) -> None:
        if self._started:
            self._ls.close()
            self._started = False
