"""The signals the overtaking specs judge, measured by a monitor (``overtaking_safety``), not by the
controller under test: swapping the controller (``none``, a baseline) keeps them.

Every period while the ego is on the road it records, from the TRUE (noise-free) world in the road
frame of ``overtaking_mpc`` (x along the eastbound road, own lane centre y = 0, oncoming lane
y = +lane width): ``gap_lead`` / ``ahead_lead`` (bumper gap behind / ahead of the lead),
``lat_lead`` / ``lat_onc`` (lateral clearance to the own / oncoming lane's vehicle box), ``gap_onc``
(longitudinal clearance to the oncoming vehicles within ``range_m``), ``clearance`` (smallest hull gap
to ANY other vehicle, followers included: <= 0 on every contact the collision monitor can report),
``lane_offset`` (the ego's body centre y) and ``ego_speed``; ``finish`` gives ``min_gap_lead_m`` and
``min_gap_oncoming_m`` (the smallest bumper gap to the lead / an oncoming car while sharing its lane).

The lead is the geometry's: the nearest vehicle ahead in the own lane, kept after the ego passed it
until it is ``PASSED_FORGET_M`` behind (the controller used its own target while passing; on the
scenario's runs the two are the same vehicle).  The others come from the snapshot; the ego's pose is
the rear-axle state of the ego bicycle backend (exact; SUMO's row of the ego carries the same pose,
but a speed SUMO derives from the displacement).

It runs in *sense*, at the start of the tick, so it samples the world the controllers decide on (the
instants at which the controller recorded these signals before).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.overtaking.controller import box_clearance, safety_signals
from corridor.controllers.overtaking.mpc import FAR_M, RoadGeometry, body_centre
from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.networks.landmarks import RuralLandmarks
from corridor.traffic.sumo.trips import road_frame

PASSED_FORGET_M = 150.0  # [m] a passed lead this far behind is no longer "the lead" of the signals


class OvertakingSafety(Component):
    """Safety and completion signals of an ego overtaking on the rural two-lane road."""

    phase = Phase.SENSE
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('min_gap_lead_m', 'm',
               'Smallest bumper gap to the lead vehicle while sharing its lane.'),
        Metric('min_gap_oncoming_m', 'm',
               'Smallest gap to an oncoming vehicle while in the oncoming lane.'),
    )
    needs: ClassVar[dict[str, Need]] = {"ego": Need(role="ego", name_at="p.ego")}  # the ego bicycle backend
    period_source: ClassVar[str | None] = "p.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

        ego: str = "ego"  # name of the EgoBicycle backend component
        period_s: float = Field(0.2, gt=0.0)  # [s] sampling period
        range_m: float = Field(400.0, gt=0.0)  # [m] oncoming vehicles this close (along x) count
        other_length_m: float = Field(4.5, gt=0.0)  # [m] the box the lane signals assume for others
        other_width_m: float = Field(1.8, gt=0.0)  # [m]

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.lead_id: str | None = None
        self.min_gap_lead_m, self.min_gap_onc_m = math.inf, math.inf

    def setup(self, ctx: RunContext) -> None:
        ego = self.ego  # resolved by the engine (role "ego")
        marks = road_frame(ctx).tables.landmarks
        if not isinstance(marks, RuralLandmarks):
            raise ValueError(f"{self.name}: needs the rural two-lane road, not {marks.kind!r}")
        self.ego, self.vid, self.bike = ego, ego.vid, ego.p.bicycle
        self.lane_y = float(marks.east_lane_y)  # [m] ENU y of the own lane centre
        self.road = RoadGeometry(lane_width_m=abs(float(marks.opposite_lane_offset_m)),
                                 other_length_m=self.p.other_length_m, other_width_m=self.p.other_width_m)

    def _lead(self, ids: np.ndarray, x: np.ndarray, v: np.ndarray, xc: float) -> int | None:
        """Row (of the own-lane vehicles) of the lead: the one last seen ahead while it is less than
        ``PASSED_FORGET_M`` behind, else the nearest one ahead."""
        where = {str(i): k for k, i in enumerate(ids)}
        k = where.get(self.lead_id) if self.lead_id is not None else None
        if k is not None and x[k] > xc - PASSED_FORGET_M:
            return k
        ahead = np.flatnonzero((v >= 0.0) & (x > xc))
        if not len(ahead):
            return None
        k = int(ahead[np.argmin(x[ahead])])
        self.lead_id = str(ids[k])
        return k

    def tick(self, ctx: RunContext) -> None:
        if not self.ego.active:
            return
        s = ctx.snapshot
        x_e, y_e, yaw, v_e = self.ego.state
        ego = np.array([[x_e, y_e - self.lane_y, yaw, v_e]])
        xc, yc = (float(z[0]) for z in body_centre(ego, self.bike.wheelbase_m))
        keep = s.ids != self.vid
        ids, x, y, v = s.ids[keep], s.position[keep, 0], s.position[keep, 1] - self.lane_y, s.velocity[keep, 0]
        own = (v >= 0.0) & (y < 0.5 * self.road.lane_width_m)
        k = self._lead(ids[own], x[own], v[own], xc)
        lead_x = np.array([x[own][k] if k is not None else FAR_M])
        onc = (v < 0.0) & (np.abs(x - xc) < self.p.range_m)
        onc_x = x[onc][:, None] if onc.any() else np.full((1, 1), FAR_M)
        onc_v = v[onc] if onc.any() else np.zeros(1)
        sig = safety_signals(ego, lead_x, onc_x, onc_v, self.bike, self.road)
        for name, val in sig.items():
            ctx.signals.record(name, ctx.t, float(val[0]))
        others = np.column_stack((x, y))  # everyone, not only the lead and oncoming cars the spec names
        clearance = box_clearance(ego, self.bike, others, s.heading[keep], s.size[keep, :2])
        ctx.signals.record("clearance", ctx.t, float(clearance[0]))
        ctx.signals.record("lane_offset", ctx.t, yc)
        ctx.signals.record("ego_speed", ctx.t, float(ego[0, 3]))
        if sig["lat_lead"][0] <= 0.0 and k is not None:  # sharing the lead's lane
            self.min_gap_lead_m = min(self.min_gap_lead_m, float(max(sig["gap_lead"][0], sig["ahead_lead"][0])))
        if sig["lat_onc"][0] <= 0.0 and onc.any():  # sharing the oncoming lane
            self.min_gap_onc_m = min(self.min_gap_onc_m, float(sig["gap_onc"][0]))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"min_gap_lead_m": self.min_gap_lead_m if math.isfinite(self.min_gap_lead_m) else math.nan,
                "min_gap_oncoming_m": self.min_gap_onc_m if math.isfinite(self.min_gap_onc_m) else math.nan}
