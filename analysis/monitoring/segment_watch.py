"""DETECT-phase monitor of the traffic centre's picture (``monitor.segment_watch``): density-estimate
error against SUMO's ground truth, camera coverage, and the downlink's delivery.

Every ``period_s`` it takes the ground truth per METANET segment from the snapshot
(``corridor.traffic.networks.segments``: vehicles on each segment / (length x lanes)) and compares

- ``rmse_loops``: the loops by the direct mapping the MPC uses without fusion (mean of the station
  downstream of merge k and the one upstream of the next merge, occupancy x 10 / vehicle length),
- ``rmse_fused``: the ``segment_estimate`` peer's densities (when the run has one),

over every segment and sample from ``start_s`` on (the loops have no interval before their first
aggregation).  Coverage: the share of (segment, sample) pairs a camera observed at least
``min_observed_m`` of (``camera`` peer's last frame), so an avoidance that drives UAVs off their
sectors shows up.  It reads peers' published values only and never refreshes them (an observer).

``wall_per_sim_s``: wall-clock seconds per simulated second from this monitor's setup to the end (all
components' work; a measurement of the machine, which varies between otherwise identical runs), and
``cpu_per_sim_s``: the run process's CPU seconds over the same span (what the run would take of wall
time on an idle core; far less sensitive to the other processes on a shared machine).
"""

from __future__ import annotations

import math
import time
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.networks.segments import RingIndex, RingSegments
from corridor.traffic.sensing.detectors import DIRECTIONS, NEEDS_DETECTORS, RampDetectors
from corridor.traffic.sumo.road_spec import road_spec


class SegmentWatch(Component):
    phase = Phase.DETECT
    needs: ClassVar[dict[str, Need]] = {
        "det": NEEDS_DETECTORS,
        "fusion": Need(role="segment_estimate", name_at="params.fusion", optional=True),
        "camera": Need(role="camera", name_at="params.camera", optional=True),
    }
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('rmse_loops', 'veh/km/lane',
               'RMSE of the loops-only segment density estimate against the truth.'),
        Metric('rmse_fused', 'veh/km/lane',
               'RMSE of the fused (loops + UAV) segment density estimate against the truth.'),
        Metric('wall_per_sim_s', '1',
               'Wall-clock seconds per simulated second.'),
        Metric('cpu_per_sim_s', '1',
               'CPU seconds per simulated second.'),
        Metric('coverage', '1',
               'Share of segment-periods a UAV camera covered.'),
        Metric('downlink_delivery_ratio', '1',
               'Share of the camera estimates sent that reached the fusion.'),
    )
    period_source: ClassVar[str | None] = "params.period_s"
    det: RampDetectors

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        fusion: str | None = "fusion"
        camera: str | None = "camera"
        period_s: float = Field(2.0, gt=0.0)  # [s]
        start_s: float = Field(120.0, ge=0.0)  # [s] errors counted from here on
        vehicle_length_m: float = Field(5.0, gt=0.0)
        min_observed_m: float = Field(50.0, ge=0.0)  # [m] a segment counts as observed
        truth_signal_period_s: float = Field(60.0, gt=0.0)  # [s] signals rho_true_i / v_true_i (per segment)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.fusion: Any = None
        self.camera: Any = None
        self.sq_loops = self.sq_fused = 0.0
        self.n_err = 0
        self.covered = 0
        self.n_cov = 0
        self.tts_vh = 0.0  # running total time spent of the vehicles on the network (the series)

    def setup(self, ctx: RunContext) -> None:
        lm = ctx.snapshot.road.tables.landmarks
        self.seg = RingSegments.build(lm, road_spec(ctx.scenario).network.params, 1)
        self.index = RingIndex(self.seg)
        self.n = self.seg.n
        self._next_truth_s = self.params.start_s
        self._wall0 = time.perf_counter()
        self._cpu0 = time.process_time()

    def loops_density(self) -> np.ndarray:
        """[n_seg] the direct mapping of the loops (``estimate_state`` with one segment per link)."""
        out = np.zeros(self.seg.n_seg)
        L, latest = self.params.vehicle_length_m, self.det.latest
        for dirn, d in enumerate(DIRECTIONS):
            hop = 1 if dirn == 0 else -1
            for k in range(self.n):
                a, b = latest[f"{d}{k}"], latest[f"{d}{(k + hop) % self.n}"]
                out[dirn * self.n + k] = 0.5 * (a.occupancy_down_pct + b.occupancy_up_pct) * 10.0 / L
        return out

    def _has_cameras(self) -> bool:
        """A camera peer with UAVs (a road-only variant keeps an empty one: no coverage figure)."""
        return self.camera is not None and bool(getattr(self.camera, "uav_ids", ())) and len(self.camera.observed_m) > 0

    def tick(self, ctx: RunContext) -> None:
        road = ctx.snapshot.road
        self.tts_vh += (len(road) if road is not None else 0) * self.period / 3600.0
        ctx.signals.record("tts_running_vh", ctx.t, self.tts_vh)
        if self._has_cameras():
            self.covered += int(np.count_nonzero(self.camera.observed_m >= self.params.min_observed_m))
            self.n_cov += len(self.camera.observed_m)
            ctx.signals.record("coverage", ctx.t, float(np.mean(self.camera.observed_m >= self.params.min_observed_m)))
        if ctx.t < self.params.start_s:
            return
        truth, v_true = self.index.truth(ctx.snapshot)
        if ctx.t + 1e-9 >= self._next_truth_s:
            self._next_truth_s += self.params.truth_signal_period_s
            for i, (r, v) in enumerate(zip(truth, v_true, strict=True)):
                ctx.signals.record(f"rho_true_{i}", ctx.t, float(r))
                ctx.signals.record(f"v_true_{i}", ctx.t, float(v))
        e_loops = self.loops_density() - truth
        self.sq_loops += float(e_loops @ e_loops)
        ctx.signals.record("rho_rmse_loops", ctx.t, float(np.sqrt(np.mean(e_loops**2))))
        if self.fusion is not None and self.fusion.kf is not None:
            e_f = self.fusion.densities() - truth
            self.sq_fused += float(e_f @ e_f)
            ctx.signals.record("rho_rmse_fused", ctx.t, float(np.sqrt(np.mean(e_f**2))))
        self.n_err += len(truth)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        nan = math.nan
        out: dict[str, Any] = {"rmse_loops": math.sqrt(self.sq_loops / self.n_err) if self.n_err else nan,
                               "wall_per_sim_s": (time.perf_counter() - self._wall0) / max(ctx.t, 1e-9),
                               "cpu_per_sim_s": (time.process_time() - self._cpu0) / max(ctx.t, 1e-9)}
        if self.fusion is not None:
            out["rmse_fused"] = math.sqrt(self.sq_fused / self.n_err) if self.n_err else nan
        if self._has_cameras():
            out["coverage"] = self.covered / self.n_cov if self.n_cov else nan
            sent = self.camera.messages_sent
            got = self.fusion.uav_received if self.fusion is not None else 0
            out["downlink_delivery_ratio"] = got / sent if sent else nan
        return out
