"""Monitors that read only the world snapshot (including the road backend's own collision report)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from corridor.analysis.ccd import MAX_STEP_M, Poses, _prev_rows, swept_overlaps
from corridor.analysis.safety import obb_overlap_pairs
from corridor.engine import Component, Metric, Phase, RunContext
from corridor.shards import Strips
from corridor.snapshot import Kind, Role

# plain ints: numpy compares an IntEnum member ~100x slower than an int (it probes the enum class)
_CAR, _TRUCK, _CONTROLLED = int(Kind.CAR), int(Kind.TRUCK), int(Role.CONTROLLED)


class CollisionMonitor(Component):
    """Counts collisions: each backend's own report (SUMO's) plus oriented-box overlap for every pair
    that a backend cannot see (an externally driven or non-road entity is involved).

    The box check is continuous (``corridor.analysis.ccd``): besides the overlap at the tick, boxes
    that met between the previous and this tick (closest approach of the straight-line motion) count,
    with the contact time inside the interval; a pair that overlaps at the tick keeps the tick's time.

    A road backend's report of a pair that involves a ``CONTROLLED`` row (an ego placed into SUMO with
    ``moveToXY``) is logged (``road_collision_report``) but not counted: SUMO checks vehicles on a lane
    as lane-aligned boxes (lane position minus length, lateral offset of the front bumper +- half the
    width), which is wrong for an ego standing at an angle to its lane (reversing into a bay: SUMO
    reported a stopped follower inside the ego while the real boxes were 0.9 m apart, issue 14).  Such
    pairs are decided by the oriented-box check, which sees every controlled row's real pose.

    A controlled road row that its backend still moves along its lanes (``RoadFrame.posed`` does not
    list it: SUMO vehicles whose speed a controller commands) is judged like every other SUMO driver,
    by SUMO's own report, not by boxes built from SUMO's drawn pose.  That pose is not the one SUMO's
    dynamics use: a vehicle that changes lanes at standstill while its rear still lies on the junction
    is drawn from its front on the new lane to its rear on the old lane's junction lane, across the
    lane between, and stays so while it stands (the merging sweep's one collision, issue 27: a
    commanded ramp car drawn at 56 deg for 8 s; a human in the same pose is never box-checked)."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('collisions', '1',
               "Pairs of entities whose footprints overlapped (SUMO's own report plus oriented-box overlap), each pair counted once.", safety_event=True),
        Metric('first_collision_s', 's',
               'Simulated time of the first collision (NaN: none).'),
    )
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.pairs: dict[tuple[str, str], float] = {}  # unordered pair -> first contact time [s]
        self._prev: Poses | None = None  # geometry of the previous tick's snapshot
        # role and kind arrays of the last tick with only backend-driven road rows (a road backend
        # publishes the same read-only arrays while its vehicles stay the same): no check needed
        self._plain: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        # role and kind arrays (read-only) of the last tick with a controlled row or an entity that is
        # not a car or truck, and whether every row was a car or a truck: a road backend publishes the
        # same arrays while its vehicles and the controlled ones stay the same
        self._codes: tuple[np.ndarray | None, np.ndarray | None, bool] = (None, None, False)
        self._strips: Strips | None = None  # a sharded run's regions (corridor.shards)
        self._how: dict[tuple[str, str], str] = {}  # a sharded run: how each pair was found
        self._prev_ids: np.ndarray | None = None  # a sharded run: the previous snapshot's ids array

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        prev, self._prev = self._prev, None
        if s.road is not None and s.road.events.collisions:
            controlled = {str(i) for i in s.ids[self._posed_rows(s)]}
            for t, a, v, kind in s.road.events.collisions:
                if a in controlled or v in controlled:  # decided by the exact box check below
                    ctx.events.emit(t, self.name, "road_collision_report",
                                    f"{a} x {v} [{s.road.source} ({kind}), lane-projected; not counted]", a=a, b=v)
                else:
                    self._add(ctx, t, a, v, f"{s.road.source} ({kind})")
        if len(s) < 2 or (s.role is self._plain[0] and s.kind is self._plain[1]):
            return  # the same (read-only) role and kind arrays as a tick that had no special row
        if s.role is self._codes[0] and s.kind is self._codes[1]:
            cars = self._codes[2]  # the same (read-only) arrays as the last tick with controlled rows
        else:
            cars = bool(np.maximum.reduce(s.kind) <= _TRUCK)  # every row a car or a truck (codes 0 and 1)
            if cars and np.maximum.reduce(s.role) < _CONTROLLED:
                self._plain = (s.role, s.kind)
                return  # only backend-driven road vehicles: their backend reports collisions
            if not (s.role.flags.writeable or s.kind.flags.writeable):
                self._codes = (s.role, s.kind, cars)
        road = s.road
        if cars and road is not None and road.posed == frozenset() and road.offset == 0 and len(road) == len(s):
            return  # every row a lane-driven road vehicle, none posed (a V2X run's speed-commanded ones, the
            #   special rows below are none): their backend reports collisions
        special = np.flatnonzero(self._posed_rows(s) | ((s.kind != _CAR) & (s.kind != _TRUCK)))
        if not len(special):
            return  # only lane-driven road vehicles (some speed-commanded): their backend reports collisions
        cur = Poses.of(s)
        if not _may_touch(prev, cur, special):  # no box of a special row can reach another's: nothing to find
            self._prev, self._prev_ids = cur, s.ids
            return
        part = (prev, cur, special)
        if ctx.shard is not None:  # a sharded run: the pairs with a special row in this rank's strip, on its rows near it
            part = self._local(ctx.shard, prev, cur, special, s.ids is self._prev_ids)
        with ctx.part(f"{self.name}.boxes"):
            self._boxes(ctx, *part)
        self._prev, self._prev_ids = cur, s.ids

    def _boxes(self, ctx: RunContext, prev: Poses | None, cur: Poses, special: np.ndarray) -> None:
        """The box checks of the pairs of ``cur`` with a row of ``special``: overlap now, or met since ``prev``."""
        ids = cur.ids
        pairs = obb_overlap_pairs(cur.position[:, :2], cur.heading, cur.size[:, 0], cur.size[:, 1],
                                  cur.position[:, 2], cur.size[:, 2], involving=special)
        now: set[tuple[int, int]] = set()
        for i, j in pairs.tolist():  # every pair has a special row
            now.add((i, j))
            self._add(ctx, ctx.t, str(ids[i]), str(ids[j]), "box overlap")
        if prev is not None and ctx.t > prev.t:
            for i, j, frac in zip(*swept_overlaps(prev, cur, special), strict=True):
                if (int(i), int(j)) not in now:
                    t_hit = prev.t + float(frac) * (ctx.t - prev.t)
                    self._add(ctx, t_hit, str(ids[i]), str(ids[j]), "box overlap between ticks")

    def _local(self, comm: Any, prev: Poses | None, cur: Poses, special: np.ndarray, same_ids: bool = False
               ) -> tuple[Poses | None, Poses, np.ndarray]:
        """This rank's part: the special rows in its strip, and the rows within reach of the strip
        (the largest two box radii plus twice the largest move since ``prev``: every partner of a
        pair with a row in the strip). Returns (prev, cur, special) restricted to those rows
        (``prev`` as is when its rows differ from ``cur``'s: matched by id). ``same_ids``: the snapshot's
        ids are the previous tick's array (published arrays are never written again), so the rows match."""
        x = cur.position[:, 0]
        if self._strips is None:
            self._strips = comm.strips or Strips(x, comm.size)
        same = prev is not None and (same_ids or (len(prev.ids) == len(cur.ids) and bool(np.all(prev.ids == cur.ids))))
        move = np.linalg.norm(cur.position - prev.position, axis=1) if same and prev is not None else np.zeros(len(x))
        step = float(move[move <= MAX_STEP_M].max(initial=0.0)) if same else MAX_STEP_M
        reach = float(np.linalg.norm(cur.size, axis=1).max()) + 2.0 * step + 1.0  # [m]
        rows = np.flatnonzero(self._strips.within(x, comm.rank, reach))
        owned = np.zeros(len(x), dtype=bool)
        owned[special] = True
        owned &= self._strips.within(x, comm.rank)
        sub = _rows(cur, rows)
        if same and prev is not None:  # the same ids row by row: one array for both
            prev = Poses(prev.t, sub.ids, prev.position[rows], prev.heading[rows], prev.size[rows])
        return prev, sub, np.flatnonzero(owned[rows])

    @staticmethod
    def _posed_rows(s: Any) -> np.ndarray:
        """Rows with role ``CONTROLLED`` whose pose is set from outside a road backend's lane dynamics
        (every controlled row, but the road rows its backend lists as only speed-commanded)."""
        ctrl = s.role == _CONTROLLED
        road = s.road
        if road is None or road.posed is None or not len(road):
            return ctrl
        rows = road.offset + np.flatnonzero(ctrl[road.sl])
        if not road.posed:  # no posed vehicle: every controlled road row is lane-driven
            ctrl[rows] = False
            return ctrl
        lane_driven = [k for k in rows.tolist() if str(s.ids[k]) not in road.posed]
        if lane_driven:
            ctrl[lane_driven] = False
        return ctrl

    def _own(self, comm: Any, s: Any, special: np.ndarray) -> np.ndarray:
        """The special rows in this rank's strip (a pair is found by a rank that owns one of its rows;
        ``finish`` takes the union over the ranks)."""
        if self._strips is None:
            self._strips = comm.strips or Strips(s.position[:, 0], comm.size)
        return special[self._strips.within(s.position[special, 0], comm.rank)]

    def _add(self, ctx: RunContext, t: float, a: str, b: str, how: str) -> None:
        key = (a, b) if a < b else (b, a)
        if key not in self.pairs:
            self.pairs[key] = t
            if ctx.shard is None:
                ctx.events.emit(t, self.name, "collision", f"{key[0]} x {key[1]} [{how}]", a=key[0], b=key[1])
            else:  # logged at the end, once the ranks agree on the first contact
                self._how[key] = how

    def _combine(self, ctx: RunContext) -> None:
        """A sharded run: the union of the ranks' pairs, each at its first contact, logged by every rank
        (the merged log keeps one)."""
        first: dict[tuple[str, str], tuple[float, str]] = {}
        for pairs, how in ctx.shard.allgather((self.pairs, self._how)):
            for key, t in pairs.items():
                if key not in first or t < first[key][0]:
                    first[key] = (t, how[key])
        self.pairs = {key: t for key, (t, _) in first.items()}
        for key, (t, how) in sorted(first.items(), key=lambda kv: kv[1][0]):
            ctx.events.emit(t, self.name, "collision", f"{key[0]} x {key[1]} [{how}]", a=key[0], b=key[1])

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        if ctx.shard is not None:
            self._combine(ctx)
        return {"collisions": len(self.pairs),
                "first_collision_s": min(self.pairs.values()) if self.pairs else np.nan}


_DENSE_PRECHECK_MAX = 20_000  # row pairs: above it _may_touch defers to the exact checks


def _rows(p: Poses, rows: np.ndarray) -> Poses:
    return Poses(p.t, p.ids[rows], p.position[rows], p.heading[rows], p.size[rows])


def _may_touch(prev: Poses | None, cur: Poses, rows: np.ndarray) -> bool:
    """False only if no pair with a row of ``rows`` can overlap now or have met since ``prev``.

    A necessary condition of both box checks: the pair's centres are now, in the plane, within the sum
    of their bounding-sphere radii (half the 3-D diagonal, at least the plane's) plus both
    displacements since ``prev`` (the closest approach of the swept check lies within them)."""
    n = len(cur.ids)
    if len(rows) * n > _DENSE_PRECHECK_MAX:
        return True  # a city fleet: the dense pre-check would cost more than the k-d tree checks it saves
    step = np.zeros(n)
    if prev is not None and len(prev.ids):
        pr = _prev_rows(prev.ids, cur.ids)
        seen = pr >= 0
        step[seen] = np.linalg.norm(cur.position[seen] - prev.position[pr[seen]], axis=1)
    reach = 0.5 * np.linalg.norm(cur.size, axis=1) + step  # [m]
    xy = cur.position[:, :2]
    d = np.linalg.norm(xy[rows][:, None, :] - xy[None, :, :], axis=-1)
    near = d <= (reach[rows][:, None] + reach[None, :]) * (1.0 + 1e-9) + 1e-6  # a margin for round-off
    near[np.arange(len(rows)), rows] = False  # a row and itself
    return bool(near.any())
