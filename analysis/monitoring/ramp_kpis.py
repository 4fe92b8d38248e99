"""Ramp-metering KPIs on the beltway: total time spent, delay, throughput, ramp queues, spill-back,
fairness across ramps and the MPC's solve times.

* TTS [veh h] = integral over the run of (vehicles in the network + vehicles waiting for insertion)
  dt.  Vehicles on arterials and ramps are in the network, so ramp queues are included; a queue that
  spills back past the arterial shows up as vehicles SUMO could not insert yet (pending).
* Total delay [veh h]: sum over arrived vehicles (departing after warm-up) of travel time + insertion
  delay - free-flow travel time (``Trips.delays`` of the ``trips`` peer).
* Throughput [veh/h]: vehicles that arrived after the warm-up, per hour of the measured span.
* Ramp queues from the ``ramp_detectors`` peer (E2 vehicles on each on-ramp storage): maximum and mean
  per ramp, the worst ramp's maximum relative to its storage, and spill-back events (the queue reaching
  its storage, counted on each rising edge).
* Fairness: mean wait per ramp by Little's law (time-mean queue / ramp outflow), reported as the
  spread (max - min) and standard deviation across ramps [s].
* MPC solve times p50/p95 [s] and fallbacks, from any peer that keeps ``solve_times_s`` and
  ``n_fallbacks`` (the ``ramp_mpc`` controller), the solves the CPU-time safety net ended
  (``mpc_cpu_capped``) and the IPOPT iteration counts (``mpc_iter_p50`` / ``mpc_iter_max``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.traffic.sensing.detectors import NEEDS_DETECTORS
from corridor.traffic.sumo.trips import NEEDS_TRIPS, road_frame


def spillback_events(queue_veh: np.ndarray, storage_veh: float) -> int:
    """Rising edges of ``queue >= storage`` in a queue time series."""
    full = np.asarray(queue_veh, dtype=float) >= storage_veh
    return int(np.count_nonzero(full[1:] & ~full[:-1]) + (1 if len(full) and full[0] else 0))


def little_wait_s(queue_veh: np.ndarray, span_s: float, served_veh: int) -> float:
    """Mean wait [s] by Little's law: time-mean queue x span / vehicles served (nan if none)."""
    if served_veh <= 0 or len(queue_veh) == 0:
        return math.nan
    return float(np.mean(queue_veh)) * span_s / served_veh


class RampKpis(Component):
    """TTS, delay, throughput, ramp queues, spill-back, fairness and MPC solve times."""

    phase = Phase.DETECT
    needs: ClassVar[dict[str, Need]] = {"trips": NEEDS_TRIPS, "det": NEEDS_DETECTORS}
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('tts_vh', 'veh*h',
               'Total time spent in the network after the warm-up (vehicles on the road plus queued).'),
        Metric('tts_pending_vh', 'veh*h',
               'Time spent by vehicles waiting to enter the network.'),
        Metric('delay_total_vh', 'veh*h',
               'Summed travel-time delay of the measured vehicles.'),
        Metric('delay_mean_s', 's',
               'Mean travel-time delay of the measured vehicles.'),
        Metric('throughput_vph', 'veh/h',
               'Measured vehicles per hour.'),
        Metric('queue_max_veh', 'veh',
               'Longest ramp queue over all ramps.'),
        Metric('queue_max_*', 'veh',
               'Longest queue of ramp <name>.'),
        Metric('queue_mean_*', 'veh',
               'Mean queue of ramp <name>.'),
        Metric('queue_max_over_storage', '1',
               "Largest ramp queue relative to the ramp's storage (> 1: spillback)."),
        Metric('spillback_events', '1',
               'Times a ramp queue exceeded its storage.'),
        Metric('ramp_wait_mean_s', 's',
               'Mean waiting time on the ramps.'),
        Metric('ramp_wait_spread_s', 's',
               "Largest minus smallest ramp's mean waiting time."),
        Metric('ramp_wait_std_s', 's',
               "Standard deviation of the ramps' mean waiting times."),
        Metric('mpc_solve_p50_s', 's',
               'Median MPC solve time (wall clock).'),
        Metric('mpc_solve_p95_s', 's',
               '95th percentile MPC solve time (wall clock).'),
        Metric('mpc_solves', '1',
               'MPC solves.'),
        Metric('mpc_fallbacks', '1',
               'MPC steps that fell back (no usable solution).'),
        Metric('mpc_suboptimal', '1',
               'MPC solves that stopped before optimality.'),
        Metric('mpc_cpu_capped', '1',
               'MPC solves stopped by their CPU budget.'),
        Metric('mpc_iter_p50', '1',
               'Median IPOPT iterations per MPC solve.'),
        Metric('mpc_iter_max', '1',
               'Largest IPOPT iteration count of an MPC solve.'),
    )
    period_source: ClassVar[str | None] = "p.period_s"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        period_s: float = Field(1.0, gt=0)  # [s] TTS sampling period
        prefix: str = Field("", max_length=32, pattern=r"^[A-Za-z0-9_.]*$")  # column prefix, e.g. "ramp."

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.tts_vh = 0.0
        self.tts_pending_vh = 0.0
        self._last_loop_t = -math.inf

    def tick(self, ctx: RunContext) -> None:
        road = road_frame(ctx)
        n_net = len(road)
        n_pending = road.events.backlog
        self.tts_vh += (n_net + n_pending) * self.period / 3600.0
        self.tts_pending_vh += n_pending * self.period / 3600.0
        ctx.signals.record("vehicles_in_network", ctx.t, n_net)
        ctx.signals.record("vehicles_pending", ctx.t, n_pending)
        self._record_detectors(ctx)

    def _record_detectors(self, ctx: RunContext) -> None:
        """Queues every tick of the detectors; loop speeds (the speed contour) once per interval."""
        latest = self.det.latest
        new_loops = any(m.t_loops > self._last_loop_t for m in latest.values())
        for key, m in latest.items():
            ctx.signals.record(f"queue_{key}", ctx.t, m.queue_veh)
            if new_loops:
                ctx.signals.record(f"speed_down_kmh_{key}", m.t_loops, _kmh(m.speed_down_mps))
                ctx.signals.record(f"speed_up_kmh_{key}", m.t_loops, _kmh(m.speed_up_mps))
                ctx.signals.record(f"occ_down_pct_{key}", m.t_loops, m.occupancy_down_pct)
        if new_loops:
            self._last_loop_t = max(m.t_loops for m in latest.values())

    SHARED: ClassVar[tuple[str, ...]] = ("tts_vh", "delay_total_vh", "delay_mean_s", "throughput_vph")

    def metric_columns(self) -> frozenset[str]:
        return frozenset(self.p.prefix + c for c in self.SHARED)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        out: dict[str, Any] = {"tts_vh": self.tts_vh, "tts_pending_vh": self.tts_pending_vh}
        out.update(self._delay_throughput(ctx))
        out.update(self._queues(ctx))
        out.update(self._solver(ctx))
        return {self.p.prefix + k: v for k, v in out.items()} if self.p.prefix else out

    def _delay_throughput(self, ctx: RunContext) -> dict[str, Any]:
        warm = ctx.scenario.warmup if ctx.scenario is not None else 0.0
        delays = np.concatenate(list(self.trips.delays(warm).values()))
        span_h = (ctx.duration - warm) / 3600.0
        return {"delay_total_vh": float(delays.sum() / 3600.0),
                "delay_mean_s": float(delays.mean()) if len(delays) else math.nan,
                "throughput_vph": len(delays) / span_h}

    def _queues(self, ctx: RunContext) -> dict[str, Any]:
        log, out = self.det.log, {}
        span_s = float(log.t[-1] - log.t[0]) + self.det.period if log.t else 0.0
        waits, worst, spills = [], 0.0, 0
        for key, m in self.det.latest.items():
            q = np.asarray(log.queue[key], dtype=float)
            qmax = float(q.max()) if len(q) else 0.0
            out[f"queue_max_{key}"] = qmax
            out[f"queue_mean_{key}"] = float(q.mean()) if len(q) else 0.0
            worst = max(worst, qmax / m.storage_veh)
            spills += spillback_events(q, m.storage_veh)
            waits.append(little_wait_s(q, span_s, self.det.passed_total[key]))
        w = np.asarray([x for x in waits if math.isfinite(x)])
        out.update({"queue_max_veh": max((out[f"queue_max_{k}"] for k in self.det.latest), default=0.0),
                    "queue_max_over_storage": worst, "spillback_events": spills,
                    "ramp_wait_mean_s": float(w.mean()) if len(w) else math.nan,
                    "ramp_wait_spread_s": float(w.max() - w.min()) if len(w) else math.nan,
                    "ramp_wait_std_s": float(w.std()) if len(w) else math.nan})
        return out

    def _solver(self, ctx: RunContext) -> dict[str, Any]:
        for c in ctx.components.values():
            times = getattr(c, "solve_times_s", None)
            if times is not None:
                t = np.asarray(times) if len(times) else np.array([math.nan])
                return {"mpc_solve_p50_s": float(np.percentile(t, 50)),
                        "mpc_solve_p95_s": float(np.percentile(t, 95)),
                        "mpc_solves": len(times), "mpc_fallbacks": int(getattr(c, "n_fallbacks", 0)),
                        "mpc_suboptimal": int(getattr(c, "n_suboptimal", 0)),
                        "mpc_cpu_capped": int(getattr(c, "n_cpu_capped", 0)),
                        **_iterations(getattr(c, "iter_counts", None))}
        return {}


def _iterations(counts: list[int] | None) -> dict[str, float]:
    """Median and largest IPOPT iteration count of the solves (deterministic, unlike solve times)."""
    if not counts:
        return {}
    return {"mpc_iter_p50": float(np.percentile(counts, 50)), "mpc_iter_max": float(max(counts))}


def _kmh(speed_mps: float) -> float:
    """[m/s] -> [km/h]; nan (no vehicle passed) stays nan."""
    return speed_mps * 3.6
