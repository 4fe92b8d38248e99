"""UAV separation monitor: separation minima, loss of separation, NMAC, time to goal, path ratio.

Reads only the world snapshot (every UAV and AIRCRAFT entity), all pairs at once with numpy.

Thresholds (Params; the scenario may override each):

- **NMAC** ``nmac_h_m = 30.48`` m (100 ft) horizontal AND ``nmac_v_m = 4.572`` m (15 ft) vertical:
  the small-UAS near mid-air collision cylinder of Weinert et al., "Well-Clear Recommendation for
  Small Unmanned Aircraft Systems Based on Unmitigated Collision Risk", J. Air Transportation 26(3),
  2018 (also ``controllers.uav_models.NMAC_*``). Used for every pair, piloted or not.
- **Loss of separation, UAV-UAV** ``los_h_m = 60.96`` m (200 ft), ``los_v_m = 15.24`` m (50 ft):
  no standard exists for UAV-to-UAV separation; corridor uses twice the sNMAC cylinder in both
  axes (a design choice, stated here so that reports are read with it in mind).
- **Loss of separation, UAV-piloted** ``los_piloted_h_m = 609.6`` m (2000 ft), ``los_piloted_v_m =
  76.2`` m (250 ft): the sUAS "well clear" volume recommended by Weinert et al. 2018 (adopted by ASTM
  F3442/F3442M-20 for small UAS detect and avoid).

A pair *enters* a violated state when both its horizontal and vertical separation fall below the
thresholds; each entry counts once (an encounter that stays inside for many ticks is one event) and
emits an event (``los`` or ``nmac``). Signals ``min_sep_h`` (smallest horizontal separation over all
pairs) and ``min_sep_3d`` (smallest 3-D distance) are recorded at the monitor's period for reports,
STL specs and the Rerun view. ``sep_min_v_m`` is the smallest vertical separation of pairs closer
than ``nmac_h_m`` horizontally (NaN if no pair came that close).

Between ticks (continuous detection, ``corridor.analysis.ccd``): the aircraft are taken to move on
straight lines from the previous tick's positions to the current ones, so every pair's relative
position moves on a segment. The minima (``sep_min_*`` and the signals, each the minimum over the
interval that ends at the tick) use that segment's closest approach, and a pair that passes through
a NMAC or LoS cylinder between two ticks (the exact sub-interval where both the horizontal and the
vertical separation are below their thresholds is non-empty) enters the violated state even if it is
outside at both ticks. Pairs with an aircraft that moved more than ``ccd.MAX_STEP_M`` in one interval
(a teleport) and ticks where the set of aircraft changed are checked at the tick only. Per UAV with a goal (from the air backend): time to goal (first time
within ``goal_radius_m``) and the ratio of flown path length to the straight start-goal distance.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.analysis.ccd import MAX_STEP_M, closest_approach, interval_below
from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.snapshot import Kind


class SeparationMonitor(Component):
    """DETECT-phase monitor of aircraft separation (registered as ``uav_separation``)."""

    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('nmac', '1',
               'Near mid-air collisions: aircraft pairs entering the NMAC cylinder (horizontal and vertical thresholds of the monitor).', safety_event=True),
        Metric('los', '1',
               'Losses of separation: aircraft pairs entering the loss-of-separation cylinder.', safety_event=True),
        Metric('nmac_pairs', '1',
               'Distinct aircraft pairs that had an NMAC.', safety_event=True),
        Metric('sep_min_h_m', 'm',
               'Smallest horizontal distance between any two aircraft (continuous closest approach).'),
        Metric('sep_min_v_m', 'm',
               'Smallest vertical distance between two aircraft while horizontally close (NaN: never close).'),
        Metric('sep_min_3d_m', 'm',
               'Smallest 3-D distance between any two aircraft.'),
        Metric('goal_reached_frac', '1',
               'Share of the UAVs that reached their goal.'),
        Metric('time_to_goal_mean_s', 's',
               'Mean time to reach the goal over the UAVs that reached it.'),
        Metric('time_to_goal_max_s', 's',
               'Longest time to reach the goal over the UAVs that reached it.'),
        Metric('path_ratio_mean', '1',
               'Mean over UAVs of flown path length / straight start-goal distance.'),
        Metric('path_ratio_max', '1',
               'Largest flown path length / straight start-goal distance.'),
    )
    # the air backend holding the goals (none: no goal metrics)
    needs: ClassVar[dict[str, Need]] = {"air": Need(role="air", name_at="params.backend", optional=True)}
    air: Any = None  # that peer (set by the engine at build)
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        nmac_h_m: float = Field(30.48, gt=0.0)  # [m] 100 ft
        nmac_v_m: float = Field(4.572, gt=0.0)  # [m] 15 ft
        los_h_m: float = Field(60.96, gt=0.0)  # [m] 200 ft
        los_v_m: float = Field(15.24, gt=0.0)  # [m] 50 ft
        los_piloted_h_m: float = Field(609.6, gt=0.0)  # [m] 2000 ft
        los_piloted_v_m: float = Field(76.2, gt=0.0)  # [m] 250 ft
        goal_radius_m: float = Field(5.0, gt=0.0)  # [m]
        backend: str | None = "air"  # air backend holding the goals (None: no goal metrics)
        track_period_s: float | None = Field(1.0, gt=0.0, le=3600.0)  # [s] between recorded positions
        # (signals track_e_<id>, track_n_<id>, track_u_<id> [m] ENU, for the report's trajectory plots;
        # None: none recorded)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.ids: np.ndarray | None = None
        self.min_h = self.min_3d = np.inf
        self.min_v_close = np.inf  # [m] min vertical separation among pairs closer than nmac_h_m
        self.los_events = self.nmac_events = 0  # pair-encounters entering LoS / NMAC (whole run)
        self._next_track_s = 0.0  # [s] next time positions are recorded

    # ---- pair geometry ---------------------------------------------------------------------------
    def _init_pairs(self, ids: np.ndarray, kind: np.ndarray) -> None:
        n = len(ids)
        self.ids = ids.copy()
        self.i, self.j = np.triu_indices(n, k=1)
        piloted = kind == Kind.AIRCRAFT
        mixed = piloted[self.i] | piloted[self.j]
        p = self.params
        self.los_h = np.where(mixed, p.los_piloted_h_m, p.los_h_m)
        self.los_v = np.where(mixed, p.los_piloted_v_m, p.los_v_m)
        self.in_los = np.zeros(len(self.i), dtype=bool)
        self.in_nmac = np.zeros(len(self.i), dtype=bool)
        self.pair_los = np.zeros(len(self.i), dtype=int)
        self.pair_nmac = np.zeros(len(self.i), dtype=int)
        self.last_pos: np.ndarray | None = None
        self.path_m = np.zeros(n)
        self.arrived_s = np.full(n, np.nan)

    def setup(self, ctx: RunContext) -> None:
        self.goals: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        if self.air is not None:
            self.goals = self.air.goals()

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        air = (s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT)
        ids, pos = s.ids[air], s.position[air]
        if len(ids) == 0:
            return
        if self.ids is None or len(ids) != len(self.ids) or np.any(ids != self.ids):
            self._init_pairs(ids, s.kind[air])
        prev = self.last_pos
        self._progress(ctx.t, pos)
        self._record_tracks(ctx, ids, pos)
        if len(self.i) == 0:
            return
        d = pos[self.i] - pos[self.j]
        dh = np.hypot(d[:, 0], d[:, 1])
        dv = np.abs(d[:, 2])
        d3 = np.hypot(dh, dv)
        p = self.params
        now_los = (dh < self.los_h) & (dv < self.los_v)
        now_nmac = (dh < p.nmac_h_m) & (dv < p.nmac_v_m)
        # between ticks: the minima of the straight-line relative motion, and cylinders passed through
        swept = self._swept(prev, pos, d) if prev is not None else None
        if swept is None:
            min_h, min_3d = float(dh.min()), float(d3.min())
            close = dh < p.nmac_h_m
            min_v_close = float(dv[close].min()) if close.any() else np.inf
            in_los, in_nmac, at_los, at_nmac = now_los, now_nmac, (dh, dv), (dh, dv)
        else:
            min_h, min_3d, min_v_close, (in_los, at_los), (in_nmac, at_nmac) = swept
            in_los, in_nmac = in_los | now_los, in_nmac | now_nmac
        self.min_h = min(self.min_h, min_h)
        self.min_3d = min(self.min_3d, min_3d)
        self.min_v_close = min(self.min_v_close, min_v_close)
        ctx.signals.record("min_sep_h", ctx.t, min_h)
        ctx.signals.record("min_sep_3d", ctx.t, min_3d)
        self.in_los = self._count(ctx, in_los, now_los, self.in_los, self.pair_los, "los", dh, dv, at_los)
        self.in_nmac = self._count(ctx, in_nmac, now_nmac, self.in_nmac, self.pair_nmac, "nmac", dh, dv, at_nmac)

    def _record_tracks(self, ctx: RunContext, ids: np.ndarray, pos: np.ndarray) -> None:
        """Every ``track_period_s``: each aircraft's ENU position, as signals for trajectory plots."""
        period = self.params.track_period_s
        if period is None or ctx.t + 1e-9 < self._next_track_s:
            return
        self._next_track_s = ctx.t + period
        for vid, (e, n, u) in zip(ids, pos):
            ctx.signals.record(f"track_e_{vid}", ctx.t, float(e))
            ctx.signals.record(f"track_n_{vid}", ctx.t, float(n))
            ctx.signals.record(f"track_u_{vid}", ctx.t, float(u))

    def _swept(self, prev: np.ndarray, pos: np.ndarray, d1: np.ndarray) -> tuple | None:
        """Minima and cylinder passes of the straight-line motion from ``prev`` to ``pos``; None when
        no pair can be swept. Teleported pairs keep their values at the tick."""
        moved = np.linalg.norm(pos - prev, axis=1) <= MAX_STEP_M
        ok = moved[self.i] & moved[self.j]
        if not ok.any():
            return None
        d0 = np.where(ok[:, None], prev[self.i] - prev[self.j], d1)  # teleported: static at the tick
        _, dh_min = closest_approach(d0[:, :2], d1[:, :2])
        _, d3_min = closest_approach(d0, d1)
        p = self.params
        lo_h, hi_h = interval_below(d0[:, :2], d1[:, :2], p.nmac_h_m)
        z0, z1 = d0[:, 2], d1[:, 2]
        # smallest |dz| while horizontally inside the NMAC radius (dz is linear in s)
        close = lo_h < hi_h
        zl, zh = z0 + lo_h * (z1 - z0), z0 + hi_h * (z1 - z0)
        v_close = np.where(zl * zh <= 0.0, 0.0, np.minimum(np.abs(zl), np.abs(zh)))
        min_v_close = float(v_close[close].min()) if close.any() else np.inf

        def passes(r_h: np.ndarray | float, r_v: np.ndarray | float) -> tuple[np.ndarray, tuple]:
            lo_a, hi_a = interval_below(d0[:, :2], d1[:, :2], r_h)
            lo_b, hi_b = interval_below(d0[:, 2:], d1[:, 2:], r_v)
            lo, hi = np.maximum(lo_a, lo_b), np.minimum(hi_a, hi_b)
            mid = (0.5 * (lo + hi))[:, None]
            at = d0 + mid * (d1 - d0)  # a point of the pass (for the event text)
            return lo < hi, (np.hypot(at[:, 0], at[:, 1]), np.abs(at[:, 2]))

        return (float(dh_min.min()), float(d3_min.min()), min_v_close,
                passes(self.los_h, self.los_v), passes(p.nmac_h_m, p.nmac_v_m))

    def _count(self, ctx: RunContext, entered: np.ndarray, now: np.ndarray, before: np.ndarray,
               per_pair: np.ndarray, kind: str, dh: np.ndarray, dv: np.ndarray,
               at: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Count and report pairs that entered the violated state since the last tick (at the tick or
        between ticks); returns the state at this tick."""
        for k in np.flatnonzero(entered & ~before):
            # at the tick, or (passed through between ticks) a point of the pass
            h_m, v_m = (float(dh[k]), float(dv[k])) if now[k] else (float(at[0][k]), float(at[1][k]))
            a, b = str(self.ids[self.i[k]]), str(self.ids[self.j[k]])
            per_pair[k] += 1
            if kind == "nmac":
                self.nmac_events += 1
            else:
                self.los_events += 1
            ctx.events.emit(ctx.t, self.name, kind, f"{a} x {b}: {h_m:.1f} m horizontal, {v_m:.1f} m vertical",
                            a=a, b=b, h_m=h_m, v_m=v_m)
        return now

    def _progress(self, t: float, pos: np.ndarray) -> None:
        """Path length and first arrival at the goal, per aircraft."""
        if self.last_pos is not None:
            self.path_m += np.linalg.norm(pos - self.last_pos, axis=1)
        self.last_pos = pos.copy()
        for k, aid in enumerate(self.ids):
            g = self.goals.get(str(aid))
            if g is not None and np.isnan(self.arrived_s[k]) and np.linalg.norm(pos[k] - g[1]) < self.params.goal_radius_m:
                self.arrived_s[k] = t

    # ---- results ---------------------------------------------------------------------------------
    def per_uav(self) -> dict[str, dict[str, float]]:
        """Per aircraft with a goal: time to goal [s] (NaN if never) and path-length ratio."""
        out = {}
        if self.ids is None:
            return out
        for k, aid in enumerate(self.ids):
            g = self.goals.get(str(aid))
            if g is not None:
                straight = float(np.linalg.norm(g[1] - g[0]))
                out[str(aid)] = {"time_to_goal_s": float(self.arrived_s[k]),
                                 "path_ratio": float(self.path_m[k] / max(straight, 1e-9))}
        return out

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        out: dict[str, Any] = {
            "nmac": self.nmac_events,
            "los": self.los_events,
            "nmac_pairs": int(np.count_nonzero(self.pair_nmac)) if self.ids is not None else 0,
            "sep_min_h_m": float(self.min_h),
            "sep_min_v_m": float(self.min_v_close) if np.isfinite(self.min_v_close) else float("nan"),
            "sep_min_3d_m": float(self.min_3d),
        }
        return {**out, **self._goal_metrics()}

    def _goal_metrics(self) -> dict[str, float]:
        nan = float("nan")
        per = self.per_uav()
        if not per:
            return dict.fromkeys(("goal_reached_frac", "time_to_goal_mean_s", "time_to_goal_max_s",
                                  "path_ratio_mean", "path_ratio_max"), nan)
        ttg = np.array([v["time_to_goal_s"] for v in per.values()])
        ratio = np.array([v["path_ratio"] for v in per.values()])
        reached = ~np.isnan(ttg)
        return {
            "goal_reached_frac": float(reached.mean()),
            "time_to_goal_mean_s": float(ttg[reached].mean()) if reached.any() else nan,
            "time_to_goal_max_s": float(ttg[reached].max()) if reached.any() else nan,
            "path_ratio_mean": float(ratio.mean()),
            "path_ratio_max": float(ratio.max()),
        }
