"""Road monitors: surrogate safety (TTC, DRAC, hard braking) and traffic KPIs (throughput past the
merge, travel-time delay of mainline and ramp vehicles).  They read only the snapshot's road frame
(lane codes, positions along the lane, accelerations, the static tables) and the ``trips`` peer."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.analysis.monitoring.tick_block import TickBlock
from corridor.analysis.safety import lane_leaders, ttc_drac
from corridor.analysis.stats import jain_index
from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.snapshot import RoadTables, Role
from corridor.traffic.sumo.road_spec import check_landmark_positions
from corridor.traffic.sumo.trips import NEEDS_ROAD, NEEDS_TRIPS, road_frame


class SurrogateSafety(Component):
    """Minimum TTC, maximum DRAC, time exposed to TTC below a threshold, hard-braking events.

    No closing pair (no follower faster than its leader after the warm-up): ``min_ttc_s`` is NaN (a
    missing value: means skip it, the summary counts the runs without it), and the ``min_ttc`` signal
    is +inf at a tick without one (the time to collision is infinite, so ``G(min_ttc > 1.5)`` holds).

    The ticks are processed in blocks of ``block_ticks`` (``corridor.analysis.monitoring.tick_block``; the
    ``min_ttc`` signal is recorded when a block is processed, each value with its own tick's time)."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('min_ttc_s', 's',
               'Smallest time-to-collision over leader-follower pairs after the warm-up.'),
        Metric('max_drac_mps2', 'm/s^2',
               'Largest deceleration rate to avoid a crash after the warm-up.'),
        Metric('ttc_exposed_s', 's',
               'Time exposed to a TTC below the threshold, summed over vehicles (TET).'),
        Metric('hard_brakes', '1',
               'Times a vehicle started braking harder than the hard-brake threshold.'),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    period_source: ClassVar[str | None] = "peer:road"  # [s] the road's step
    block_ticks: ClassVar[int] = 100

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        ttc_threshold_s: float = Field(1.5, gt=0)  # for time exposed (TET)
        hard_brake_mps2: float = Field(-4.5, lt=0)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.warmup = scenario.warmup
        self.min_ttc, self.max_drac, self.tet = np.inf, 0.0, 0.0
        self.hard_brakes = 0
        self._braking = np.zeros(0, dtype=bool)  # per uid: was braking hard at its previous tick
        self._block = TickBlock(self.block_ticks)

    def setup(self, ctx: RunContext) -> None:
        road_frame(ctx)  # fails early without a road

    def tick(self, ctx: RunContext) -> None:
        road_frame(ctx)
        if self._block.add(ctx.t, ctx.snapshot):
            self._process(ctx)

    def _process(self, ctx: RunContext) -> None:
        b = self._block.take()
        if b is None:
            return
        uid, lane, lane_pos, accel = b.road("uid"), b.road("lane"), b.road("lane_pos"), b.road("accel")
        vel, length = b.rows_of("velocity"), b.rows_of("size")[:, 0]
        counting = b.t >= self.warmup  # per tick
        self._hard_brakes(uid, accel < self.p.hard_brake_mps2, counting[b.tick], road_frame(ctx).tables.n_uids)
        f, lead = lane_leaders(lane, lane_pos, group=b.tick)  # the pairs of each tick, in its order
        speed = np.hypot(vel[:, 0], vel[:, 1])  # [m/s] (WorldSnapshot.speed)
        ttc, drac = ttc_drac(lane_pos[lead] - length[lead] - lane_pos[f], speed[f], speed[lead])
        at = b.tick[f]
        ttc_now = np.full(len(b), np.inf)
        np.minimum.at(ttc_now, at, ttc)
        counted = counting[at]
        if counted.any():
            self.min_ttc = min(self.min_ttc, float(np.minimum.reduce(ttc[counted])))
            self.max_drac = max(self.max_drac, float(np.maximum.reduce(drac[counted])))
            exposed = np.bincount(at[ttc < self.p.ttc_threshold_s], minlength=len(b))
            for k in exposed[counting & (exposed > 0)].tolist():  # tick by tick, as the sum was taken
                self.tet += float(k) * self.period
        ctx.signals.record_many("min_ttc", b.t, ttc_now)

    def _hard_brakes(self, uid: np.ndarray, braking: np.ndarray, counting: np.ndarray, n_uids: int) -> None:
        """Count the rows where a vehicle starts braking hard (not braking at its previous tick)."""
        if len(self._braking) < n_uids:
            self._braking = np.concatenate([self._braking, np.zeros(n_uids + 256, dtype=bool)])
        if not len(uid):
            return
        # each vehicle's rows in tick order (uids below 2**16: numpy's radix sort, the same order)
        order = np.argsort(uid.astype(np.uint16) if n_uids <= 1 << 16 else uid, kind="stable")
        u, now = uid[order], braking[order]
        first = np.empty(len(u), dtype=bool)
        first[0], first[1:] = True, u[1:] != u[:-1]
        before = np.empty(len(u), dtype=bool)
        before[0], before[1:] = False, now[:-1]
        before[first] = self._braking[u[first]]
        self.hard_brakes += int(np.count_nonzero(now & ~before & counting[order]))
        last = np.empty(len(u), dtype=bool)
        last[:-1], last[-1] = first[1:], True
        self._braking[u[last]] = now[last]

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._process(ctx)
        return {"min_ttc_s": self.min_ttc if math.isfinite(self.min_ttc) else math.nan, "max_drac_mps2": self.max_drac,
                "ttc_exposed_s": self.tet, "hard_brakes": self.hard_brakes}


class MergeArea(BaseModel):
    """A stretch of road around the merge, by landmark x positions of the network [m]."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    start_landmark: str = "merge_start_x"
    before_m: float = Field(300.0, ge=0)  # [m] upstream of the start landmark
    end_landmark: str = "merge_end_x"
    after_m: float = Field(300.0, ge=0)  # [m] downstream of the end landmark


class TrafficKpis(Component):
    """Throughput past a line (the merge end), travel-time delay by role (mainline / ramp) with
    Jain's fairness index between the two mean delays, an energy proxy (mean over arrived
    vehicles of ∫ a² dt), and total time spent (``tts_vh``: vehicles on the road plus vehicles
    waiting to be inserted, integrated after the warm-up).

    Delay is taken over every vehicle that entered the demand after the warm-up: vehicles that had
    not arrived when the run ended count with their delay so far (see ``Trips.delays``), and
    ``insertion_backlog`` is the number still waiting to enter the network at the end."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('throughput_vph', 'veh/h',
               'Vehicles crossing the counting line (past the merge) per hour after the warm-up.'),
        Metric('tts_vh', 'veh*h',
               'Total time spent: vehicles on the road plus waiting to enter, integrated after the warm-up.'),
        Metric('insertion_backlog', 'veh',
               'Vehicles still waiting to enter the network at the end.'),
        Metric('delay_mean_s', 's',
               'Mean travel-time delay of the measured vehicles (unfinished trips count with their delay so far).'),
        Metric('delay_total_vh', 'veh*h',
               'Summed delay of the measured vehicles.'),
        Metric('delay_*_mean_s', 's',
               'Mean delay by role (mainline, ramp).'),
        Metric('delay_*_p95_s', 's',
               '95th percentile of the delay by role (mainline, ramp).'),
        Metric('n_*', 'veh',
               'Measured vehicles by role (mainline, ramp).'),
        Metric('delay_jain_index', '1',
               "Jain's fairness index between the mainline and ramp mean delays (1: equal)."),
        Metric('energy_proxy_mean', 'm^2/s^3',
               'Mean over arrived vehicles of the integral of acceleration squared.'),
        Metric('merge_loss_*_s', 's',
               'Mean time lost inside the merge area per vehicle, by role (mainline, ramp, mean: all).'),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD, "trips": NEEDS_TRIPS}
    period_source: ClassVar[str | None] = "peer:road"  # [s] the road's step
    block_ticks: ClassVar[int] = 100  # ticks processed together (corridor.analysis.monitoring.tick_block)

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
        count_landmark: str | None = "past_merge_x"  # network landmark giving the counting line x [m];
        #   None (a network without one, e.g. a user's own): throughput counts arrivals at destinations
        merge_area: MergeArea | None = None  # time loss inside this stretch, reported on its own
        prefix: str = Field("", max_length=32, pattern=r"^[A-Za-z0-9_.]*$")  # column prefix, e.g. "traffic."

    @classmethod
    def check_scenario(cls, params: Params, scenario: Any) -> None:
        """At load: the counting line and the merge area are positions the road's network has."""
        hint = {"count_landmark": params.count_landmark}
        if params.merge_area is not None:
            hint |= {"merge_area.start_landmark": params.merge_area.start_landmark,
                     "merge_area.end_landmark": params.merge_area.end_landmark}
        try:
            check_landmark_positions(scenario, hint)
        except ValueError as exc:
            raise ValueError(f"{exc} (count_landmark: null counts arrivals instead)"
                             if "count_landmark" in str(exc) else str(exc)) from None

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.p = params
        self.warmup = scenario.warmup
        self.passed = np.zeros(0, dtype=bool)  # per uid
        self.energy = np.zeros(0)  # per uid: ∫ a² dt [m²/s³] after warm-up
        self.area_loss = np.zeros(0)  # per uid: time lost inside the merge area [s]
        self.in_area = np.zeros(0, dtype=bool)  # per uid: was seen inside it
        self.count = 0
        self.tts_vh = 0.0
        self._block = TickBlock(self.block_ticks)

    def setup(self, ctx: RunContext) -> None:
        lm = road_frame(ctx).tables.landmarks
        self.line_x = lm.x(self.p.count_landmark) if self.p.count_landmark is not None else None
        a = self.p.merge_area
        self.area_x = (lm.x(a.start_landmark) - a.before_m, lm.x(a.end_landmark) + a.after_m) if a else None

    def tick(self, ctx: RunContext) -> None:
        r = road_frame(ctx)
        n = len(r)
        if ctx.t >= self.warmup:
            self.tts_vh += (n + r.events.backlog) * self.period / 3600.0
        if n == 0:
            return
        if self._block.add(ctx.t, ctx.snapshot):
            self._process(ctx)

    def _process(self, ctx: RunContext) -> None:
        """The held ticks (with vehicles) at once; every per-uid sum is added in tick order."""
        b = self._block.take()
        if b is None:
            return
        tb = road_frame(ctx).tables
        if len(self.passed) < tb.n_uids:
            grow = tb.n_uids + 256
            self.passed = np.concatenate([self.passed, np.zeros(grow, dtype=bool)])
            self.energy = np.concatenate([self.energy, np.zeros(grow)])
            self.area_loss = np.concatenate([self.area_loss, np.zeros(grow)])
            self.in_area = np.concatenate([self.in_area, np.zeros(grow, dtype=bool)])
        uid, lane, accel = b.road("uid"), b.road("lane"), b.road("accel")
        x, vel = b.rows_of("position")[:, 0], b.rows_of("velocity")
        counting = (b.t >= self.warmup)[b.tick]  # per row
        speed = np.hypot(vel[:, 0], vel[:, 1])  # [m/s] (WorldSnapshot.speed)
        np.add.at(self.energy, uid[counting], (accel * accel * self.period)[counting])  # sequential: tick order
        if self.area_x is not None:
            self._merge_area_loss(tb, uid, lane, x, speed)
        ctx.signals.record_many("vehicles", b.t, b.rows)
        ctx.signals.record_many("mean_speed", b.t, [float(np.add.reduce(speed[k:k + n])) / n  # = speed.mean()
                                                    for k, n in zip(b.starts.tolist(), b.rows.tolist(), strict=True)])
        if self.line_x is not None:
            self._count_past_line(uid, x, counting)

    def _count_past_line(self, uid: np.ndarray, x: np.ndarray, counting: np.ndarray) -> None:
        """Count each vehicle once, at its first row past the counting line."""
        past = np.flatnonzero(x > self.line_x)
        seen, first = np.unique(uid[past], return_index=True)  # each vehicle's first row past the line
        new = past[first[~self.passed[seen]]]  # ... unless it was counted in an earlier block
        self.passed[seen] = True
        self.count += int(np.count_nonzero(counting[new]))

    def _merge_area_loss(self, tb: RoadTables, uid: np.ndarray, lane: np.ndarray, x: np.ndarray,
                         speed: np.ndarray) -> None:
        """SUMO's time loss, dt·(1 − v / v_desired), of every vehicle inside the merge area; v_desired
        is its own desired speed on its lane, min(top speed, limit · speed factor)."""
        inside = np.flatnonzero((x >= self.area_x[0]) & (x <= self.area_x[1]))
        if not len(inside):
            return
        uid, code = uid[inside], lane[inside]
        v_des = np.minimum(tb.max_speed[uid], tb.lane_speed_limit[code] * tb.speed_factor[uid])
        np.add.at(self.area_loss, uid, self.period * np.minimum(np.maximum(1.0 - speed[inside] / v_des, 0.0), 1.0))
        self.in_area[uid] = True

    def _area_metrics(self) -> dict[str, float]:
        """Mean time lost inside the merge area per measured vehicle (departed after the warm-up,
        seen in the area), by role: the part of the delay that the merge itself causes."""
        out, both = {}, []
        for role, code in (("mainline", Role.MAINLINE), ("ramp", Role.RAMP)):
            uids = self.trips.departed_uids(self.warmup, code)
            uids = uids[uids < len(self.in_area)]
            lost = self.area_loss[uids[self.in_area[uids]]]
            out[f"merge_loss_{role}_s"] = float(lost.mean()) if len(lost) else np.nan
            both.append(lost)
        lost = np.concatenate(both)
        out["merge_loss_mean_s"] = float(lost.mean()) if len(lost) else np.nan
        return out

    SHARED: ClassVar[tuple[str, ...]] = ("throughput_vph", "tts_vh", "insertion_backlog", "delay_mean_s",
                                         "delay_total_vh")  # names other KPI monitors use too

    def metric_columns(self) -> frozenset[str]:
        return frozenset(self.p.prefix + c for c in self.SHARED)

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        self._process(ctx)
        out = self._finish(ctx)
        return {self.p.prefix + k: v for k, v in out.items()} if self.p.prefix else out

    def _finish(self, ctx: RunContext) -> dict[str, Any]:
        span_h = (ctx.duration - self.warmup) / 3600.0
        count = self.count if self.line_x is not None else self.trips.arrivals_after(self.warmup)
        out: dict[str, Any] = {"throughput_vph": count / span_h, "tts_vh": self.tts_vh}
        delays = self.trips.delays(self.warmup, unfinished=True)
        out["insertion_backlog"] = self.trips.backlog()
        for role, d in delays.items():
            out[f"delay_{role}_mean_s"] = float(d.mean()) if len(d) else np.nan
            out[f"delay_{role}_p95_s"] = float(np.percentile(d, 95)) if len(d) else np.nan
            out[f"n_{role}"] = len(d)
        both = np.concatenate(list(delays.values()))
        means = [out["delay_mainline_mean_s"], out["delay_ramp_mean_s"]]
        out["delay_jain_index"] = jain_index(np.maximum(means, 0.0)) if all(np.isfinite(means)) else np.nan
        measured = self.trips.measured_uids(self.warmup)
        out["energy_proxy_mean"] = float(self.energy[measured].mean()) if len(measured) else np.nan
        out["delay_mean_s"] = float(both.mean()) if len(both) else np.nan
        out["delay_total_vh"] = float(both.sum() / 3600.0)
        if self.area_x is not None:
            out.update(self._area_metrics())
        return out
