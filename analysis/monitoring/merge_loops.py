"""Virtual loop detectors across the carriageway, and the bottleneck figures they show (``merge_loops``).

A DETECT-phase monitor that reads only the snapshot: a station is a line x = const (a landmark of the
network plus an offset); a vehicle is counted when its centre crosses the line between two road steps,
with its speed then (a spot speed).  Stations upstream of ``mainline_x_below`` count only vehicles of
the mainline (the ramp may cross the same x on its own road).  Per interval of ``interval_s`` each
station gives a flow [veh/h], a space-mean speed (the harmonic mean of the spot speeds) [m/s] and a
density q / v [veh/km]; they are recorded as signals ``loop_flow_vph_<station>``,
``loop_speed_mps_<station>``, ``loop_density_vpkm_<station>`` (the report's flow-time and flow-density
plots) and the run's row gets the breakdown figures of ``corridor.analysis.bottleneck``.

The ticks are processed in blocks of ``block_ticks`` (``corridor.analysis.monitoring.tick_block``): the
crossings of a block in one numpy pass, the intervals closed tick by tick (their signals recorded when
the block is processed, each with its interval's end time); the figures are those of tick-by-tick
processing, bit for bit (``tests/traffic/test_traffic_tick_block.py``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.analysis.bottleneck import analyse
from corridor.analysis.monitoring.tick_block import RoadTicks, TickBlock
from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.snapshot import Role
from corridor.traffic.sumo.trips import NEEDS_ROAD, road_frame


class Station(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    landmark: str  # a position of the network's landmarks (a field ending in _x)
    offset_m: float = 0.0  # [m] along +x from it


class MergeLoops(Component):
    """Counts crossings of each station per interval; breakdown and capacity drop at the end."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('breakdown', '1', "1 if the upstream station's speed fell at least 25 % below free flow and stayed so (HCM breakdown), else 0."),
        Metric('breakdown_s', 's', 'End of the loop interval at which the breakdown began (NaN: none).'),
        Metric('free_flow_speed_mps', 'm/s', 'Free-flow speed at the upstream station (given, or measured over the first minutes).'),
        Metric('prebreakdown_flow_vph', 'veh/h', 'Largest moving-average downstream flow before the breakdown (NaN: none).'),
        Metric('discharge_flow_vph', 'veh/h', 'Mean downstream (queue discharge) flow after the breakdown (NaN: none).'),
        Metric('capacity_drop_pct', '%', 'Capacity drop: 100 x (1 - discharge / pre-breakdown maximum flow) (NaN: no breakdown).'),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "peer:road"  # [s] every road step
    block_ticks: ClassVar[int] = 100  # ticks processed together (corridor.analysis.monitoring.tick_block)

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        stations: dict[str, Station] = Field(min_length=1)
        interval_s: float = Field(60.0, gt=0)  # [s] loop aggregation
        upstream: str = "up"  # the station whose speed shows the breakdown (inside the queue)
        downstream: str = "down"  # the station whose flow is the bottleneck's discharge
        mainline_below: str = "merge_x"  # landmark: stations before it count mainline vehicles only
        free_flow_speed_mps: float | None = Field(None, gt=0)  # None: measured at `upstream` over
        free_flow_window_s: float = Field(300.0, gt=0)  # [s] the first seconds of the run (low demand)
        speed_drop: float = Field(0.25, gt=0, lt=1)  # HCM breakdown: >= 25 % below free-flow speed
        sustain_s: float = Field(300.0, ge=0)  # [s] ... held this long
        window_s: float = Field(300.0, gt=0)  # [s] moving average for the pre-breakdown maximum
        transition_s: float = Field(120.0, ge=0)  # [s] left out after the breakdown

    def __init__(self, name: str, params: Params, scenario: Any = None) -> None:
        super().__init__(name)
        self.p = params
        for key in (params.upstream, params.downstream):
            if key not in params.stations:
                raise ValueError(f"{name}: station {key!r} is not among stations ({', '.join(params.stations)})")
        self.names = list(params.stations)
        self._x_prev = np.zeros(0)  # per uid: centre x at its previous road step [m] (nan: unseen)
        self._count = np.zeros(len(self.names))
        self._inv_speed = np.zeros(len(self.names))  # sum of 1 / spot speed [s/m]
        self._interval_end = params.interval_s
        self.t: list[float] = []
        self.flow: list[np.ndarray] = []  # per interval: [veh/h] per station
        self.speed: list[np.ndarray] = []  # [m/s] (nan: nobody crossed)
        self._block = TickBlock(self.block_ticks)

    def setup(self, ctx: RunContext) -> None:
        lm = road_frame(ctx).tables.landmarks
        self.line_x = np.array([lm.x(s.landmark) + s.offset_m for s in self.p.stations.values()])
        self.mainline_only = self.line_x < lm.x(self.p.mainline_below)

    def tick(self, ctx: RunContext) -> None:
        road_frame(ctx)
        if self._block.add(ctx.t, ctx.snapshot):
            self._process(ctx)

    def _process(self, ctx: RunContext) -> None:
        """The held ticks at once: the block's crossings in one numpy pass, then the intervals closed
        tick by tick, each tick's counts and spot speeds added as one tick-by-tick step adds them."""
        b = self._block.take()
        if b is None:
            return
        tb = road_frame(ctx).tables
        crossed = self._crossings(b, tb.role, tb.n_uids)  # (block rows, stations)
        hit = np.flatnonzero(crossed.any(axis=1))
        ticks = np.unique(b.tick[hit]).tolist()
        vel = b.rows_of("velocity") if len(hit) else np.zeros((0, 3))
        due = iter(ticks)
        k_next = next(due, -1)
        for k, t in enumerate(b.t.tolist()):
            if k == k_next:  # the tick's rows, as (crossed / v).sum(axis=0) of a tick-by-tick step
                rows = slice(int(b.starts[k]), int(b.starts[k] + b.rows[k]))
                c = crossed[rows]
                self._count += c.sum(axis=0)
                self._inv_speed += (c / np.maximum(np.hypot(vel[rows, 0], vel[rows, 1]), 0.1)[:, None]).sum(axis=0)
                k_next = next(due, -1)
            while t + 1e-9 >= self._interval_end:
                self._close_interval(ctx)

    def _crossings(self, b: RoadTicks, role: np.ndarray, n_uids: int) -> np.ndarray:
        """Which station each row of the block crossed since its vehicle's previous row (rows, stations)."""
        if len(self._x_prev) < n_uids:
            self._x_prev = np.concatenate([self._x_prev, np.full(n_uids + 256 - len(self._x_prev), np.nan)])
        uid = b.road("uid")
        if not len(uid):
            return np.zeros((0, len(self.names)), dtype=bool)
        x = b.rows_of("position")[:, 0]
        # each vehicle's rows in tick order: its x at its previous row (the first: the previous block's)
        order = np.argsort(uid.astype(np.uint16) if n_uids <= 1 << 16 else uid, kind="stable")
        u, xo = uid[order], x[order]
        first = np.empty(len(u), dtype=bool)
        first[0], first[1:] = True, u[1:] != u[:-1]
        before_o = np.empty(len(u))
        before_o[1:] = xo[:-1]
        before_o[first] = self._x_prev[u[first]]
        last = np.empty(len(u), dtype=bool)
        last[:-1], last[-1] = first[1:], True
        self._x_prev[u[last]] = xo[last]
        before = np.empty(len(u))
        before[order] = before_o
        crossed = (before[:, None] < self.line_x[None, :]) & (x[:, None] >= self.line_x[None, :])
        crossed &= ~(self.mainline_only[None, :] & (role[uid] == Role.RAMP)[:, None])
        return crossed

    def _close_interval(self, ctx: RunContext) -> None:
        t = self._interval_end
        flow = self._count * 3600.0 / self.p.interval_s
        with np.errstate(divide="ignore", invalid="ignore"):
            speed = np.where(self._count > 0, self._count / self._inv_speed, np.nan)
        for k, name in enumerate(self.names):
            ctx.signals.record(f"loop_flow_vph_{name}", t, flow[k])
            ctx.signals.record(f"loop_speed_mps_{name}", t, speed[k])
            ctx.signals.record(f"loop_density_vpkm_{name}", t, flow[k] / speed[k] / 3.6 if speed[k] > 0 else np.nan)
        self.t.append(t)
        self.flow.append(flow)
        self.speed.append(speed)
        self._count = np.zeros(len(self.names))
        self._inv_speed = np.zeros(len(self.names))
        self._interval_end += self.p.interval_s

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._process(ctx)
        if not self.t:
            return {}
        t, flow, speed = np.array(self.t), np.array(self.flow), np.array(self.speed)
        up, down = self.names.index(self.p.upstream), self.names.index(self.p.downstream)
        ffs = self.p.free_flow_speed_mps
        if ffs is None:
            early = speed[t <= self.p.free_flow_window_s, up]
            ffs = float(np.nanmean(early)) if np.isfinite(early).any() else math.nan
        b = analyse(t, speed[:, up], flow[:, down], self.p.interval_s, ffs, self.p.speed_drop,
                    self.p.sustain_s, self.p.window_s, self.p.transition_s)
        return {"free_flow_speed_mps": b.free_flow_speed_mps, "breakdown": float(b.occurred),
                "breakdown_s": b.breakdown_s, "prebreakdown_flow_vph": b.prebreakdown_flow_vph,
                "discharge_flow_vph": b.discharge_flow_vph, "capacity_drop_pct": 100.0 * b.capacity_drop}
