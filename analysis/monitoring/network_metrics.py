"""Network-wide figures of Flow's benchmarks and energy from SUMO's emission model (``network_metrics``).

A DETECT-phase monitor that reads only the snapshot's road frame:

* ``avg_speed_mps``: Flow's "average speed" of the merge benchmarks, the mean speed of all vehicles in
  the network at each road step, averaged over the steps of the horizon (after the warm-up);
* ``avg_speed_all_mps``: the same with the vehicles waiting to enter the network (SUMO's insertion
  backlog) counted at 0 m/s.  Flow's figure leaves them out, so a controller that moves a queue from
  inside the network to its entrance (a blocked insertion) raises it without moving anyone faster;
  this one does not reward that;
* ``outflow_vph``: vehicles that left the network (arrived) per hour, after the warm-up;
* ``co2_g_per_km``, ``fuel_g_per_km``: CO2 and fuel of all vehicles over the distance they drove
  (after the warm-up), integrated from the per-vehicle rates [mg/s] that the road backend reads from
  SUMO's emission model (HBEFA / PHEMlight, the vType's ``emissionClass``) when
  ``road.sumo.emissions`` is on; ``co2_total_kg`` is the total.

The per-step mean speed is recorded as the signal ``network_speed_mps``.  With ``cell_m`` the mean speed
of the vehicles on the highway (not on a ramp lane) per cell of ``cell_m`` along x and per
``cell_period_s`` is recorded as signals ``ts_speed_kmh_<cell start x, 5 digits>`` (the report's
time-space diagram, where waves and their damping show).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.sumo.trips import NEEDS_ROAD, road_frame


class NetworkMetrics(Component):
    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('avg_speed_mps', 'm/s', "Flow's average speed: mean speed of all vehicles in the network over the measured steps."),
        Metric('avg_speed_all_mps', 'm/s',
               "Flow's average speed with the vehicles waiting to enter the network counted at 0 m/s."),
        Metric('outflow_vph', 'veh/h', 'Vehicles that left the network per hour after the warm-up.'),
        Metric('co2_g_per_km', 'g/km', "CO2 from SUMO's emission model per vehicle-kilometre (road.sumo.emissions)."),
        Metric('fuel_g_per_km', 'g/km', "Fuel from SUMO's emission model per vehicle-kilometre (road.sumo.emissions)."),
        Metric('co2_total_kg', 'kg', "Total CO2 from SUMO's emission model (road.sumo.emissions)."),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "peer:road"  # [s] every road step

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        cell_m: float | None = Field(None, gt=0)  # [m] time-space diagram cells (None: not recorded)
        cell_period_s: float = Field(5.0, gt=0)  # [s]

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.warmup = scenario.warmup if scenario is not None else 0.0
        self.speed_sum = 0.0  # sum over steps of the step's mean speed [m/s]
        self.steps = 0
        self.speed_all_sum = 0.0  # sum over steps of the step's speed sum / (vehicles in + waiting to enter)
        self.steps_all = 0
        self.arrived = 0
        self.distance_m = 0.0  # [m] driven by all vehicles after the warm-up
        self.co2_mg = 0.0
        self.fuel_mg = 0.0
        self.emissions_read = False
        self._ts_sum = self._ts_n = np.zeros(0)
        self._ts_end = self.p.cell_period_s

    def setup(self, ctx: RunContext) -> None:
        lm = road_frame(ctx).tables.landmarks
        self._is_ramp = getattr(lm, "is_ramp_lane", lambda lane: False)
        self._ramp_lane = np.zeros(0, dtype=bool)
        if self.p.cell_m is not None:
            x0 = float(getattr(lm, "mainline_start_x", 0.0))
            self._ts_edges = np.arange(x0, float(lm.mainline_end_x) + self.p.cell_m, self.p.cell_m)
            self._ts_sum = np.zeros(len(self._ts_edges) - 1)
            self._ts_n = np.zeros(len(self._ts_edges) - 1)

    def tick(self, ctx: RunContext) -> None:
        road = road_frame(ctx)
        if ctx.t < self.warmup:
            return
        self.arrived += len(road.events.arrived)
        n, waiting = len(road), road.events.backlog
        if n + waiting:
            self.steps_all += 1
        if not n:
            return
        speed = ctx.snapshot.speed[road.sl]
        mean = float(speed.mean())
        self.speed_all_sum += float(speed.sum()) / (n + waiting)
        self.speed_sum += mean
        self.steps += 1
        self.distance_m += float(speed.sum()) * self.period
        ctx.signals.record("network_speed_mps", ctx.t, mean)
        if self.p.cell_m is not None:
            self._space_time(ctx, road, speed)
        if len(road.co2_mgps):
            self.emissions_read = True
            self.co2_mg += float(road.co2_mgps.sum()) * self.period
            self.fuel_mg += float(road.fuel_mgps.sum()) * self.period

    def _space_time(self, ctx: RunContext, road: Any, speed: np.ndarray) -> None:
        """Add the step's highway speeds to their cells; record the cells' means every cell period."""
        tb = road.tables
        if len(self._ramp_lane) < tb.n_lanes:
            self._ramp_lane = np.array([bool(self._is_ramp(n)) for n in tb.lane_names], dtype=bool)
        x = ctx.snapshot.position[road.sl, 0]
        k = np.searchsorted(self._ts_edges, x, side="right") - 1
        ok = ~self._ramp_lane[road.lane] & (k >= 0) & (k < len(self._ts_sum))
        self._ts_sum += np.bincount(k[ok], weights=speed[ok], minlength=len(self._ts_sum))
        self._ts_n += np.bincount(k[ok], minlength=len(self._ts_n))
        if ctx.t + 1e-9 >= self._ts_end:
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = np.where(self._ts_n > 0, 3.6 * self._ts_sum / self._ts_n, np.nan)
            for x0, v in zip(self._ts_edges[:-1], mean):
                ctx.signals.record(f"ts_speed_kmh_{int(round(x0)):05d}", self._ts_end, float(v))
            self._ts_sum[:] = 0.0
            self._ts_n[:] = 0.0
            self._ts_end += self.p.cell_period_s

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        span_h = max(ctx.duration - self.warmup, 1e-9) / 3600.0
        km = self.distance_m / 1000.0
        out: dict[str, Any] = {
            "avg_speed_mps": self.speed_sum / self.steps if self.steps else np.nan,
            "avg_speed_all_mps": self.speed_all_sum / self.steps_all if self.steps_all else np.nan,
            "outflow_vph": self.arrived / span_h,
        }
        if self.emissions_read:
            out["co2_g_per_km"] = self.co2_mg / 1000.0 / km if km > 0 else np.nan
            out["fuel_g_per_km"] = self.fuel_mg / 1000.0 / km if km > 0 else np.nan
            out["co2_total_kg"] = self.co2_mg / 1e6
        return out
