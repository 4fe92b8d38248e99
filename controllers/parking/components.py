"""The parking controller in a run: the ``parking`` component around ``ParkingManoeuvre``.

Each period it reads the snapshot only: the ego's row (``ego``; the box centre, heading and velocity
give the rear-axle pose the plan and the tracker use), every other row as an obstacle polygon (parked
cars, walls, pedestrian-sized obstacles), and the lot's typed landmarks (``ParkingLot``: the goal bay
and the vehicle's geometry) from the road frame.  It puts a ``ParkingInput`` on the bus.

The planner is corridor's TPCAP planner (``corridor.controllers.parking.planner.plan``) with a
``VehicleGeometry`` matching the simulated car: highway-env's box is a bicycle of wheelbase = box
length whose rear axle is the rear edge of the box, so the planner gets wheelbase = length, both
overhangs = ``margin_m`` and width + 2 ``margin_m`` (the margin is the clearance the plan keeps).

It records no signal and judges nothing: success, pose error, clearance and manoeuvre time are
measured by the ``parking`` monitor (``corridor.analysis.monitoring.parking``).  ``finish`` returns the
controller's own figures (final mode, re-plans, aborts and why, planning time per call, planned
direction changes).
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
from corridor.controllers.parking.spot_detection import DetectorParams, SlotDetector
from corridor.controllers.parking.tracking import TrackingParams
from corridor.engine import Controller, Metric, RunContext
from corridor.snapshot import WorldSnapshot
from corridor.vehicles.ground.highway_env_parking import ParkingInput, ParkingLot
from corridor.vehicles.sensors.range_sensors import RangeSensorParams, Scan, scan


class ParkingLotController(Controller):
    """Parks the ego of a ``highway_env_parking`` lot in its goal bay (plan, then follow)."""

    metrics: ClassVar[tuple[Metric, ...]] = (
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
        Metric('plan_time_max_s', 's',
               'Longest planning wall time.'),
        Metric('plan_search_s', 's',
               'Search (hybrid A*) wall time of the last plan.'),
        Metric('plan_optimise_s', 's',
               'Optimisation (IPOPT) wall time of the last plan.'),
        Metric('planned_direction_changes', '1',
               'Forward/reverse switches of the last plan (-1: no plan).'),
        Metric('planned_length_m', 'm',
               'Length of the last plan.'),
        Metric('mode_transitions', '1',
               'Transitions of the manoeuvre automaton.'),
    )
    period_source: ClassVar[str | None] = "p.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

        ego: str = "ego"  # the ego's snapshot id
        period_s: float = Field(0.1, gt=0.0)  # [s]
        orientation: str = Field("nose_in", pattern="^(nose_in|reverse_in)$")  # highway-env's goal is nose-in
        margin_m: float = Field(0.3, ge=0.0, le=1.0)  # [m] footprint inflation given to the planner
        max_steer_rad: float = Field(0.7, gt=0.0)  # [rad] planned (the car's limit is pi/4: room to correct)
        max_speed_mps: float = Field(2.0, gt=0.0)  # [m/s] planned
        max_accel_mps2: float = Field(1.0, gt=0.0)  # [m/s^2] planned
        max_steer_rate_rps: float = Field(1.0, gt=0.0)  # [rad/s] planned
        plan_dt_s: float = Field(0.1, gt=0.0, le=0.1)  # [s]
        cruise_mps: float = Field(2.0, gt=0.0)  # [m/s] tracking speed limit
        straighten_m: float = Field(3.0, ge=0.0)  # [m]
        stuck_s: float = Field(12.0, gt=0.0)  # [s]
        max_replans: int = Field(3, ge=0)
        sensors: RangeSensorParams | None = None  # side-looking range sensors (None: none)
        slot_width_m: float = Field(2.8, gt=0.0)  # [m] free width a perpendicular slot needs

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.man: ParkingManoeuvre | None = None
        self.lot: ParkingLot | None = None
        self.detectors: list[SlotDetector] = []
        self.last_scan: Scan | None = None

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.man = None

    # ------------------------------------------------------------------ set-up on the first observation
    def _build(self, lot: ParkingLot) -> None:
        p = self.p
        self.lot = lot
        self.fp = Footprint(lot.vehicle_length_m, lot.vehicle_width_m, lot.rear_offset_m)
        tp = TrackingParams(wheelbase_m=lot.wheelbase_m, max_steer_rad=lot.max_steer_rad,
                            max_accel_mps2=min(1.5, lot.max_accel_mps2), cruise_mps=p.cruise_mps)
        mp = ManoeuvreParams(tracking=tp, straighten_m=p.straighten_m, stuck_s=p.stuck_s, max_replans=p.max_replans)
        self.man = ParkingManoeuvre(mp, self.fp, self._plan, self.events, name=self.name)
        if p.sensors is not None:
            self.detectors = [self._row_detector(lot, h) for h in sorted(set(np.round(lot.bay_heading, 6)))]

    def _row_detector(self, lot: ParkingLot, heading: float) -> SlotDetector:
        """A detector along the entry line of the row of bays with ``heading`` (pointing into the row)."""
        rows = np.flatnonzero(np.isclose(lot.bay_heading, heading, atol=1e-6))
        into = np.array([math.cos(heading), math.sin(heading)])
        along = np.array([into[1], -into[0]])
        s = lot.bay_centres[rows] @ along
        entry = lot.bay_centres[rows[np.argmin(s)]] - 0.5 * lot.bay_length_m * into
        origin = entry - 0.5 * lot.bay_width_m * along
        side = 1 if float(np.cross(along, into)) > 0 else -1
        length = float(s.max() - s.min()) + lot.bay_width_m
        return SlotDetector(origin, along, side, length, DetectorParams(perpendicular_width_m=self.p.slot_width_m))

    def _plan(self, start: np.ndarray, goal: np.ndarray, obstacles: Sequence[np.ndarray]) -> Any:
        from corridor.controllers.parking.geometry import VehicleGeometry
        from corridor.controllers.parking.planner import plan

        p, lot = self.p, self.lot
        assert lot is not None
        veh = VehicleGeometry(wheelbase_m=lot.wheelbase_m, front_hang_m=p.margin_m, rear_hang_m=p.margin_m,
                              width_m=lot.vehicle_width_m + 2.0 * p.margin_m, max_steer_rad=p.max_steer_rad,
                              max_speed_mps=p.max_speed_mps, max_accel_mps2=p.max_accel_mps2,
                              max_steer_rate_rps=p.max_steer_rate_rps)
        walls = np.vstack(lot.walls)  # the search area: inside the walls
        bounds = (float(walls[:, 0].min()), float(walls[:, 0].max()), float(walls[:, 1].min()), float(walls[:, 1].max()))
        return plan(start, goal, obstacles, veh, dt_s=p.plan_dt_s, bounds=bounds)

    # ------------------------------------------------------------------ observe / step
    def goal_pose(self, lot: ParkingLot) -> np.ndarray:
        """Rear-axle goal pose: the bay centre with the car's heading (nose-in or reversed in)."""
        h = lot.goal_heading + (0.0 if self.p.orientation == "nose_in" else math.pi)
        c = lot.goal_centre
        return np.array([c[0] - lot.rear_offset_m * math.cos(h), c[1] - lot.rear_offset_m * math.sin(h), h])

    def observe(self, ctx: RunContext) -> ParkingObservation | None:
        s: WorldSnapshot = ctx.snapshot
        if s.road is None or not isinstance(s.road.tables.landmarks, ParkingLot):
            return None
        rows = np.flatnonzero(s.ids == self.p.ego)
        if not len(rows):
            return None
        if self.man is None:
            self._build(s.road.tables.landmarks)
        lot = self.lot
        assert lot is not None
        k = int(rows[0])
        h = float(s.heading[k])
        d = np.array([math.cos(h), math.sin(h)])
        rear = s.position[k, :2] - lot.rear_offset_m * d
        v = float(s.velocity[k, :2] @ d)
        others = np.flatnonzero(s.ids != self.p.ego)
        polys = box_polygons(s.position[others, :2], s.heading[others], s.size[others, 0], s.size[others, 1])
        if self.p.sensors is not None:  # sensing: the sensors' echoes off every other box, with their errors
            self.last_scan = scan(self.p.sensors, np.array([rear[0], rear[1], h]), polys, self.rng)
            for det in self.detectors:
                det.add(self.last_scan.origin, self.last_scan.axis, self.last_scan.range_m, self.p.sensors.max_range_m)
        return ParkingObservation(ctx.t, np.array([rear[0], rear[1], h]), v, self.goal_pose(lot),
                                  lot.bay_polygon(lot.goal_bay), tuple(str(i) for i in s.ids[others]), polys)

    def step(self, obs: ParkingObservation | None) -> list[Any]:
        if obs is None or self.man is None:
            return []
        accel, steer = self.man.step(obs)
        return [ParkingInput(self.p.ego, accel, steer)]

    def overlays(self) -> dict[str, tuple[str, Any]]:
        """What a recorder may draw (name -> ("lines", [(k, 2)...]) or ("points", (n, 2))): the sensor
        beams of the last scan (to the echo, or to the maximum range) and the echoes."""
        sc = self.last_scan
        if sc is None:
            return {}
        reach = np.where(np.isfinite(sc.range_m), sc.range_m, sc.max_range_m)
        beams = [np.vstack([o, o + r * a]) for o, a, r in zip(sc.origin, sc.axis, reach)]
        return {"sensors/beams": ("lines", beams), "sensors/echoes": ("points", sc.hits)}

    def _report_slots(self, ctx: RunContext) -> None:
        """The detected slots per row as an event (the ``parking`` monitor scores them)."""
        for k, det in enumerate(self.detectors):
            ext = det.observed_extent()
            found = det.slots("perpendicular")
            ctx.events.emit(ctx.t, self.name, "slots", f"row {k}: {len(found)} slots detected",
                            origin=det.origin.tolist(), direction=det.direction.tolist(), side=det.side,
                            extent=ext, slots=[(f.s0_m, f.s1_m) for f in found], need_m=self.p.slot_width_m,
                            band_m=(0.0, self.lot.bay_length_m if self.lot else 0.0))

    # ------------------------------------------------------------------ metrics
    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._report_slots(ctx)
        m = self.man
        if m is None:
            return {"final_mode": "none"}
        last = m.plans[-1] if m.plans else None
        return {
            **m.metrics(),
            "plan_time_max_s": float(np.max(m.plan_wall_s)) if m.plan_wall_s else math.nan,
            "plan_search_s": float(getattr(last, "search_time_s", math.nan)) if last is not None else math.nan,
            "plan_optimise_s": float(getattr(last, "optimise_time_s", math.nan)) if last is not None else math.nan,
            "planned_direction_changes": int(last.direction_changes()) if last is not None else -1,
            "planned_length_m": float(last.length_m()) if last is not None else math.nan,
            "mode_transitions": len(m.ha.history),
        }
