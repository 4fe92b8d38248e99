"""The parking controller on a SUMO street: search with side range sensors, then park in the slot found.

The ego is the ``ego_bicycle`` backend's car (SUMO routes and inserts it, corridor integrates it and
places it in SUMO every step, reversing allowed).  In ``search`` it drives along its lane at
``search_speed_mps`` while the right-hand sensors scan the bay row (beyond the kerb line of the
street's ``StreetParkingLandmarks``) and the slot detector accumulates evidence; once a slot long
enough (parallel) or wide enough (perpendicular) lies ``pass_m`` behind the rear axle, its goal pose is
announced (an event of kind ``goal``: the box centre and heading the ``parking`` monitor judges) and
the same ``ParkingManoeuvre`` as in the lot plans (corridor's planner) and follows the plan.

Planning obstacles: every other car of the snapshot at that moment (parked cars and stopped through
traffic), a wall beyond the bays' far edge and a wall along the street's centreline (parallel: the
manoeuvre may use the ego's lane and the next one) or one lane further (perpendicular).  A car
that moves into the remaining path later (a scene change) aborts and re-plans.  The ego's own state
comes from the ego backend (odometry, exact), the rest from the snapshot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.parking.clearance import box_polygons
from corridor.controllers.parking.manoeuvre import (
    Footprint,
    ManoeuvreParams,
    ParkingManoeuvre,
    ParkingObservation,
)
from corridor.controllers.parking.spot_detection import DetectorParams, Slot, SlotDetector
from corridor.controllers.parking.tracking import TrackingParams
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.traffic.networks.landmarks import StreetParkingLandmarks
from corridor.traffic.sumo.trips import road_frame
from corridor.vehicles.ground.ego_bicycle import EgoBicycle, EgoInput
from corridor.vehicles.sensors.range_sensors import RangeSensorParams, Scan, scan


class ParkingStreetController(Controller):
    """Searches a street's bay row for a free slot and parks the ``ego_bicycle`` car in it."""

    needs: ClassVar[dict[str, Need]] = {"ego": Need(role="ego", name_at="p.ego")}
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('final_mode', 'text',
               "The manoeuvre automaton's mode at the end (parked, abort, ...)."),
        Metric('replans', '1',
               'Re-plans during the run.'),
        Metric('aborts', '1',
               'Transitions to the abort mode.'),
        Metric('abort_reasons', 'text',
               "Why the manoeuvre aborted, '; '-separated."),
        Metric('plan_failures', '1',
               'Planner calls that found no path.'),
        Metric('plan_time_p50_s', 's',
               'Median planning wall time per call.'),
        Metric('plan_time_p95_s', 's',
               '95th percentile planning wall time per call.'),
        Metric('planned_direction_changes', '1',
               'Forward/reverse switches of the last plan (-1: no plan).'),
        Metric('slot_found_s', 's',
               'Time the controller chose a slot (NaN: never).'),
        Metric('mode_transitions', '1',
               'Transitions of the manoeuvre automaton.'),
    )
    period_source: ClassVar[str | None] = "p.period_s"
    ego: EgoBicycle

    class Params(BaseModel):
        model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

        ego: str = "ego"  # the EgoBicycle backend component
        period_s: float = Field(0.1, gt=0.0)  # [s]
        search_speed_mps: float = Field(3.0, gt=0.0)  # [m/s]
        pass_m: float = Field(1.0, ge=0.0)  # [m] the slot's end this far behind the rear axle: stop, plan
        margin_m: float = Field(0.25, ge=0.0, le=1.0)  # [m] footprint inflation given to the planner
        slot_margin_m: float = Field(0.5, ge=0.0)  # [m] free length/width beyond the car's a slot needs
        max_steer_rad: float = Field(0.6, gt=0.0)  # [rad] planned
        max_speed_mps: float = Field(1.5, gt=0.0)  # [m/s] planned
        cruise_mps: float = Field(1.5, gt=0.0)  # [m/s] tracking speed limit
        max_replans: int = Field(20, ge=0)  # a follower may stand behind the ego until it changes lanes
        sensors: RangeSensorParams = Field(default_factory=lambda: RangeSensorParams(sides=(-1,)))

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.man: ParkingManoeuvre | None = None
        self.detector: SlotDetector | None = None
        self.last_scan: Scan | None = None
        self.goal: np.ndarray | None = None
        self.slot: Slot | None = None

    def setup(self, ctx: RunContext) -> None:
        marks = road_frame(ctx).tables.landmarks
        if not isinstance(marks, StreetParkingLandmarks):
            raise ValueError(f"{self.name}: parking_street needs the parking_street network, not {marks.kind!r}")
        self.marks = marks
        super().setup(ctx)
        b = self.ego.p.bicycle
        self.fp = Footprint(b.length_m, b.width_m, 0.5 * b.wheelbase_m)
        tp = TrackingParams(wheelbase_m=b.wheelbase_m, max_steer_rad=min(b.steer_max_rad, 0.7),
                            max_accel_mps2=1.5, cruise_mps=self.p.cruise_mps)
        mp = ManoeuvreParams(tracking=tp, search_speed_mps=self.p.search_speed_mps, max_replans=self.p.max_replans)
        self.man = ParkingManoeuvre(mp, self.fp, self._plan, ctx.events, name=self.name)
        m = marks
        self.perpendicular = m.layout == "perpendicular"
        need = b.width_m + 2 * self.p.slot_margin_m if self.perpendicular else b.length_m + 2 * self.p.slot_margin_m
        start = m.bay_x[0] - 0.5 * m.bay_length_m
        self.detector = SlotDetector(np.array([start, m.kerb_y]), np.array([1.0, 0.0]), -1,
                                     len(m.bay_x) * m.bay_length_m,
                                     DetectorParams(parallel_length_m=need, perpendicular_width_m=need,
                                                    probe_m=min(2.0, m.bay_depth_m)))

    # ------------------------------------------------------------------ planning
    def _plan(self, start: np.ndarray, goal: np.ndarray, obstacles: Sequence[np.ndarray]) -> Any:
        from corridor.controllers.parking.geometry import VehicleGeometry
        from corridor.controllers.parking.planner import plan

        p, b, m = self.p, self.ego.p.bicycle, self.marks
        hang = 0.5 * (b.length_m - b.wheelbase_m) + p.margin_m
        veh = VehicleGeometry(wheelbase_m=b.wheelbase_m, front_hang_m=hang, rear_hang_m=hang,
                              width_m=b.width_m + 2 * p.margin_m, max_steer_rad=p.max_steer_rad,
                              max_speed_mps=p.max_speed_mps, max_accel_mps2=1.0, max_steer_rate_rps=1.0)
        x0, x1 = float(start[0]) - 40.0, float(start[0]) + 20.0
        far = m.kerb_y - m.bay_depth_m - 0.25  # [m] centre of the wall beyond the bays
        # the manoeuvre may use the ego's lane and the next one (perpendicular: two more)
        top = m.east_lane_y + (2.5 if self.perpendicular else 1.5) * m.lane_width_m + 0.25
        walls = box_polygons(np.array([[0.5 * (x0 + x1), far], [0.5 * (x0 + x1), top]]), np.zeros(2),
                             np.full(2, x1 - x0), np.full(2, 0.5))
        return plan(start, goal, [*obstacles, *walls], veh, dt_s=0.1,
                    bounds=(x0, x1, far, top))

    def _choose(self, rear_x: float, t: float) -> None:
        """The first slot (in driving order) whose end lies ``pass_m`` behind the rear axle: its goal."""
        assert self.detector is not None
        m = self.marks
        kind = "perpendicular" if self.perpendicular else "parallel"
        for s in self.detector.slots(kind):
            x0, x1 = self.detector.origin[0] + s.s0_m, self.detector.origin[0] + s.s1_m
            if x1 > rear_x - self.p.pass_m:
                continue
            need = self.detector.p.parallel_length_m
            cx = x0 + 0.5 * min(x1 - x0, need + 1.0) if not self.perpendicular else 0.5 * (x0 + x1)
            h = 0.5 * math.pi if self.perpendicular else 0.0  # perpendicular: reversed in, facing the street
            cy = m.kerb_y - 0.5 * m.bay_depth_m if self.perpendicular else m.bay_y + 0.2
            d = np.array([math.cos(h), math.sin(h)])
            self.goal = np.array([cx - self.fp.rear_to_centre_m * d[0], cy - self.fp.rear_to_centre_m * d[1], h])
            self.slot = s
            self.events.emit(t, self.name, "goal", f"slot [{x0:.1f}, {x1:.1f}] m: park at ({cx:.1f}, {cy:.1f})",
                             x=cx, y=cy, heading=h, s0=x0, s1=x1)
            return

    # ------------------------------------------------------------------ observe / step
    def observe(self, ctx: RunContext) -> ParkingObservation | None:
        if not self.ego.active or self.man is None:
            return None
        x, y, yaw, v = (float(a) for a in self.ego.state)
        s = ctx.snapshot
        others = np.flatnonzero(s.ids != self.ego.vid)
        polys = box_polygons(s.position[others, :2], s.heading[others], s.size[others, 0], s.size[others, 1])
        pose = np.array([x, y, yaw])
        self.last_scan = scan(self.p.sensors, pose, polys, self.rng)
        if self.goal is None and self.detector is not None:
            self.detector.add(self.last_scan.origin, self.last_scan.axis, self.last_scan.range_m,
                              self.p.sensors.max_range_m)
            self._choose(x, ctx.t)
        bay = None
        if self.goal is not None:
            c = self.goal[:2] + self.fp.rear_to_centre_m * np.array([math.cos(self.goal[2]), math.sin(self.goal[2])])
            bay = box_polygons(c, np.array([self.goal[2]]), np.array([self.fp.length_m + 1.0]),
                               np.array([self.fp.width_m + 0.6]))[0]
        return ParkingObservation(ctx.t, pose, v, self.goal, bay, tuple(str(i) for i in s.ids[others]), polys)

    def step(self, obs: ParkingObservation | None) -> list[Any]:
        if obs is None or self.man is None:
            return []
        accel, steer = self.man.step(obs)
        return [EgoInput(self.ego.vid, accel, steer)]

    def overlays(self) -> dict[str, tuple[str, Any]]:
        sc = self.last_scan
        if sc is None:
            return {}
        reach = np.where(np.isfinite(sc.range_m), sc.range_m, sc.max_range_m)
        return {"sensors/beams": ("lines", [np.vstack([o, o + r * a]) for o, a, r in zip(sc.origin, sc.axis, reach)]),
                "sensors/echoes": ("points", sc.hits)}

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        m, det = self.man, self.detector
        if det is not None:
            found = det.slots("perpendicular" if self.perpendicular else "parallel")
            ctx.events.emit(ctx.t, self.name, "slots", f"{len(found)} slots detected", origin=det.origin.tolist(),
                            direction=det.direction.tolist(), side=det.side, extent=det.observed_extent(),
                            slots=[(f.s0_m, f.s1_m) for f in found], need_m=det.p.parallel_length_m,
                            band_m=(0.0, self.marks.bay_depth_m))
        if m is None:
            return {"final_mode": "none"}
        last = m.plans[-1] if m.plans else None
        return {
            **m.metrics(),
            "planned_direction_changes": int(last.direction_changes()) if last is not None else -1,
            "slot_found_s": next((h[0] for h in m.ha.history if h[2] == "slot_found"), math.nan),
            "mode_transitions": len(m.ha.history),
        }
