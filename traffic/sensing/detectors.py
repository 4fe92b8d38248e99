"""SENSE-phase detector reader for the metered beltway: loops and ramp queues per interchange.

Every ``period`` (a few seconds) it samples the ramp queues (E2 lane-area detectors over each on-ramp:
vehicles on the ramp and halting ones); every ``aggregate_s`` (the loops' own aggregation period of
the network, ``detector_period_s``) it reads the last completed interval of every E1 loop: occupancy
[%], flow [veh/h] and mean speed [m/s] up- and downstream of each merge, and the vehicles that passed
each meter.  The newest values are kept in ``latest`` (one ``RampMeasurement`` per ramp key
``"{d}{k}"``), which controllers and KPIs read through their peer of role ``ramp_detectors``
(``NEEDS_DETECTORS``).  It reads only the
snapshot's detector part (``RoadFrame.detectors``: the loops, lane areas and watched edges that the
network's landmarks declare, read by the road backend after each step).

It also lists vehicles newly seen on each origin arterial (``a{k}_in``), which route guidance may
switch to the other loop while they are still there (``new_on_origin``, replaced every tick: a
guiding controller must tick with the same period, as ``ramp_mpc`` does by default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.snapshot import DetectorFrame
from corridor.traffic.networks.beltway import BeltwayParams
from corridor.traffic.networks.landmarks import BeltwayLandmarks, MeteredRamp
from corridor.traffic.sensing.loop_faults import LoopFaults, Reading, StationFault, apply_fault, draw_faults
from corridor.traffic.sumo.road_spec import road_spec
from corridor.traffic.sumo.trips import road_frame

DIRECTIONS = ("ccw", "cw")
# how ramp controllers and KPIs name their detectors peer (exactly one in the run)
NEEDS_DETECTORS = Need(role="ramp_detectors", hint="add a `ramp_detectors` monitor to the scenario (monitors: ...)")


@dataclass
class RampMeasurement:
    """What the detectors of one metered on-ramp (direction d, interchange k) saw."""

    key: str  # "{d}{k}"
    direction: str
    interchange: int
    tls: str
    storage_veh: float
    occupancy_down_pct: float = 0.0  # mean over lanes, downstream of the merge [%]
    flow_down_vph: float = 0.0  # sum over lanes [veh/h]
    speed_down_mps: float = math.nan  # flow-weighted mean [m/s] (nan: nobody passed)
    occupancy_up_pct: float = 0.0  # upstream of the merge
    flow_up_vph: float = 0.0
    speed_up_mps: float = math.nan
    ramp_flow_vph: float = 0.0  # vehicles past the meter [veh/h]
    queue_veh: float = 0.0  # vehicles on the on-ramp storage now [veh]
    halting_veh: float = 0.0  # of which halting [veh]
    demand_vph: float = 0.0  # arrivals at the ramp over the last interval (outflow + queue growth)
    t_loops: float = -math.inf  # [s] end of the loop interval the loop values belong to
    ok_down: bool = True  # the downstream station's values of this interval arrived (False: held)
    ok_up: bool = True


@dataclass
class DetectorLog:
    """Time series of the queue samples (for monitors): t [s] and queue [veh] per ramp key."""

    t: list[float] = field(default_factory=list)
    queue: dict[str, list[float]] = field(default_factory=dict)


class RampDetectors(Component):
    """Reads the beltway's E1/E2 detectors into ``latest`` (per ramp) and ``log`` (queue samples)."""

    phase = Phase.SENSE
    provides: ClassVar[frozenset[str]] = frozenset({"ramp_detectors"})
    metrics: ClassVar[tuple[Metric, ...] | None] = (
        Metric('loops_failed', '1',
               'Loop detectors failed by the fault model.'),
    )
    period_source: ClassVar[str | None] = "p.period_s"  # [s] queue sampling

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        period_s: float = Field(5.0, gt=0)  # [s] queue sampling period (a multiple of dt)
        aggregate_s: float | None = Field(None, gt=0)  # [s] loop interval; None = the network's
        faults: LoopFaults = Field(default_factory=LoopFaults)  # failing loop stations (none by default)

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params or self.Params()
        self.latest: dict[str, RampMeasurement] = {}
        self.log = DetectorLog()
        self.new_on_origin: dict[int, list[str]] = {}
        self._seen_origin: set[str] = set()
        self.history: list[tuple[float, str, str, float, float, float]] = []  # (t, key, up|down, occ, q, v)
        self.passed_total: dict[str, int] = {}  # vehicles past each meter so far (completed intervals)
        self._queue_at_interval: dict[str, float] = {}
        self._next_aggregate_s = 0.0
        self.faults: dict[str, StationFault] = {}  # station "{key}/{up|down}" -> its fault
        self._failed_seen: set[str] = set()
        self._ctx: RunContext | None = None

    def setup(self, ctx: RunContext) -> None:
        lm = road_frame(ctx).tables.landmarks
        if not isinstance(lm, BeltwayLandmarks):
            raise ValueError(f"{self.name}: ramp detectors need the beltway network (no interchanges)")
        self.interchanges = lm.interchanges
        spec = road_spec(ctx.scenario) if ctx.scenario else None
        net = spec.network.params if spec is not None else BeltwayParams()  # the builder's typed params
        self.aggregate_s = self.p.aggregate_s or float(net.detector_period_s)
        self._next_aggregate_s = self.aggregate_s
        for ic in self.interchanges:
            for d in DIRECTIONS:
                r = ic.ramp(d)
                key = f"{d}{ic.index}"
                self.latest[key] = RampMeasurement(key=key, direction=d, interchange=int(ic.index),
                                                   tls=r.meter_tls, storage_veh=float(r.ramp_storage_veh))
                self.log.queue[key] = []
                self._queue_at_interval[key] = 0.0
                self.passed_total[key] = 0
        stations = [f"{key}/{side}" for key in self.latest for side in ("down", "up")]
        self.faults = draw_faults(self.p.faults, stations, ctx.rng(f"{self.name}/faults"))
        self._ctx = ctx

    def ramp(self, key: str) -> MeteredRamp:
        """Landmarks (edges, detector ids) of ramp ``"{d}{k}"``."""
        d = "ccw" if key.startswith("ccw") else "cw"
        return self.interchanges[int(key[len(d):])].ramp(d)

    def tick(self, ctx: RunContext) -> None:
        det = road_frame(ctx).detectors
        if det is None:  # before the road's first step
            det = DetectorFrame()
        self._sample_queues(det, ctx.t)
        self._sample_origins(det)
        if ctx.t + 1e-9 >= self._next_aggregate_s:
            self._read_loops(det, ctx.t)
            self._next_aggregate_s += self.aggregate_s

    def _sample_queues(self, det: DetectorFrame, t: float) -> None:
        self.log.t.append(t)
        for key, m in self.latest.items():
            k = det.area_index.get(self.ramp(key).e2_ramp)
            m.queue_veh = float(det.area_vehicles[k]) if k is not None else 0.0
            m.halting_veh = float(det.area_halting[k]) if k is not None else 0.0
            self.log.queue[key].append(m.queue_veh)

    def _sample_origins(self, det: DetectorFrame) -> None:
        """Vehicles on each origin arterial not seen before (candidates for route guidance)."""
        self.new_on_origin = {}
        for ic in self.interchanges:
            fresh = [v for v in det.edge_vehicles.get(ic.origin_edge, ()) if v not in self._seen_origin]
            self._seen_origin.update(fresh)
            self.new_on_origin[int(ic.index)] = fresh

    def _read_loops(self, det: DetectorFrame, t: float) -> None:
        """Last completed interval of every loop, aggregated per ramp; ramp demand by conservation."""
        span_h = self.aggregate_s / 3600.0
        for key, m in self.latest.items():
            r = self.ramp(key)
            down = self._faulty(f"{key}/down", t, Reading(*_loop_group(det, r.e1_downstream, span_h)),
                                Reading(m.occupancy_down_pct, m.flow_down_vph, m.speed_down_mps))
            up = self._faulty(f"{key}/up", t, Reading(*_loop_group(det, r.e1_upstream, span_h)),
                              Reading(m.occupancy_up_pct, m.flow_up_vph, m.speed_up_mps))
            m.occupancy_down_pct, m.flow_down_vph, m.speed_down_mps, m.ok_down = (
                down.occupancy_pct, down.flow_vph, down.speed_mps, down.ok)
            m.occupancy_up_pct, m.flow_up_vph, m.speed_up_mps, m.ok_up = up.occupancy_pct, up.flow_vph, up.speed_mps, up.ok
            k = det.loop_index.get(r.e1_ramp)
            passed = int(det.loop_count[k]) if k is not None else 0
            m.ramp_flow_vph = passed / span_h
            self.passed_total[key] += int(passed)
            growth = m.queue_veh - self._queue_at_interval[key]
            m.demand_vph = max(passed + growth, 0.0) / span_h
            self._queue_at_interval[key] = m.queue_veh
            m.t_loops = t
            self.history.append((t, key, "down", m.occupancy_down_pct, m.flow_down_vph, m.speed_down_mps))
            self.history.append((t, key, "up", m.occupancy_up_pct, m.flow_up_vph, m.speed_up_mps))


    def _faulty(self, station: str, t: float, true: Reading, held: Reading) -> Reading:
        """The station's values as the centre gets them (``loop_faults``); a failure is an event."""
        fault = self.faults.get(station)
        out = apply_fault(fault, t, true, held, self.p.faults.bias_factor)
        if fault is not None and t >= fault.t_fail_s and station not in self._failed_seen:
            self._failed_seen.add(station)
            if self._ctx is not None:
                self._ctx.events.emit(fault.t_fail_s, self.name, "loop_failure", f"{station}: {fault.mode}",
                                      station=station, mode=fault.mode)
        return out

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"loops_failed": len(self.faults)} if self.p.faults.share > 0 else {}


def _loop_group(det: DetectorFrame, ids: tuple[str, ...], span_h: float) -> tuple[float, float, float]:
    """(mean occupancy [%], total flow [veh/h], flow-weighted speed [m/s]) of loops across lanes."""
    k = [det.loop_index[i] for i in ids]
    n = det.loop_count[k]
    occ = det.loop_occupancy_pct[k]
    spd = det.loop_speed_mps[k]  # -1 when empty
    ok = (n > 0) & (spd >= 0)
    speed = float(np.sum(spd[ok] * n[ok]) / np.sum(n[ok])) if ok.any() else math.nan
    return float(occ.mean()), float(n.sum() / span_h), speed
