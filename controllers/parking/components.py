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
measured by the ``parking`` monitor (``corridor.analysis.parking_monitor``).  ``finish`` returns the
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
from corridor.controllers.parking.tracking import TrackingParams
from corridor.engine import Controller, RunContext
from corridor.snapshot import WorldSnapshot
from corridor.vehicles.highway_env_parking import ParkingInput, ParkingLot


class ParkingLotController(Controller):
    """Parks the ego of a ``highway_env_parking`` lot in its goal bay (plan, then follow)."""

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
        plan_time_limit_s: float = Field(20.0, gt=0.0)  # [s] wall clock per planner call
        plan_dt_s: float = Field(0.1, gt=0.0, le=0.1)  # [s]
        cruise_mps: float = Field(2.0, gt=0.0)  # [m/s] tracking speed limit
        straighten_m: float = Field(3.0, ge=0.0)  # [m]
        stuck_s: float = Field(12.0, gt=0.0)  # [s]
        max_replans: int = Field(3, ge=0)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.man: ParkingManoeuvre | None = None
        self.lot: ParkingLot | None = None

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

    def _plan(self, start: np.ndarray, goal: np.ndarray, obstacles: Sequence[np.ndarray]) -> Any:
        from corridor.controllers.parking.geometry import VehicleGeometry
        from corridor.controllers.parking.planner import plan

        p, lot = self.p, self.lot
        assert lot is not None
        veh = VehicleGeometry(wheelbase_m=lot.wheelbase_m, front_hang_m=p.margin_m, rear_hang_m=p.margin_m,
                              width_m=lot.vehicle_width_m + 2.0 * p.margin_m, max_steer_rad=p.max_steer_rad,
                              max_speed_mps=p.max_speed_mps, max_accel_mps2=p.max_accel_mps2,
                              max_steer_rate_rps=p.max_steer_rate_rps)
        return plan(start, goal, obstacles, veh, time_limit_s=p.plan_time_limit_s, dt_s=p.plan_dt_s)

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
        return ParkingObservation(ctx.t, np.array([rear[0], rear[1], h]), v, self.goal_pose(lot),
                                  lot.bay_polygon(lot.goal_bay), tuple(str(i) for i in s.ids[others]), polys)

    def step(self, obs: ParkingObservation | None) -> list[Any]:
        if obs is None or self.man is None:
            return []
        accel, steer = self.man.step(obs)
        return [ParkingInput(self.p.ego, accel, steer)]

    # ------------------------------------------------------------------ metrics
    def finish(self, ctx: RunContext) -> dict[str, Any]:
        m = self.man
        if m is None:
            return {"final_mode": "none"}
        wall = np.asarray(m.plan_wall_s) if m.plan_wall_s else np.full(1, np.nan)
        last = m.plans[-1] if m.plans else None
        return {
            "final_mode": m.mode,
            "replans": m.replans,
            "aborts": sum(1 for h in m.ha.history if h[2] == "abort"),
            "abort_reasons": "; ".join(m.reasons),
            "plan_failures": m.plan_failures,
            "plan_time_p50_s": float(np.percentile(wall, 50)),
            "plan_time_p95_s": float(np.percentile(wall, 95)),
            "plan_time_max_s": float(np.max(wall)),
            "plan_search_s": float(getattr(last, "search_time_s", math.nan)) if last is not None else math.nan,
            "plan_optimise_s": float(getattr(last, "optimise_time_s", math.nan)) if last is not None else math.nan,
            "planned_direction_changes": int(last.direction_changes()) if last is not None else -1,
            "planned_length_m": float(last.length_m()) if last is not None else math.nan,
            "mode_transitions": len(m.ha.history),
        }
