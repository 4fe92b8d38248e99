"""The SUMO backend (libsumo): builds the network and demand, steps SUMO, reads state by
subscriptions into the world snapshot, applies external-control commands.

libsumo allows one simulation per process; the batch runner gives each run its own process.
SUMO x/y [m] are used as the scenario's local ENU east/north (the generated networks are planar; a
user's own network keeps its own x/y).  A user's own route files (``sumo_files``) are loaded as
they are, before the scenario's flows; SUMO's own output files (``road.sumo.outputs``) go to the
batch folder through ``RunContext.output_path``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from itertools import chain
from operator import itemgetter
from pathlib import Path, PurePosixPath
from typing import Any, ClassVar

import numpy as np

from corridor.engine import Backend, RunContext
from corridor.poses import PlanarPoses
from corridor.snapshot import DetectorFrame, Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot
from corridor.traffic.networks.registry import BuiltNetwork, build_network
from corridor.traffic.sumo import commands as cmd
from corridor.traffic.sumo.demand import FlowDef, VehicleTypeDef, write_routes
from corridor.traffic.sumo.road_spec import SUMO_OUTPUT_OPTIONS, RoadSpec

_CAR, _CONTROLLED = int(Kind.CAR), int(Role.CONTROLLED)  # plain ints for numpy (see _read_state)
_RAMP, _MAINLINE = int(Role.RAMP), int(Role.MAINLINE)
_OFF_NETWORK = -1e9  # [m] positions below this are SUMO's INVALID_DOUBLE_VALUE (-2**30)
_NO_UIDS = np.zeros(0, dtype=np.int64)
_NO_UIDS.flags.writeable = False
# the commands this backend executes itself (a tuple: ``A | B`` would build a union on every command)
_ROAD_COMMANDS = (cmd.SetSpeed, cmd.SetAccel, cmd.ChangeLane, cmd.MoveToXY, cmd.Release, cmd.SetLaneChangeMode)


@dataclass(frozen=True)
class _Rows:
    """Per-row arrays fixed by the list of vehicles (ids in SUMO's order); the arrays are read-only."""

    id_list: list[str]
    ids: np.ndarray
    uid: np.ndarray
    half_length: np.ndarray  # (N, 1) [m]
    size: np.ndarray
    role: np.ndarray
    kind: np.ndarray
    no_distance: np.ndarray

    def __post_init__(self) -> None:
        for a in (self.ids, self.uid, self.half_length, self.size, self.role, self.kind, self.no_distance):
            a.flags.writeable = False


_NO_ROWS = _Rows([], np.zeros(0, dtype=object), np.zeros(0, dtype=np.int64), np.zeros((0, 1)), np.zeros((0, 3)),
                 np.zeros(0, dtype=np.int8), np.zeros(0, dtype=np.int8), np.zeros(0))


def sumo_binary() -> str:
    import sumo

    return str(Path(sumo.SUMO_HOME) / "bin" / "sumo")


def sumo_seed(run_seed: int) -> int:
    """SUMO's ``--seed`` of a run (derived from the run seed)."""
    return int(np.random.SeedSequence(run_seed, spawn_key=(7,)).generate_state(1)[0] % 2**31)


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


def _uids(values: list[int]) -> np.ndarray:
    """An int64 array of uids (the shared empty one on most steps: no event)."""
    return np.array(values, dtype=np.int64) if values else _NO_UIDS


class SumoBackend(Backend):
    """Road traffic in SUMO.  Its snapshot part carries a ``RoadFrame``: the lane frame of its rows,
    the run's static tables (vehicles by uid, lanes, routes, the network's typed landmarks), the
    step's road events (departures, arrivals, teleports, SUMO's collision report, the insertion
    backlog) and the readings of the detectors the network declares.  Consumers read only that;
    writes are commands (those of other SUMO-side modules carry an ``apply_to_sumo(libsumo)`` method).

    Seam for backends that drive a SUMO vehicle themselves (the ego bicycle): ``pre_step`` hooks run
    right before each SUMO step and may ``apply`` ``apply_to_sumo`` commands (insert, place);
    ``vehicle_pose`` reads one vehicle's raw SUMO pose and ``mark_controlled`` makes its row
    ``Role.CONTROLLED``.  ``libsumo`` (valid between setup and close) is for tests only."""

    Params = RoadSpec  # ``backends.road.params`` (or the ``road:`` shorthand)
    # the engine adds these monitors (name: registered type) to every scenario with this backend:
    # trip bookkeeping (departures, arrivals, delays, backlog, teleports) is measured, not simulated
    required_monitors: ClassVar[dict[str, str]] = {"trips": "trips"}
    provides: ClassVar[frozenset[str]] = frozenset({"road"})
    period_source: ClassVar[str | None] = "road.sumo.step_length"  # [s] SUMO's step

    def __init__(self, name: str, params: RoadSpec, scenario: Any, network: BuiltNetwork | None = None,
                 cache_dir: Path | None = None) -> None:
        super().__init__(name)
        self.scenario = scenario
        self.road = params
        self.net = network or build_network(self.road.network.type, self.road.network.params, cache_dir)
        self.tables = RoadTables(self.net.landmarks)
        self.controlled: set[str] = set()
        # of those, the vehicles whose pose is set from outside SUMO's lane dynamics (moveToXY, the
        # ego bicycle): the others are only speed- or lane-commanded and SUMO still moves them along
        # its lanes (the collision monitor trusts SUMO's own check for them, as for every SUMO driver)
        self.posed: set[str] = set()
        self._lc_mode0: dict[str, int] = {}  # original lane-change modes of vehicles a controller changed
        self._speed_mode0: dict[str, int] = {}  # speed modes their vehicle types set at departure
        # the speed mode this backend last gave each vehicle: a command repeating it skips the libsumo call
        # (SUMO's setSpeedMode only sets the influencer's flags, so setting the same mode again changes nothing)
        self._speed_mode_set: dict[str, int] = {}
        self._ids: list[str] = []  # ids of the vehicles in the network after the last step
        # the rows whose id list is ``_ids`` (None: no vehicle), and the last set of those ids made (apply)
        self._ids_rows: _Rows | None = None
        self._live: tuple[_Rows | None, set[str]] = (None, set())
        self.commands_ignored = 0
        # called right before each simulationStep: externally integrated vehicles (the ego bicycle)
        # place themselves here, so SUMO moves everyone to the same time instant
        self.pre_step: list[Callable[[RunContext], None]] = []
        self._part = WorldSnapshot(road=RoadFrame(name, self.tables))
        self._rows = _NO_ROWS
        # the last role array with controlled rows, the rows and the controlled ids it was made for
        self._roles: tuple[_Rows, set[str], np.ndarray] = (_NO_ROWS, set(), _NO_ROWS.role)
        self._blank = False  # a vehicle was off-lane (lane id "") in the last step
        self._lanes: tuple[list[str], np.ndarray] = ([], np.zeros(0, dtype=np.int64))  # the last step's lane codes
        self._started = False

    # ------------------------------------------------------------------ set-up
    def setup(self, ctx: RunContext) -> None:
        import libsumo

        self._ls = self.libsumo = libsumo
        self._rng = ctx.rng("sumo.demand")  # the stream's name predates the backend entry's name (road)
        self._flow_of = {fid: fl for fid, fl in self.road.demand.flows.items()}
        routes_files = [*self.net.route_files, *self._write_demand(ctx)]
        libsumo.start(self._args(routes_files, sumo_seed(ctx.run_seed), ctx.duration) + self._output_args(ctx))
        self._started = True
        self._vars = (libsumo.VAR_POSITION, libsumo.VAR_SPEED, libsumo.VAR_ANGLE,
                      libsumo.VAR_ACCELERATION, libsumo.VAR_LANE_ID, libsumo.VAR_LANEPOSITION)
        self._read_vars = (libsumo.VAR_POSITION, libsumo.VAR_SPEED, libsumo.VAR_ANGLE, libsumo.VAR_ACCELERATION,
                           libsumo.VAR_LANEPOSITION, libsumo.VAR_LANE_ID)
        self._emission_vars = (libsumo.VAR_CO2EMISSION, libsumo.VAR_FUELCONSUMPTION) if self.road.sumo.emissions else ()
        self._vars += self._emission_vars
        every = round(self.period / ctx.dt)
        self._last_tick = ((round(ctx.duration / ctx.dt) - 1) // every) * every  # the run's last SUMO step
        self._sim_vars = (libsumo.VAR_DEPARTED_VEHICLES_IDS, libsumo.VAR_ARRIVED_VEHICLES_IDS,
                          libsumo.VAR_TELEPORT_STARTING_VEHICLES_IDS)
        libsumo.simulation.subscribe(list(self._sim_vars))
        # one getter per read variable (position, speed, angle, acceleration, lane position, lane id)
        self._getters = tuple(map(itemgetter, self._read_vars))
        for r, edges in self.net.routes.items():
            self.tables.add_route(r, tuple(self._route_lanes(edges)))
        self._subscribe_detectors()

    def _subscribe_detectors(self) -> None:
        """Subscribe the loops, lane areas and watched edges that the network's landmarks declare."""
        ls, lm = self._ls, self.tables.landmarks
        loops, areas, edges = lm.declared_detectors() if hasattr(lm, "declared_detectors") else ((), (), ())
        self._det: DetectorFrame | None = None  # None: nothing to read each step
        if loops or areas or edges:
            self._det = DetectorFrame(loop_ids=tuple(loops), area_ids=tuple(areas),
                                      loop_index={i: k for k, i in enumerate(loops)},
                                      area_index={i: k for k, i in enumerate(areas)})
        self._det_edges = tuple(edges)
        self._loop_vars = (ls.VAR_LAST_INTERVAL_NUMBER, ls.VAR_LAST_INTERVAL_OCCUPANCY, ls.VAR_LAST_INTERVAL_SPEED)
        self._area_vars = (ls.LAST_STEP_VEHICLE_NUMBER, ls.LAST_STEP_VEHICLE_HALTING_NUMBER)
        for i in loops:
            ls.inductionloop.subscribe(i, self._loop_vars)
        for i in areas:
            ls.lanearea.subscribe(i, self._area_vars)
        for e in edges:
            ls.edge.subscribe(e, (ls.LAST_STEP_VEHICLE_ID_LIST,))

    def _write_demand(self, ctx: RunContext) -> list[Path]:
        """The scenario's own demand as a route file (none when a user's route files carry it all)."""
        d = self.road.demand
        vtypes = [VehicleTypeDef(n, vtype_attrs(vt)) for n, vt in d.vehicle_types.items()]
        flows = [FlowDef(fid, fl.route, fl.vtype, fl.rate_profile(ctx.duration, d.scale),
                         depart_lane=fl.depart_lane, depart_speed=fl.depart_speed, arrivals=fl.arrivals)
                 for fid, fl in d.flows.items()]
        for fl in flows:
            if fl.route not in self.net.routes:
                raise ValueError(f"road.demand.flows.{fl.id}.route: unknown route {fl.route!r}; "
                                 f"the network has {', '.join(sorted(self.net.routes)) or 'no named route'}")
        routes: dict[str, tuple[str, ...]] = dict(self.net.routes)
        if self.net.user_files:  # the user's files declare the routes and types: only what the flows add
            if not flows:
                return []
            used = {fl.vtype for fl in flows}
            vtypes = [v for v in vtypes if v.id in used]
            routes = {}
        path = Path(ctx.workdir) / "routes.rou.xml"
        return [write_routes(path, routes, vtypes, flows, ctx.duration, known_routes=self.net.routes)]

    def _output_args(self, ctx: RunContext) -> list[str]:
        """SUMO's own output files the scenario asks for (``road.sumo.outputs``), written inside the
        batch folder as ``sumo/<run_id>/<kind>.xml`` (the run's scratch folder without one)."""
        args: list[str] = []
        for kind in self.road.sumo.outputs:
            path = str(ctx.output_path(PurePosixPath("sumo", ctx.run_id, f"{kind}.xml"), per_run=False))
            args += [*SUMO_OUTPUT_OPTIONS[kind], path]
        return args

    def _args(self, routes_files: list[Path], seed: int, duration: float) -> list[str]:
        o = self.road.sumo
        args = [sumo_binary(), "-n", str(self.net.net_file), "-r", ",".join(str(p) for p in routes_files),
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
        uid_of = self.tables.uid_of
        dep, arr, tel = self._sim_vars
        departed = [self._on_depart(vid, t) for vid in sim.get(dep, ())]
        arrived = []
        for vid in sim.get(arr, ()):
            if vid in uid_of:
                arrived.append(uid_of[vid])
            self.controlled.discard(vid)
            self.posed.discard(vid)
            self._speed_mode0.pop(vid, None)
            self._speed_mode_set.pop(vid, None)
        teleported = []
        for vid in sim.get(tel, ()):
            teleported.append(uid_of.get(vid, -1))
            ctx.events.emit(t, self.name, "teleport", f"{vid} teleported (jam or stuck merge)", vid=vid)
        hits = ls.simulation.getCollisions()
        events = RoadEvents(departed=_uids(departed), arrived=_uids(arrived), teleported=_uids(teleported),
                            collisions=tuple((t, c.collider, c.victim, c.type) for c in hits) if hits else ())
        self._pending(events)
        self._read_state(ls.vehicle.getAllSubscriptionResults(), t, events, final=ctx.tick == self._last_tick)

    def _pending(self, ev: RoadEvents) -> None:
        """Vehicles due to depart that SUMO could not insert yet (the road at the origin is full)."""
        ls = self._ls
        ids = tuple(ls.simulation.getPendingVehicles())
        if not ids:
            return
        n = len(ids)
        specs = [self._flow_of.get(vid.split(".", 1)[0]) for vid in ids]
        codes = self.tables.route_code_of
        ev.pending_ids = ids
        ev.pending_wait_s = np.fromiter((ls.vehicle.getDepartDelay(v) for v in ids), dtype=float, count=n)
        ev.pending_route = np.fromiter((codes.get(s.route, -1) if s else -1 for s in specs), dtype=np.int64, count=n)
        ev.pending_role = np.fromiter((_RAMP if s is not None and s.route == "ramp" else _MAINLINE
                                       for s in specs), dtype=np.int8, count=n)

    def _on_depart(self, vid: str, t: float) -> int:
        ls = self._ls
        ls.vehicle.subscribe(vid, self._vars)
        flow = vid.split(".", 1)[0]  # vehicle ids are <flow>.<step>.<n> (flow names have no dots)
        spec = self._flow_of.get(flow)
        route = spec.route if spec else ls.vehicle.getRouteID(vid)
        vt = self.road.demand.vehicle_types[spec.vtype] if spec else None
        connected = bool(spec and self._rng.random() < spec.connected_share)
        if vt is not None and vt.speed_mode is not None:
            ls.vehicle.setSpeedMode(vid, vt.speed_mode)
            self._speed_mode0[vid] = self._speed_mode_set[vid] = vt.speed_mode
        desired = ls.vehicle.getSpeedFactor(vid)
        max_speed = vt.max_speed if vt else 50.0
        if spec is None and self.net.user_files:  # a vehicle of the user's files: its own
            max_speed = ls.vehicle.getMaxSpeed(vid)  # type's top speed and route (free-flow time)
            if route not in self.tables.route_code_of:
                self.tables.add_route(route, tuple(self._route_lanes(tuple(ls.vehicle.getRoute(vid)))))
        return self.tables.add_vehicle(
            vid, length=vt.length if vt else ls.vehicle.getLength(vid),
            width=vt.width if vt else ls.vehicle.getWidth(vid),  # vehicles added by id, not by a flow
            route=self.tables.add_route(route), role=int(Role.RAMP if route == "ramp" else Role.MAINLINE),
            connected=connected, speed_factor=desired, max_speed=max_speed,
            depart_s=t, depart_delay_s=ls.vehicle.getDepartDelay(vid))

    def _new_lane(self, lane_id: str) -> int:
        # a parked vehicle (SUMO parking area) is on no lane: lane id "" with no speed limit
        return self.tables.add_lane(lane_id, self._ls.lane.getMaxSpeed(lane_id) if lane_id else float("nan"))

    def _read_detectors(self) -> DetectorFrame | None:
        d = self._det
        if d is None:
            return None
        ls = self._ls
        loops = ls.inductionloop.getAllSubscriptionResults()
        n_, occ_, spd_ = self._loop_vars
        lv = np.array([(loops[i][n_], loops[i][occ_], loops[i][spd_]) for i in d.loop_ids], dtype=float)
        areas = ls.lanearea.getAllSubscriptionResults()
        an, ah = self._area_vars
        av = np.array([(areas[i][an], areas[i][ah]) for i in d.area_ids], dtype=float)
        edges = ls.edge.getAllSubscriptionResults()
        ids_var = ls.LAST_STEP_VEHICLE_ID_LIST
        return DetectorFrame(
            loop_ids=d.loop_ids, loop_count=lv[:, 0], loop_occupancy_pct=lv[:, 1], loop_speed_mps=lv[:, 2],
            area_ids=d.area_ids, area_vehicles=av[:, 0], area_halting=av[:, 1],
            edge_vehicles={e: tuple(edges[e][ids_var]) for e in self._det_edges},
            loop_index=d.loop_index, area_index=d.area_index)

    def _read_state(self, res: dict[str, dict[int, Any]], t: float, events: RoadEvents, final: bool) -> None:
        """The step's subscription results -> this backend's snapshot part: one C-level pass per
        variable (``np.fromiter`` over ``map(itemgetter)``: no Python frame per row, 3x faster than one
        ``np.array`` over a list of row tuples), then whole-array numpy (plain-int role/kind codes:
        numpy compares IntEnum members ~100x slower)."""
        P, LN = self._read_vars[0], self._read_vars[5]  # position, lane id (the teleport check)
        g_pos, g_speed, g_angle, g_accel, g_lane_pos, g_lane = self._getters
        rows = res.values()
        lanes = list(map(g_lane, rows))
        # a teleporting vehicle still reports (lane '', position INVALID_DOUBLE_VALUE = -2**30): it is off
        # the road until SUMO re-inserts it.  A parked one (SUMO parking area) also has lane '' but a pose.
        blank, blank_before = "" in lanes, self._blank
        self._blank = blank
        if blank and any(not r[LN] and r[P][0] < _OFF_NETWORK for r in rows):
            res = {v: r for v, r in res.items() if r[LN] or r[P][0] >= _OFF_NETWORK}
            rows = res.values()
            lanes = list(map(g_lane, rows))
        ids = list(res)
        n = len(ids)
        self._ids = ids
        detectors = self._read_detectors()
        if n == 0:
            self._ids_rows = None
            self._part = WorldSnapshot(road=RoadFrame(self.name, self.tables, t=t, events=events, detectors=detectors))
            return
        front = np.fromiter(chain.from_iterable(map(g_pos, rows)), dtype=float, count=2 * n).reshape(n, 2)
        speed = np.fromiter(map(g_speed, rows), dtype=float, count=n)
        angle = np.fromiter(map(g_angle, rows), dtype=float, count=n)
        accel = np.fromiter(map(g_accel, rows), dtype=float, count=n)
        lane_pos = np.fromiter(map(g_lane_pos, rows), dtype=float, count=n)
        # the vehicles are those of the previous step unless one departed, arrived or teleported, or
        # a vehicle was off-lane (teleporting, parked) in either step: then the id lists are compared
        quiet = not (blank or blank_before or len(events.departed) or len(events.arrived) or len(events.teleported))
        same = self._same_rows(ids, quiet)
        self._ids_rows = same  # its id_list is ids, the same list or an equal one
        # odometers only on the run's last step (for the unfinished vehicles' delay so far): one more
        # subscribed variable every step would cost ~2 % of the kernel's throughput
        distance = np.array([self._ls.vehicle.getDistance(v) for v in ids]) if final else same.no_distance
        role = self._role(same) if self.controlled else same.role
        road = RoadFrame(self.name, self.tables, t=t, uid=same.uid, lane=self._lane_codes(lanes), lane_pos=lane_pos, accel=accel,
                         distance=distance, events=events, detectors=detectors,
                         posed=frozenset(self.posed) if self.posed else frozenset())
        if self._emission_vars:  # [mg/s] SUMO's emission model (HBEFA / PHEMlight of the vType's emissionClass)
            co2, fuel = (itemgetter(v) for v in self._emission_vars)
            road.co2_mgps = np.fromiter(map(co2, rows), dtype=float, count=n)
            road.fuel_mgps = np.fromiter(map(fuel, rows), dtype=float, count=n)
        # SUMO reports the front bumper and its angle (clockwise from north): centre, velocity and
        # ENU yaw are derived when a consumer first reads them (corridor.poses)
        self._part = WorldSnapshot(t=0.0, ids=same.ids, kind=same.kind, role=role, size=same.size, road=road,
                                   poses=PlanarPoses(front, angle, speed, same.half_length))

    def _role(self, same: _Rows) -> np.ndarray:
        """The rows' roles with the controlled vehicles' rows ``CONTROLLED`` (read-only): the previous
        step's array while the rows and the set of controlled ids stay the same (a set comparison in C,
        against a list, an index and a copy a step).  A vehicle enters the tables only by departing,
        which changes the rows, so the ids of the set that have a uid cannot change either."""
        rows, ids, role = self._roles
        if rows is same and ids == self.controlled:
            return role
        uid_of = self.tables.uid_of  # the rows of the controlled vehicles, by uid (one per id): no pass over the ids
        by_uid = np.zeros(len(self.tables.vehicle_ids), dtype=bool)
        by_uid[[uid_of[v] for v in self.controlled if v in uid_of]] = True
        role = same.role.copy()
        role[by_uid[same.uid]] = _CONTROLLED
        role.flags.writeable = False
        self._roles = (same, set(self.controlled), role)
        return role

    def _lane_codes(self, lanes: list[str]) -> np.ndarray:
        """Lane code per row (read-only; the previous step's array when no vehicle changed lanes)."""
        if lanes == self._lanes[0]:
            return self._lanes[1]
        codes = self.tables.lane_code_of
        try:
            lane = np.fromiter(map(codes.__getitem__, lanes), dtype=np.int64, count=len(lanes))
        except KeyError:  # a lane entered for the first time: code it (in order of appearance)
            for ln in lanes:
                if ln not in codes:
                    self._new_lane(ln)
            lane = np.fromiter(map(codes.__getitem__, lanes), dtype=np.int64, count=len(lanes))
        lane.flags.writeable = False
        self._lanes = (lanes, lane)
        return lane

    def _same_rows(self, ids: list[str], quiet: bool = False) -> _Rows:
        """The rows' arrays that depend only on which vehicles are on the road, in SUMO's order:
        rebuilt when that list changes (a departure, an arrival), else the previous step's (read-only).

        ``quiet``: no vehicle departed, arrived or teleported and none was off-lane in this or the
        previous step.  SUMO's subscription results are keyed by id in sorted order and a vehicle
        enters them only by departing (it is subscribed then) and leaves them only by arriving
        (every removal is reported as an arrival) or by a teleport (filtered out): the same number of
        ids is then the same list, and the comparison (~5 us a step for 300 ids) is skipped."""
        prev = self._rows.id_list
        if (quiet and len(ids) == len(prev)) or ids == prev:
            return self._rows
        tb, n = self.tables, len(ids)
        uid = np.fromiter(map(tb.uid_of.__getitem__, ids), dtype=np.int64, count=n)
        length = tb.length[uid]
        size = np.empty((n, 3))
        size[:, 0], size[:, 1], size[:, 2] = length, tb.width[uid], 1.5
        self._rows = _Rows(id_list=ids, ids=np.array(ids, dtype=object), uid=uid,
                           half_length=(0.5 * length)[:, None], size=size, role=tb.role[uid],
                           kind=np.full(n, _CAR, dtype=np.int8), no_distance=np.full(n, np.nan))
        return self._rows

    def snapshot_part(self) -> WorldSnapshot:
        return self._part

    def static_part(self) -> WorldSnapshot:
        return self._part

    # ------------------------------------------------------------------ seam for vehicle backends
    def vehicle_pose(self, vid: str) -> tuple[float, float, float, float]:
        """SUMO's own pose of ``vid`` now: front bumper x, y [m], SUMO angle [deg], speed [m/s]."""
        v = self._ls.vehicle
        x, y = v.getPosition(vid)
        return x, y, v.getAngle(vid), v.getSpeed(vid)

    def mark_controlled(self, vid: str) -> None:
        """Report ``vid`` as ``Role.CONTROLLED`` from the next snapshot on (an externally driven vehicle,
        its pose set from outside SUMO: ``RoadFrame.posed``)."""
        self.controlled.add(vid)
        self.posed.add(vid)

    # ------------------------------------------------------------------ commands
    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        v = self._ls.vehicle
        rows = self._ids_rows  # the ids as a set, made again when the rows change
        if rows is None:
            live = set(self._ids)
        elif rows is self._live[0]:
            live = self._live[1]
        else:
            live = set(rows.id_list)
            self._live = (rows, live)
        for c in commands:
            if hasattr(c, "apply_to_sumo"):  # commands of other SUMO-side modules (ramp meters, ...)
                c.apply_to_sumo(self._ls)
                continue
            vid = getattr(c, "vid", None)
            if vid is None or not isinstance(c, _ROAD_COMMANDS):
                continue
            if vid not in live:
                self.commands_ignored += 1
                continue
            if isinstance(c, cmd.Release):
                v.setSpeed(vid, -1)
                self._set_speed_mode(vid, self._speed_mode0.get(vid, 31))
                if vid in self._lc_mode0:
                    v.setLaneChangeMode(vid, self._lc_mode0.pop(vid))
                self.controlled.discard(vid)
                self.posed.discard(vid)
                continue
            if isinstance(c, cmd.SetLaneChangeMode):
                self._lc_mode0.setdefault(vid, v.getLaneChangeMode(vid))
                v.setLaneChangeMode(vid, c.mode)
                continue
            self.controlled.add(vid)
            if isinstance(c, cmd.SetSpeed):
                if c.speed_mode is not None:
                    self._set_speed_mode(vid, c.speed_mode)
                v.setSpeed(vid, max(0.0, c.speed_mps))
            elif isinstance(c, cmd.SetAccel):
                if c.speed_mode is not None:
                    self._set_speed_mode(vid, c.speed_mode)
                v.setAcceleration(vid, c.accel_mps2, c.duration_s)
            elif isinstance(c, cmd.ChangeLane):
                v.changeLane(vid, c.lane_index, c.duration_s)
            elif isinstance(c, cmd.MoveToXY):
                self.posed.add(vid)
                v.setSpeed(vid, max(0.0, c.speed_mps))
                v.moveToXY(vid, c.edge, c.lane, c.x, c.y, 90.0 - math.degrees(c.yaw_rad), c.keep_route)

    def _set_speed_mode(self, vid: str, mode: int) -> None:
        """``setSpeedMode`` unless this backend already gave ``vid`` that mode (the same flags either way)."""
        if self._speed_mode_set.get(vid) != mode:
            self._ls.vehicle.setSpeedMode(vid, mode)
            self._speed_mode_set[vid] = mode

    def close(self) -> None:
        if self._started:
            self._ls.close()
            self._started = False
