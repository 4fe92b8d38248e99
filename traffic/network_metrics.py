"""Network-wide figures of Flow's benchmarks and energy from SUMO's emission model (``network_metrics``).

A DETECT-phase monitor that reads only the snapshot's road frame:

* ``avg_speed_mps``: Flow's "average speed" of the merge benchmarks, the mean speed of all vehicles in
  the network at each road step, averaged over the steps of the horizon (after the warm-up);
* ``outflow_vph``: vehicles that left the network (arrived) per hour, after the warm-up;
* ``co2_g_per_km``, ``fuel_g_per_km``: CO2 and fuel of all vehicles over the distance they drove
  (after the warm-up), integrated from the per-vehicle rates [mg/s] that the road backend reads from
  SUMO's emission model (HBEFA / PHEMlight, the vType's ``emissionClass``) when
  ``road.sumo.emissions`` is on; ``co2_total_kg`` is the total.

The per-step mean speed is recorded as the signal ``network_speed_mps``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from corridor.engine import Component, Need, Phase, RunContext
from corridor.traffic.trips import NEEDS_ROAD, road_frame


class NetworkMetrics(Component):
    phase = Phase.DETECT
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "peer:road"  # [s] every road step

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.warmup = scenario.warmup if scenario is not None else 0.0
        self.speed_sum = 0.0  # sum over steps of the step's mean speed [m/s]
        self.steps = 0
        self.arrived = 0
        self.distance_m = 0.0  # [m] driven by all vehicles after the warm-up
        self.co2_mg = 0.0
        self.fuel_mg = 0.0
        self.emissions_read = False

    def tick(self, ctx: RunContext) -> None:
        road = road_frame(ctx)
        if ctx.t < self.warmup:
            return
        self.arrived += len(road.events.arrived)
        if not len(road):
            return
        speed = ctx.snapshot.speed[road.sl]
        mean = float(speed.mean())
        self.speed_sum += mean
        self.steps += 1
        self.distance_m += float(speed.sum()) * self.period
        ctx.signals.record("network_speed_mps", ctx.t, mean)
        if len(road.co2_mgps):
            self.emissions_read = True
            self.co2_mg += float(road.co2_mgps.sum()) * self.period
            self.fuel_mg += float(road.fuel_mgps.sum()) * self.period

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        span_h = max(ctx.duration - self.warmup, 1e-9) / 3600.0
        km = self.distance_m / 1000.0
        out: dict[str, Any] = {
            "avg_speed_mps": self.speed_sum / self.steps if self.steps else np.nan,
            "outflow_vph": self.arrived / span_h,
        }
        if self.emissions_read:
            out["co2_g_per_km"] = self.co2_mg / 1000.0 / km if km > 0 else np.nan
            out["fuel_g_per_km"] = self.fuel_mg / 1000.0 / km if km > 0 else np.nan
            out["co2_total_kg"] = self.co2_mg / 1e6
        return out
