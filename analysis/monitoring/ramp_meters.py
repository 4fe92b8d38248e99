"""Ramp-meter rates as a monitor (``ramp_meters``): what the meters run, whoever (or nobody) controls
them, so the report's meter-rate plot exists for every variant, ``ramp_none`` and ``none`` included.

It sits at the end of *decide* (monitors are built after the controllers, so it runs after them in
that phase) and reads every ``SetMeterRate`` / ``MeterOff`` command on the bus before the road backend
applies it; a meter no command has touched runs the network's default program (``landmarks.meter``:
one vehicle per green + red cycle).  Every ``period_s`` it records ``rate_{d}{k}`` [veh/h] per meter,
a switched-off meter at its open rate (the value the ramp controllers recorded themselves before).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Phase, RunContext
from corridor.traffic.networks.landmarks import BeltwayLandmarks
from corridor.traffic.sumo.meters import DIRECTIONS, MeterOff, SetMeterRate
from corridor.traffic.sumo.road_spec import road_spec
from corridor.traffic.sumo.trips import road_frame


class RampMeters(Component):
    """Records the rate every beltway meter runs, from the meter commands on the bus."""

    phase = Phase.DECIDE
    period_source: ClassVar[str | None] = "dt"  # every tick: no command may pass unseen

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        period_s: float = Field(60.0, gt=0)  # [s] between two samples of the rates (= the control step)
        open_rate_vph: float = Field(1800.0, gt=0)  # [veh/h] recorded for a meter switched off

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params

    def setup(self, ctx: RunContext) -> None:
        lm = road_frame(ctx).tables.landmarks
        if not isinstance(lm, BeltwayLandmarks):
            raise ValueError(f"{self.name}: ramp meters need the beltway network, not {lm.kind!r}")
        self.key_of = {ic.ramp(d).meter_tls: f"{d}{ic.index}" for ic in lm.interchanges for d in DIRECTIONS}
        default = 3600.0 / (lm.meter.green_s + lm.meter.red_s)  # [veh/h] the network's own program
        self.rate_vph = {tls: min(default, self.p.open_rate_vph) for tls in self.key_of}
        self._every = max(1, round(self.p.period_s / ctx.dt))
        self._angles = {ic.ramp(d).meter_tls: (float(ic.angle_rad), d) for ic in lm.interchanges for d in DIRECTIONS}
        spec = road_spec(ctx.scenario) if ctx.scenario is not None else None
        self._radius_m = spec.network.params.circumference_m / (2 * np.pi) if spec is not None else 0.0

    def rerun_log(self, rec: Any, rr: Any, ctx: RunContext) -> None:
        """Each meter as a point beside its on-ramp: green when open, red at the lowest rates (Rerun)."""
        if not self._radius_m:
            return
        tls = list(self.rate_vph)
        ang = np.array([self._angles[t][0] for t in tls])
        r = self._radius_m + np.array([80.0 if self._angles[t][1] == "ccw" else -80.0 for t in tls])
        share = np.clip(np.array([self.rate_vph[t] for t in tls]) / self.p.open_rate_vph, 0.0, 1.0)
        colors = np.column_stack([255 * (1 - share), 255 * share, np.zeros(len(tls)), np.full(len(tls), 255)])
        rec.log("world/meters", rr.Points3D(np.column_stack([r * np.cos(ang), r * np.sin(ang), np.full(len(tls), 2.0)]),
                                            colors=colors.astype(np.uint8), radii=25.0,
                                            labels=[f"{self.key_of[t]} {self.rate_vph[t]:.0f}" for t in tls]))

    def tick(self, ctx: RunContext) -> None:
        for c in ctx.commands:
            if isinstance(c, SetMeterRate) and c.tls in self.rate_vph:
                self.rate_vph[c.tls] = min(c.rate_vph, c.timing.open_rate_vph)
            elif isinstance(c, MeterOff) and c.tls in self.rate_vph:
                self.rate_vph[c.tls] = self.p.open_rate_vph
        if ctx.tick % self._every == 0:
            for tls, key in self.key_of.items():
                ctx.signals.record(f"rate_{key}", ctx.t, self.rate_vph[tls])
