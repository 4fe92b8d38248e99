"""The parking manoeuvre as a hybrid automaton (``corridor.modes``): modes, guards, and what each does.

Modes::

    search --slot known--> slot_found --plan--> position | reverse_in | straighten
    position <-> reverse_in   (at each cusp of the plan: the next segment's direction)
    position | reverse_in --last segment, in the bay--> straighten --at the goal, stopped--> parked
    position | reverse_in | straighten --path blocked / no progress--> abort
    slot_found | replan --no plan--> abort --stopped--> replan --plan--> position | ...

* ``search``: no slot yet (the vehicle creeps along at ``search_speed_mps``, e.g. past the parked cars
  while the spot detector looks); ``slot_found``: a goal pose is known, the planner runs once;
* ``position`` / ``reverse_in``: following a forward / reverse segment of the plan;
* ``straighten``: the last segment once the body is in the bay (or within ``straighten_m`` of its
  end): the final alignment; ``parked``: the last segment done (at the goal, standing);
* ``abort``: braking to a standstill because the remaining path is blocked by an obstacle that the
  plan did not know (a scene change) or because the car made no progress for ``stuck_s``; ``replan``:
  a new plan from the standing pose (at most ``max_replans``).

Every transition is an event (``kind="mode"``) of the run's log.  The algorithm imports no engine
code: the planner is a callable ``plan_fn(start, goal, obstacles) -> trajectory`` (raising on failure),
so it runs alone in tests.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from corridor.controllers.parking.clearance import box_polygons, clearances
from corridor.controllers.parking.tracking import (
    Segment,
    TrackingParams,
    segment_done,
    speed_command,
    split_segments,
    steer_command,
    track_errors,
)
from corridor.events import EventLog
from corridor.modes import HybridAutomaton, Transition

MODES = ("search", "slot_found", "position", "reverse_in", "straighten", "parked", "abort", "replan")
FOLLOW = ("position", "reverse_in", "straighten")


def inside_convex(point: np.ndarray, poly: np.ndarray) -> bool:
    """``point`` inside the counter-clockwise convex polygon ``poly`` (k, 2)."""
    e = np.roll(poly, -1, axis=0) - poly
    r = point - poly
    return bool(np.all(e[:, 0] * r[:, 1] - e[:, 1] * r[:, 0] >= 0.0))


@dataclass(frozen=True)
class Footprint:
    """The vehicle's box relative to its rear axle (the planner's and tracker's reference point)."""

    length_m: float
    width_m: float
    rear_to_centre_m: float  # [m] rear axle -> box centre, along the heading

    def polygon(self, pose: np.ndarray) -> np.ndarray:
        x, y, th = pose[:3]
        c = np.array([x + self.rear_to_centre_m * math.cos(th), y + self.rear_to_centre_m * math.sin(th)])
        return box_polygons(c, np.array([th]), np.array([self.length_m]), np.array([self.width_m]))[0]


@dataclass(frozen=True)
class ManoeuvreParams:
    tracking: TrackingParams = field(default_factory=TrackingParams)
    search_speed_mps: float = 0.0  # [m/s] creeping speed while searching
    straighten_m: float = 3.0  # [m] the last segment's final metres are "straighten" at the latest
    block_margin_m: float = 0.2  # [m] a new obstacle closer than this to the remaining path blocks it
    stuck_s: float = 12.0  # [s] no progress along a segment for this long: abort
    abort_wait_s: float = 1.0  # [s] standstill before re-planning
    max_replans: int = 3


@dataclass(frozen=True)
class ParkingObservation:
    """What the manoeuvre sees: time, rear-axle pose and signed speed, the goal (rear-axle pose; None
    while searching), the goal bay's polygon, the obstacles (ids and (m, 4, 2) polygons)."""

    t: float  # [s]
    pose: np.ndarray  # (x [m], y [m], theta [rad]) of the rear axle
    v_mps: float  # [m/s] signed (negative: reversing)
    goal: np.ndarray | None
    bay: np.ndarray | None  # (4, 2) goal bay polygon
    obstacle_ids: tuple[str, ...]
    obstacles: np.ndarray  # (m, 4, 2)


PlanFn = Callable[[np.ndarray, np.ndarray, Sequence[np.ndarray]], Any]


class ParkingManoeuvre:
    """``step(obs) -> (accel [m/s^2], steer [rad])`` through the modes above."""

    def __init__(self, params: ManoeuvreParams, footprint: Footprint, plan_fn: PlanFn,
                 events: EventLog | None = None, name: str = "parking") -> None:
        self.p, self.fp, self.plan_fn = params, footprint, plan_fn
        self.events, self.name = events, name
        self.ha = HybridAutomaton(name, MODES, "search", self._transitions())
        self.plans: list[Any] = []
        self.plan_wall_s: list[float] = []
        self.plan_failures = 0
        self.replans = 0
        self.reasons: list[str] = []
        self._reset_plan()

    def _reset_plan(self) -> None:
        self.segments: list[Segment] = []
        self.seg_k, self.hint = 0, 0
        self.plan_ok, self.plan_failed = False, False
        self.planned_ids: dict[str, np.ndarray] = {}
        self.blocked = False
        self._progress_t, self._best_left = 0.0, math.inf

    # ------------------------------------------------------------------ automaton
    def _transitions(self) -> list[Transition]:
        def to(mode: str) -> Callable[[dict[str, Any]], bool]:
            return lambda x: x["plan_ok"] and x["follow"] == mode

        def cusp(mode: str) -> Callable[[dict[str, Any]], bool]:
            return lambda x: x["follow"] == mode

        tr = [Transition("search", "slot_found", lambda x: x["slot_known"], "slot known")]
        for src in ("slot_found", "replan"):
            tr += [Transition(src, m, to(m), "plan ready") for m in FOLLOW]
            tr.append(Transition(src, "abort", lambda x: x["plan_failed"], "no plan"))
        for src in FOLLOW:
            tr.append(Transition(src, "abort", lambda x: x["blocked"], "path blocked"))
            tr.append(Transition(src, "abort", lambda x: x["stuck"], "no progress"))
        tr.append(Transition("straighten", "parked", lambda x: x["done"], "at the goal"))
        for src in ("position", "reverse_in"):
            tr += [Transition(src, m, cusp(m), "cusp" if m != "straighten" else "last segment")
                   for m in FOLLOW if m != src]
        tr.append(Transition("abort", "replan", lambda x: x["may_replan"], "standing"))
        return tr

    @property
    def mode(self) -> str:
        return self.ha.mode

    # ------------------------------------------------------------------ step
    def step(self, obs: ParkingObservation) -> tuple[float, float]:
        mode = self.ha.mode
        standing = abs(obs.v_mps) < self.p.tracking.stop_mps
        if mode in ("slot_found", "replan") and standing and not (self.plan_ok or self.plan_failed):
            self._plan(obs, replan=mode == "replan")  # from a standstill (the planner starts at rest)
        if mode in FOLLOW:
            self._advance(obs)
            self.blocked = self._is_blocked(obs)
        x = self._flags(obs)
        new, _ = self.ha.update(obs.t, x, self.events)
        if new != mode:
            self._on_enter(new, mode, obs)
        return self._act(new, obs)

    def _flags(self, obs: ParkingObservation) -> dict[str, Any]:
        last = bool(self.segments) and self.seg_k == len(self.segments) - 1
        done = bool(self.segments) and self.seg_k >= len(self.segments)
        return {
            "slot_known": obs.goal is not None,
            "plan_ok": self.plan_ok, "plan_failed": self.plan_failed,
            "follow": self._follow_mode(obs, last) if self.segments and not done else "",
            "blocked": self.blocked,
            "stuck": self.ha.mode in FOLLOW and obs.t - self._progress_t > self.p.stuck_s,
            "done": done,
            "may_replan": (abs(obs.v_mps) < self.p.tracking.stop_mps and self.replans < self.p.max_replans
                           and self.ha.time_in_mode(obs.t) >= self.p.abort_wait_s),
        }

    def _follow_mode(self, obs: ParkingObservation, last: bool) -> str:
        seg = self.segments[self.seg_k]
        if last:
            st = track_errors(seg, obs.pose, self.hint)
            in_bay = obs.bay is not None and inside_convex(self.fp.polygon(obs.pose).mean(axis=0), obs.bay)
            if in_bay or st.s_left_m <= self.p.straighten_m:
                return "straighten"
        return "position" if seg.direction > 0 else "reverse_in"

    def metrics(self) -> dict[str, Any]:
        """The run metrics every parking controller reports: final mode, re-plans, aborts and their
        reasons, planner failures and planning wall time [s] (p50 / p95 over the calls)."""
        wall = np.asarray(self.plan_wall_s) if self.plan_wall_s else np.full(1, np.nan)
        return {
            "final_mode": self.mode,
            "replans": self.replans,
            "aborts": sum(1 for h in self.ha.history if h[2] == "abort"),
            "abort_reasons": "; ".join(self.reasons),
            "plan_failures": self.plan_failures,
            "plan_time_p50_s": float(np.percentile(wall, 50)),
            "plan_time_p95_s": float(np.percentile(wall, 95)),
        }

    def _on_enter(self, new: str, old: str, obs: ParkingObservation) -> None:
        if new == "abort":
            self.reasons.append(self.ha.history[-1][3])
        if new in ("slot_found", "replan"):
            self._reset_plan()
        if new in FOLLOW and old in ("slot_found", "replan"):
            self._progress_t = obs.t

    # ------------------------------------------------------------------ planning
    def _plan(self, obs: ParkingObservation, replan: bool) -> None:
        if replan:
            self.replans += 1
        t0 = time.perf_counter()
        try:
            traj = self.plan_fn(np.asarray(obs.pose, dtype=float), np.asarray(obs.goal, dtype=float),
                                list(obs.obstacles))
        except Exception as exc:  # the planner's NoSolution (or a solver failure): abort, maybe re-plan
            self.plan_wall_s.append(time.perf_counter() - t0)
            self.plan_failures += 1
            self.plan_failed = True
            if self.events is not None:
                self.events.emit(obs.t, self.name, "plan", f"no plan: {str(exc).splitlines()[0][:120]}")
            return
        self.plan_wall_s.append(time.perf_counter() - t0)
        self.plans.append(traj)
        self.segments = split_segments(traj.x, traj.y, traj.theta, traj.v, traj.steer, self.p.tracking.wheelbase_m)
        self.seg_k, self.hint = 0, 0
        self.planned_ids = {i: o.mean(axis=0) for i, o in zip(obs.obstacle_ids, obs.obstacles)}
        self.plan_ok = bool(self.segments)
        self.plan_failed = not self.segments
        if self.events is not None:
            xy = np.column_stack([traj.x, traj.y])
            self.events.emit(obs.t, self.name, "plan", f"plan: {len(self.segments)} segments, "
                             f"{self.plan_wall_s[-1]:.2f} s", polyline=xy.tolist())

    def _is_blocked(self, obs: ParkingObservation) -> bool:
        """An obstacle the plan did not know (new, or moved by > 0.2 m) within ``block_margin_m`` of the
        footprint along the rest of the path."""
        new = [k for k, i in enumerate(obs.obstacle_ids)
               if i not in self.planned_ids or np.hypot(*(obs.obstacles[k].mean(axis=0) - self.planned_ids[i])) > 0.2]
        if not new or not self.segments or self.seg_k >= len(self.segments):
            return False
        polys = obs.obstacles[new]
        for j, seg in enumerate(self.segments[self.seg_k:]):
            start = self.hint if j == 0 else 0
            for k in range(start, len(seg.s), 3):
                pose = np.array([seg.xy[k, 0], seg.xy[k, 1], seg.theta[k]])
                if clearances(self.fp.polygon(pose), polys).min() < self.p.block_margin_m:
                    return True
        return False

    # ------------------------------------------------------------------ following
    def _advance(self, obs: ParkingObservation) -> None:
        if self.seg_k >= len(self.segments):
            return
        seg = self.segments[self.seg_k]
        st = track_errors(seg, obs.pose, self.hint)
        self.hint = st.index
        if st.s_left_m < self._best_left - 0.05:
            self._best_left, self._progress_t = st.s_left_m, obs.t
        if segment_done(st, obs.v_mps, self.p.tracking):
            self.seg_k, self.hint = self.seg_k + 1, 0
            self._best_left, self._progress_t = math.inf, obs.t

    def _act(self, mode: str, obs: ParkingObservation) -> tuple[float, float]:
        tp = self.p.tracking
        if mode in FOLLOW and self.seg_k < len(self.segments):
            seg = self.segments[self.seg_k]
            st = track_errors(seg, obs.pose, self.hint)
            clear = float(clearances(self.fp.polygon(obs.pose), obs.obstacles).min()) if len(obs.obstacles) else math.inf
            return speed_command(seg, st, obs.v_mps, clear, tp), steer_command(seg, st, tp)
        target = self.p.search_speed_mps if mode == "search" else 0.0
        return float(np.clip(tp.k_v * (target - obs.v_mps), -tp.max_accel_mps2, tp.max_accel_mps2)), 0.0
