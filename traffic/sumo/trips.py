"""Trip bookkeeping of the road: departures, arrivals, free-flow times, delays, backlog, teleports.

A DETECT-phase monitor (registered as ``trips``, added to every road scenario by default) that reads
only the snapshot's road frame: its per-step events (departed / arrived / teleported uids, the
insertion backlog) and the run's static tables (depart time and insertion delay, route segments,
speed factor and top speed per uid).  ``traffic_kpis`` and ``ramp_kpis`` take delays from it (their
peer of role ``trips``, ``NEEDS_TRIPS``).

Delay of a vehicle = travel time + insertion delay - free-flow time of its route at its own desired
speed (``min(vmax, limit x speed factor)`` per segment).  Vehicles that had not arrived when the run
ended count (with ``unfinished``) with their delay so far: elapsed time minus the free-flow time of
the distance covered, or, still waiting to be inserted, their insertion delay.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.snapshot import RoadEvents, RoadFrame, RoadTables, Role

TRIPS = "trips"  # the name the default trips monitor runs under


def road_frame(ctx: RunContext) -> RoadFrame:
    """The snapshot's road frame (present from setup on when the scenario has a road)."""
    road = ctx.snapshot.road
    if road is None:
        raise ValueError("this component needs a road backend: add `road:` to the scenario")
    return road


NEEDS_ROAD = Need(role="road", hint="add `road:` to the scenario")
NEEDS_TRIPS = Need(role=TRIPS, hint=f"add the `{TRIPS}` monitor (added by default to road scenarios)")


def freeflow_s(segments: tuple[tuple[float, float], ...], speed_factor: float, max_speed: float) -> float:
    """Free-flow travel time [s] of a route at a driver's desired speed on each segment."""
    return sum(length / min(max_speed, limit * speed_factor) for length, limit in segments)


class Trips(Component):
    """Per-uid trip records (depart, arrive, free-flow time) kept from the road frame's events."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('vehicles_departed', 'veh',
               'Vehicles that entered the network.'),
        Metric('vehicles_arrived', 'veh',
               'Vehicles that reached their destination.'),
        Metric('vehicles_measured', 'veh',
               'Vehicles that departed after the warm-up (the ones delays are taken over).'),
        Metric('teleports', '1',
               'Vehicles SUMO teleported (jammed too long; collisions are counted by the collisions monitor).'),
        Metric('merge_failures', '1',
               'Ramp vehicles that reached the end of the acceleration lane without merging.'),
    )
    needs: ClassVar[dict[str, Need]] = {"road": NEEDS_ROAD}
    provides: ClassVar[frozenset[str]] = frozenset({TRIPS})
    period_source: ClassVar[str | None] = "peer:road"  # [s] the road's step

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __init__(self, name: str, params: Params | None = None, scenario: Any = None) -> None:
        super().__init__(name)
        self.arrive_s = np.zeros(0)  # per uid [s] (nan: not arrived)
        self.freeflow_s = np.zeros(0)  # per uid [s]
        self.n_departed = 0
        self.teleports = 0
        self.merge_failures = 0

    def setup(self, ctx: RunContext) -> None:
        self.tables: RoadTables = road_frame(ctx).tables
        self.last: RoadFrame | None = None

    def tick(self, ctx: RunContext) -> None:
        road = road_frame(ctx)
        self.last = road
        ev = road.events
        if not (len(ev.departed) or len(ev.arrived) or len(ev.teleported)):
            return  # most steps: nothing departed, arrived or teleported
        tb = self.tables
        if len(ev.departed):
            n = tb.n_uids
            if n > len(self.arrive_s):
                grow = max(256, n - len(self.arrive_s), len(self.arrive_s))
                self.arrive_s = np.concatenate([self.arrive_s, np.full(grow, np.nan)])
                self.freeflow_s = np.concatenate([self.freeflow_s, np.zeros(grow)])
            for k in ev.departed:
                self.freeflow_s[k] = freeflow_s(tb.route_segments[tb.route[k]], tb.speed_factor[k],
                                                tb.max_speed[k])
            self.n_departed = n
        if len(ev.arrived):
            self.arrive_s[ev.arrived] = road.t
        for k in ev.teleported:
            self.teleports += 1
            if k >= 0 and tb.role[k] == Role.RAMP:
                self.merge_failures += 1

    # ------------------------------------------------------------------ queries
    def _arrived(self) -> np.ndarray:
        return ~np.isnan(self.arrive_s[:self.n_departed])

    def departed_uids(self, warmup_s: float, role: int) -> np.ndarray:
        """uids of the vehicles of ``role`` that departed after the warm-up (arrived or not)."""
        tb, n = self.tables, self.n_departed
        return np.flatnonzero((tb.depart_s[:n] >= warmup_s) & (tb.role[:n] == role)).astype(np.int64)

    def measured_uids(self, warmup_s: float) -> np.ndarray:
        """uids of the vehicles that departed after the warm-up and arrived."""
        n = self.n_departed
        return np.flatnonzero(self._arrived() & (self.tables.depart_s[:n] >= warmup_s)).astype(np.int64)

    def arrivals_after(self, t_s: float) -> int:
        """Vehicles that arrived at their destination at or after ``t_s`` [s]."""
        return int(np.count_nonzero(self.arrive_s[:self.n_departed] >= t_s))

    def backlog(self) -> int:
        """Vehicles due to depart that could not be inserted yet, after the last step."""
        return self.last.events.backlog if self.last is not None else 0

    def delays(self, warmup_s: float, unfinished: bool = False) -> dict[str, np.ndarray]:
        """Travel-time delay [s] (incl. insertion delay) per arrived vehicle, by role.

        ``unfinished``: also count, with their delay so far (a lower bound), the vehicles that
        entered the demand after the warm-up but had not arrived when the run ended — those still
        on the road (elapsed time minus the free-flow time of the distance covered) and those still
        waiting to be inserted (their insertion delay).  Without them a control that jams the road
        would look better the fewer vehicles it lets through.
        """
        tb = self.tables
        out: dict[str, list[float]] = {"mainline": [], "ramp": []}
        for k in self.measured_uids(warmup_s):
            d = (self.arrive_s[k] - tb.depart_s[k]) + tb.depart_delay_s[k] - self.freeflow_s[k]
            out["ramp" if tb.role[k] == Role.RAMP else "mainline"].append(float(d))
        if unfinished and self.last is not None:
            for role, d in self._unfinished_delays(self.last, warmup_s):
                out[role].append(d)
        return {k: np.asarray(v) for k, v in out.items()}

    def _unfinished_delays(self, road: RoadFrame, warmup_s: float) -> list[tuple[str, float]]:
        tb, t = self.tables, road.t
        out = []
        for row, k in enumerate(road.uid):
            if tb.depart_s[k] < warmup_s or not math.isnan(self.arrive_s[k]):
                continue
            route_len = sum(length for length, _ in tb.route_segments[tb.route[k]]) or 1.0
            done = min(float(road.distance[row]) / route_len, 1.0)
            role = "ramp" if tb.role[k] == Role.RAMP else "mainline"
            out.append((role, float((t - tb.depart_s[k]) + tb.depart_delay_s[k] - self.freeflow_s[k] * done)))
        ev: RoadEvents = road.events
        for wait, role in zip(ev.pending_wait_s, ev.pending_role, strict=True):
            if t - wait >= warmup_s:
                out.append(("ramp" if role == Role.RAMP else "mainline", float(wait)))
        return out

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        warm = ctx.scenario.warmup if ctx.scenario is not None else 0.0
        return {
            "vehicles_departed": self.n_departed,
            "vehicles_arrived": int(np.count_nonzero(self._arrived())),
            "vehicles_measured": len(self.measured_uids(warm)),
            "teleports": self.teleports,
            "merge_failures": self.merge_failures,
        }
