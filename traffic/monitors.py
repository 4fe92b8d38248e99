"""Road monitors: surrogate safety (TTC, DRAC, hard braking) and traffic KPIs (throughput past the
merge, travel-time delay of mainline and ramp vehicles).  They read the SUMO backend's lane-frame
arrays, aligned row by row with its snapshot part."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.analysis.safety import lane_leaders, ttc_drac
from corridor.analysis.stats import jain_index
from corridor.engine import Component, Phase, RunContext
from corridor.traffic.sumo_backend import SumoBackend


def road_backend(ctx: RunContext) -> SumoBackend:
    for b in ctx.backends():
        if isinstance(b, SumoBackend):
            return b
    raise ValueError("this monitor needs a road (SUMO) backend: add `road:` to the scenario")


class SurrogateSafety(Component):
    """Minimum TTC, maximum DRAC, time exposed to TTC below a threshold, hard-braking events."""

    phase = Phase.DETECT

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        ttc_threshold_s: float = Field(1.5, gt=0)  # for time exposed (TET)
        hard_brake_mps2: float = Field(-4.5, lt=0)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.period = scenario.road.sumo.step_length if scenario.road else scenario.dt
        self.warmup = scenario.warmup
        self.min_ttc, self.max_drac, self.tet = np.inf, 0.0, 0.0
        self.hard_brakes = 0
        self._braking = np.zeros(0, dtype=bool)  # per uid: was braking hard at the previous tick

    def setup(self, ctx: RunContext) -> None:
        self.road = road_backend(ctx)

    def tick(self, ctx: RunContext) -> None:
        r = self.road
        if len(self._braking) < r.n_uids:
            self._braking = np.concatenate([self._braking, np.zeros(r.n_uids + 256, dtype=bool)])
        braking = r.accel < self.p.hard_brake_mps2
        counting = ctx.t >= self.warmup
        if counting:
            self.hard_brakes += int(np.count_nonzero(braking & ~self._braking[r.uid]))
        self._braking[r.uid] = braking
        f, lead = lane_leaders(r.lane_code, r.lane_pos)
        ttc_now = np.inf
        if len(f):
            s = r.snapshot_part()
            speed = s.speed
            gap = r.lane_pos[lead] - s.size[lead, 0] - r.lane_pos[f]
            ttc, drac = ttc_drac(gap, speed[f], speed[lead])
            ttc_now = float(ttc.min())
            if counting:
                self.min_ttc = min(self.min_ttc, ttc_now)
                self.max_drac = max(self.max_drac, float(drac.max()))
                self.tet += float(np.count_nonzero(ttc < self.p.ttc_threshold_s)) * self.period
        ctx.signals.record("min_ttc", ctx.t, min(ttc_now, 99.0))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"min_ttc_s": min(self.min_ttc, 99.0), "max_drac_mps2": self.max_drac,
                "ttc_exposed_s": self.tet, "hard_brakes": self.hard_brakes}


class TrafficKpis(Component):
    """Throughput past a line (the merge end), travel-time delay by role (mainline / ramp) with
    Jain's fairness index between the two mean delays, an energy proxy (mean over arrived
    vehicles of ∫ a² dt), and total time spent (``tts_vh``: vehicles on the road plus vehicles
    waiting to be inserted, integrated after the warm-up).

    Delay is taken over every vehicle that entered the demand after the warm-up: vehicles that had
    not arrived when the run ended count with their delay so far (see ``SumoBackend.delays``), and
    ``insertion_backlog`` is the number still waiting to enter the network at the end."""

    phase = Phase.DETECT

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        count_landmark: str = "past_merge_x"  # network landmark giving the counting line x [m]

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.period = scenario.road.sumo.step_length
        self.warmup = scenario.warmup
        self.passed = np.zeros(0, dtype=bool)  # per uid
        self.energy = np.zeros(0)  # per uid: ∫ a² dt [m²/s³] after warm-up
        self.count = 0
        self.tts_vh = 0.0

    def setup(self, ctx: RunContext) -> None:
        self.road = road_backend(ctx)
        self.line_x = float(self.road.net.landmarks[self.p.count_landmark])

    def tick(self, ctx: RunContext) -> None:
        r = self.road
        n = len(r.active)
        if ctx.t >= self.warmup:
            self.tts_vh += (n + r.backlog()) * self.period / 3600.0
        if n == 0:
            return
        if len(self.passed) < r.n_uids:
            grow = r.n_uids + 256
            self.passed = np.concatenate([self.passed, np.zeros(grow, dtype=bool)])
            self.energy = np.concatenate([self.energy, np.zeros(grow)])
        part = r.snapshot_part()
        if ctx.t >= self.warmup:
            self.energy[r.uid] += r.accel**2 * self.period
        new = (part.position[:, 0] > self.line_x) & ~self.passed[r.uid]
        self.passed[r.uid[new]] = True
        if ctx.t >= self.warmup:
            self.count += int(np.count_nonzero(new))
        ctx.signals.record("vehicles", ctx.t, n)
        ctx.signals.record("mean_speed", ctx.t, float(part.speed.mean()))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        span_h = (ctx.duration - self.warmup) / 3600.0
        out: dict[str, Any] = {"throughput_vph": self.count / span_h, "tts_vh": self.tts_vh}
        delays = self.road.delays(self.warmup, unfinished=True)
        out["insertion_backlog"] = self.road.backlog()
        for role, d in delays.items():
            out[f"delay_{role}_mean_s"] = float(d.mean()) if len(d) else np.nan
            out[f"delay_{role}_p95_s"] = float(np.percentile(d, 95)) if len(d) else np.nan
            out[f"n_{role}"] = len(d)
        both = np.concatenate(list(delays.values()))
        means = [out["delay_mainline_mean_s"], out["delay_ramp_mean_s"]]
        out["delay_jain_index"] = jain_index(np.maximum(means, 0.0)) if all(np.isfinite(means)) else np.nan
        measured = self.road.measured_uids(self.warmup)
        out["energy_proxy_mean"] = float(self.energy[measured].mean()) if len(measured) else np.nan
        out["delay_mean_s"] = float(both.mean()) if len(both) else np.nan
        out["delay_total_vh"] = float(both.sum() / 3600.0)
        return out
