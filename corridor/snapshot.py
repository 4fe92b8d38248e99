"""World snapshot: one struct-of-arrays view of every entity, in the scenario's local ENU frame.

Backends fill it each tick (``WorldSnapshot.from_parts`` concatenates their blocks); cross-domain
logic (collision checks between anything, a UAV counting cars below it) reads only this, vectorised.
A road backend adds a ``RoadFrame``: the lane frame of its rows, the run's growing static tables
(vehicles, lanes, routes, typed landmarks), the step's road events and its detector readings.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import Any

import numpy as np

from corridor.poses import ConcatGeometry, Geometry, PlanarPoses


class Kind(IntEnum):
    """Entity kinds; stored as int8 in ``WorldSnapshot.kind``."""

    CAR = 0
    TRUCK = 1
    UAV = 2
    AIRCRAFT = 3
    OBSTACLE = 4


class Role(IntEnum):
    """What an entity is doing in the scenario (colouring, metrics grouping)."""

    MAINLINE = 0
    RAMP = 1
    CONTROLLED = 2
    OTHER = 3


def _grow(a: np.ndarray, n: int, fill: float | int | bool = 0) -> np.ndarray:
    """``a`` with room for at least ``n`` rows (geometric growth, new rows ``fill``)."""
    if n <= len(a):
        return a
    extra = max(256, len(a), n - len(a))
    return np.concatenate([a, np.full(extra, fill, dtype=a.dtype)])


class RoadTables:
    """Per-run static facts of a road backend; they grow as vehicles depart and lanes are entered.

    * per vehicle, indexed by ``uid`` (the vehicle's index in departure order, 0, 1, ...): ``vehicle_ids``
      and arrays ``length`` [m], ``width`` [m], ``route`` (route code), ``role``, ``connected``,
      ``speed_factor`` (multiplier of the speed limit: the driver's desired speed), ``max_speed``
      [m/s], ``depart_s`` [s] and ``depart_delay_s`` [s] (insertion delay); the arrays have spare
      capacity, rows ``[:n_uids]`` are valid;
    * per lane code: ``lane_names`` and ``lane_speed_limit`` [m/s];
    * per route code: ``route_names`` and ``route_segments`` ((length [m], speed limit [m/s]) per
      segment, for free-flow times);
    * ``landmarks``: the network's typed landmarks (whatever model the road's builder returns).
    """

    def __init__(self, landmarks: Any = None) -> None:
        self.landmarks = landmarks
        self.vehicle_ids: list[str] = []
        self.uid_of: dict[str, int] = {}
        self.length, self.width = np.zeros(0), np.zeros(0)
        self.speed_factor, self.max_speed = np.zeros(0), np.zeros(0)
        self.depart_s, self.depart_delay_s = np.zeros(0), np.zeros(0)
        self.route = np.zeros(0, dtype=np.int64)
        self.role = np.zeros(0, dtype=np.int8)
        self.connected = np.zeros(0, dtype=bool)
        self.lane_names: list[str] = []
        self.lane_code_of: dict[str, int] = {}
        self.lane_speed_limit = np.zeros(0)
        self.route_names: list[str] = []
        self.route_code_of: dict[str, int] = {}
        self.route_segments: list[tuple[tuple[float, float], ...]] = []

    @property
    def n_uids(self) -> int:
        """How many vehicles (uids) the run has seen so far."""
        return len(self.vehicle_ids)

    @property
    def n_lanes(self) -> int:
        """How many lane codes the run has assigned so far."""
        return len(self.lane_names)

    def add_route(self, name: str, segments: tuple[tuple[float, float], ...] = ()) -> int:
        """Code of route ``name`` (added with its segments on first sight)."""
        code = self.route_code_of.get(name)
        if code is None:
            code = self.route_code_of[name] = len(self.route_names)
            self.route_names.append(name)
            self.route_segments.append(tuple(segments))
        return code

    def add_lane(self, name: str, speed_limit_mps: float) -> int:
        """Assign the next lane code to lane ``name`` with its speed limit [m/s]; returns the code."""
        code = self.lane_code_of[name] = len(self.lane_names)
        self.lane_names.append(name)
        self.lane_speed_limit = _grow(self.lane_speed_limit, code + 1, np.nan)
        self.lane_speed_limit[code] = speed_limit_mps
        return code

    def add_vehicle(self, vid: str, *, length: float, width: float, route: int, role: int, connected: bool,
                    speed_factor: float, max_speed: float, depart_s: float, depart_delay_s: float) -> int:
        """Append a departed vehicle; returns its uid."""
        k = self.uid_of[vid] = len(self.vehicle_ids)
        self.vehicle_ids.append(vid)
        if k >= len(self.length):
            n = k + 1
            self.length, self.width = _grow(self.length, n), _grow(self.width, n)
            self.speed_factor, self.max_speed = _grow(self.speed_factor, n), _grow(self.max_speed, n)
            self.depart_s, self.depart_delay_s = _grow(self.depart_s, n), _grow(self.depart_delay_s, n)
            self.route, self.role = _grow(self.route, n, -1), _grow(self.role, n)
            self.connected = _grow(self.connected, n, False)
        self.length[k], self.width[k], self.route[k], self.role[k] = length, width, route, role
        self.connected[k], self.speed_factor[k], self.max_speed[k] = connected, speed_factor, max_speed
        self.depart_s[k], self.depart_delay_s[k] = depart_s, depart_delay_s
        return k


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


# shared empty defaults (read-only: a step without events allocates nothing)
_NO_INTS, _NO_FLOATS, _NO_CODES = (_read_only(np.zeros(0, dtype=np.int64)), _read_only(np.zeros(0)),
                                   _read_only(np.zeros(0, dtype=np.int8)))


@dataclass
class RoadEvents:
    """What happened on the road during the backend's last step.

    ``departed`` / ``arrived`` / ``teleported``: uids; ``collisions``: the backend's own report,
    (t [s], collider id, victim id, type); ``pending_*``: vehicles due to depart that could not be
    inserted yet (the insertion backlog): ids, their wait so far [s], route code and role.
    """

    departed: np.ndarray = field(default_factory=lambda: _NO_INTS)
    arrived: np.ndarray = field(default_factory=lambda: _NO_INTS)
    teleported: np.ndarray = field(default_factory=lambda: _NO_INTS)
    collisions: tuple[tuple[float, str, str, str], ...] = ()
    pending_ids: tuple[str, ...] = ()
    pending_wait_s: np.ndarray = field(default_factory=lambda: _NO_FLOATS)
    pending_route: np.ndarray = field(default_factory=lambda: _NO_INTS)
    pending_role: np.ndarray = field(default_factory=lambda: _NO_CODES)

    @property
    def backlog(self) -> int:
        """Vehicles waiting to be inserted at this step."""
        return len(self.pending_ids)


@dataclass
class DetectorFrame:
    """Readings of the road's fixed detectors after the last step (the ones the network declares).

    Loops (``loop_ids``): vehicles, occupancy [%] and mean speed [m/s] (-1: nobody) of the last
    completed aggregation interval.  Lane areas (``area_ids``): vehicles and halting vehicles now.
    Watched edges: the ids of the vehicles on each, in the backend's order.
    """

    loop_ids: tuple[str, ...] = ()
    loop_count: np.ndarray = field(default_factory=lambda: np.zeros(0))
    loop_occupancy_pct: np.ndarray = field(default_factory=lambda: np.zeros(0))
    loop_speed_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    area_ids: tuple[str, ...] = ()
    area_vehicles: np.ndarray = field(default_factory=lambda: np.zeros(0))
    area_halting: np.ndarray = field(default_factory=lambda: np.zeros(0))
    edge_vehicles: dict[str, tuple[str, ...]] = field(default_factory=dict)
    loop_index: dict[str, int] = field(default_factory=dict)
    area_index: dict[str, int] = field(default_factory=dict)


@dataclass
class RoadFrame:
    """The lane frame of the road entities of a snapshot.

    It is aligned row by row with the snapshot rows ``offset .. offset + len(uid)`` (``rows`` / ``sl``).

    ``t`` is the road backend's own clock [s] (its reports carry it); ``uid`` indexes ``tables``;
    ``lane`` is a lane code; ``lane_pos`` [m] along the lane (front bumper); ``accel`` [m/s²];
    ``distance`` [m] driven since departure (a backend may fill it on the run's last step only, nan
    before: it is needed for the unfinished vehicles' delay at the end).
    """

    source: str
    tables: RoadTables
    t: float = 0.0
    uid: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lane: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lane_pos: np.ndarray = field(default_factory=lambda: np.zeros(0))
    accel: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    co2_mgps: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [mg/s] the backend's emission
    fuel_mgps: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [mg/s] model (empty: not read)
    events: RoadEvents = field(default_factory=RoadEvents)
    detectors: DetectorFrame | None = None
    offset: int = 0  # snapshot row of the first road entity
    # ids of the ``Role.CONTROLLED`` rows whose pose is set from outside the backend's lane dynamics
    # (SUMO: ``moveToXY``, the ego bicycle); the other controlled rows are only speed-commanded and the
    # backend still moves them along its lanes.  None: every controlled row is posed from outside
    posed: frozenset[str] | None = None

    def __len__(self) -> int:
        return int(self.uid.shape[0])

    @property
    def sl(self) -> slice:
        """The snapshot rows of the road entities (contiguous)."""
        return slice(self.offset, self.offset + len(self))

    @property
    def rows(self) -> np.ndarray:
        """The snapshot row indices of the road entities."""
        rows: np.ndarray = np.arange(self.offset, self.offset + len(self))
        return rows

    @property
    def route(self) -> np.ndarray:
        """Route code per row."""
        route: np.ndarray = self.tables.route[self.uid]
        return route

    @property
    def connected(self) -> np.ndarray:
        """Whether each row's vehicle is connected (V2X), per row."""
        connected: np.ndarray = self.tables.connected[self.uid]
        return connected


class WorldSnapshot:
    """Struct-of-arrays state of all entities at time ``t`` [s].

    position/velocity are ENU metres and m/s; heading is the yaw angle [rad] measured
    counter-clockwise from east (ENU convention); size is (length, width, height) [m].

    A backend may give the three geometry arrays as a lazy source instead (``poses``: a
    ``corridor.poses.PlanarPoses``): they are derived on first access and cached, so a tick whose
    consumers read only ids, sizes and the road frame never computes them.  Published arrays are
    never written again (the lazily derived ones are read-only).
    """

    __slots__ = ("t", "ids", "kind", "role", "size", "road", "_position", "_velocity", "_heading", "_poses")

    def __init__(self, t: float = 0.0, ids: np.ndarray | None = None, kind: np.ndarray | None = None,
                 role: np.ndarray | None = None, position: np.ndarray | None = None,
                 velocity: np.ndarray | None = None, heading: np.ndarray | None = None,
                 size: np.ndarray | None = None, road: RoadFrame | None = None, *,
                 poses: PlanarPoses | ConcatGeometry | None = None) -> None:
        self.t = t
        self.ids = np.zeros(0, dtype=object) if ids is None else ids
        self.kind = np.zeros(0, dtype=np.int8) if kind is None else kind
        self.role = np.zeros(0, dtype=np.int8) if role is None else role
        self.size = np.zeros((0, 3)) if size is None else size
        self.road = road  # the road entities' lane frame (at most one road backend)
        self._poses = poses
        if poses is not None:
            if position is not None or velocity is not None or heading is not None:
                raise ValueError("give the geometry as arrays or as a lazy source (poses), not both")
            self._position = self._velocity = self._heading = None
        else:
            self._position = np.zeros((0, 3)) if position is None else position
            self._velocity = np.zeros((0, 3)) if velocity is None else velocity
            self._heading = np.zeros(0) if heading is None else heading

    def _fill(self) -> None:
        self._position, self._velocity, self._heading = self._poses.geometry()  # type: ignore[union-attr]

    @property
    def position(self) -> np.ndarray:
        """(N, 3) [m] ENU centre positions."""
        if self._position is None:
            self._fill()
        return self._position  # type: ignore[return-value]

    @property
    def velocity(self) -> np.ndarray:
        """(N, 3) [m/s] ENU velocities."""
        if self._velocity is None:
            self._fill()
        return self._velocity  # type: ignore[return-value]

    @property
    def heading(self) -> np.ndarray:
        """(N,) [rad] yaw, counter-clockwise from east."""
        if self._heading is None:
            self._fill()
        return self._heading  # type: ignore[return-value]

    def geometry_source(self) -> Geometry | PlanarPoses | ConcatGeometry:
        """The geometry as arrays if derived (or given), else its lazy source (for ``from_parts``)."""
        if self._position is None:
            return self._poses  # type: ignore[return-value]
        return self._position, self.velocity, self.heading

    def pending_poses(self) -> list[PlanarPoses]:
        """The lazy pose sources whose geometry is not derived yet (for ``fill_geometry``)."""
        return [] if self._position is not None or self._poses is None else self._poses.pending()

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def __repr__(self) -> str:
        return f"WorldSnapshot(t={self.t}, rows={len(self)}, road={self.road is not None})"

    @property
    def speed(self) -> np.ndarray:
        """Horizontal speed [m/s]."""
        speed: np.ndarray = np.hypot(self.velocity[:, 0], self.velocity[:, 1])
        return speed

    def index(self) -> dict[str, int]:
        """Map id -> row (built on demand; cheap for the sizes of a tick)."""
        return {str(i): k for k, i in enumerate(self.ids)}

    def select(self, mask: np.ndarray) -> WorldSnapshot:
        """The rows of ``mask`` (without the road frame, whose rows would no longer be contiguous)."""
        return WorldSnapshot(
            self.t, self.ids[mask], self.kind[mask], self.role[mask], self.position[mask],
            self.velocity[mask], self.heading[mask], self.size[mask],
        )

    @staticmethod
    def from_parts(t: float, parts: list[WorldSnapshot]) -> WorldSnapshot:
        """Concatenate the backends' parts into the tick's snapshot at time ``t`` [s].

        The road frame (of at most one part) keeps pointing at its own rows (its ``offset`` moves by
        the rows of the parts before it).  The geometry stays lazy while a part's is.
        """
        parts = [p for p in parts if len(p) or p.road is not None]
        if not parts:
            return WorldSnapshot(t=t)
        if len(parts) == 1:
            p = parts[0]
            p.t = t
            return p
        road, offset = None, 0
        for p in parts:
            if p.road is not None:
                if road is not None:
                    raise ValueError("at most one road backend per run: two snapshot parts carry a road frame")
                road = replace(p.road, offset=offset + p.road.offset)
            offset += len(p)
        common: dict[str, Any] = {"t": t, "ids": np.concatenate([p.ids for p in parts]),
                  "kind": np.concatenate([p.kind for p in parts]), "role": np.concatenate([p.role for p in parts]),
                  "size": np.concatenate([p.size for p in parts]), "road": road}
        if any(p.pending_poses() for p in parts):
            return WorldSnapshot(**common, poses=ConcatGeometry([p.geometry_source() for p in parts]))
        return WorldSnapshot(
            **common,
            position=np.concatenate([p.position for p in parts]),
            velocity=np.concatenate([p.velocity for p in parts]),
            heading=np.concatenate([p.heading for p in parts]),
        )


def nearest_indices(pos: np.ndarray, idx: int, n: int) -> np.ndarray:
    """Rows of the ``n`` entities nearest to row ``idx`` of ``pos``, nearest first, ties in row order.

    Row ``idx`` itself and rows at a non-finite distance are left out.
    """
    rel = pos - pos[idx]
    d2 = np.einsum("kd,kd->k", rel, rel)
    d2[idx] = np.inf
    near = np.argsort(d2, kind="stable")[:n]
    out: np.ndarray = near[np.isfinite(d2[near])]
    return out


def fill_geometry(snapshots: Sequence[WorldSnapshot]) -> Geometry | None:
    """Derive the lazy geometry of many snapshots (a block of ticks) in one numpy pass.

    The values are those each snapshot would derive on its own (``PlanarPoses.fill_many``).

    Returns:
        The joint (position [m], velocity [m/s], heading [rad]) of all their rows, in order, when each
        snapshot was one pending ``PlanarPoses`` part; else None (read each snapshot's arrays).
    """
    pending = [s.pending_poses() for s in snapshots]
    joint = PlanarPoses.fill_many([q for p in pending for q in p])
    if joint is not None and all((len(p) == 1 and len(p[0]) == len(s)) or (not p and not len(s))
                                 for p, s in zip(pending, snapshots, strict=True)):
        return joint
    return None
