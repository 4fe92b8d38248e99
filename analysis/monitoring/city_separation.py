"""Separation monitor for a city's fleet (registered as ``city_separation``): the measures of
``uav_separation`` (loss of separation, NMAC, minimum separations, the same thresholds and the same
continuous check between ticks), found with k-d trees instead of all N^2 pairs, plus rates per
flight hour, per-aircraft nearest-approach distributions and the delivery missions' delay.

Each tick (the scenario's ``dt``) the aircraft are taken to move on straight lines from the previous
tick's positions (as ``uav_separation`` does, ``analysis.ccd``). Candidate pairs are those within
``hypot(los_h, los_v) + 2 * (largest move in the interval)`` at the tick (UAV-UAV), or within the
piloted LoS cylinder's reach of a piloted aircraft: any pair that enters a cylinder during the
interval is among them. A pair *enters* LoS / NMAC when its swept relative motion passes through
the cylinder (or is inside at the tick); each entry counts once and is an event. The minima use the
segment's closest approach for the candidate pairs and the tick's nearest neighbours (k-d tree) for
the rest. Per aircraft, its smallest 3-D distance to any other over the run gives the distribution
``sep_nn_*`` (median, 5 % quantile): the statistic the fidelity comparison tests.

Rates: ``los_per_fh`` / ``nmac_per_fh`` = events / quadcopter flight hours. Mission delay: the
deliveries the air backend's missions logged (flown minus nominal time).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from corridor.analysis.ccd import MAX_STEP_M, closest_approach, interval_below
from corridor.engine import Component, Metric, Need, Phase, RunContext
from corridor.shards import ShardComm, Strips
from corridor.snapshot import Kind


@dataclass(frozen=True)
class Region:
    """A rank's part of the separation checks in a sharded run (``corridor.shards``): the rows in its
    strip (``owned``: it counts the LoS / NMAC entries of the pairs whose lower row it owns and
    queries their nearest neighbours), the rows whose pairs it checks (``checked``: the strip widened
    by the halo, and the piloted aircraft) and the rows of its k-d trees (``local``: the strip
    widened by ``region_margin_m``). The halo is wider than any aircraft moves in a tick, so a pair a
    rank takes over from its neighbour was checked by it one tick before: it knows whether the pair
    was inside. The margin holds every partner within the candidate radius of a checked row."""

    owned: np.ndarray  # (N,) bool
    checked: np.ndarray  # (N,) bool
    local: np.ndarray  # (L,) rows, ascending


class CitySeparation(Component):
    phase = Phase.DETECT
    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('nmac', '1', 'Near mid-air collisions: aircraft pairs entering the NMAC cylinder.', safety_event=True),
        Metric('los', '1', 'Losses of separation: aircraft pairs entering the LoS cylinder.', safety_event=True),
        Metric('nmac_per_fh', '1/h', 'NMAC per quadcopter flight hour.'),
        Metric('los_per_fh', '1/h', 'Losses of separation per quadcopter flight hour.'),
        Metric('sep_min_h_m', 'm', 'Smallest horizontal distance between any two aircraft (continuous).'),
        Metric('sep_min_3d_m', 'm', 'Smallest 3-D distance between any two aircraft (continuous).'),
        Metric('sep_nn_median_m', 'm', 'Median over aircraft of each one\'s smallest 3-D distance to another.'),
        Metric('sep_nn_p05_m', 'm', '5 % quantile over aircraft of each one\'s smallest 3-D distance to another.'),
        Metric('missions_done', '1', 'Deliveries completed.'),
        Metric('mission_delay_mean_s', 's', 'Mean delay of the completed deliveries (flown minus nominal time).'),
        Metric('mission_delay_p95_s', 's', '95 % quantile of the delivery delays.'),
    )
    needs: ClassVar[dict[str, Need]] = {"air": Need(role="air", name_at="params.backend", optional=True)}
    air: Any = None
    period_source: ClassVar[str | None] = "dt"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        nmac_h_m: float = Field(30.48, gt=0.0)  # [m] 100 ft (as uav_separation)
        nmac_v_m: float = Field(4.572, gt=0.0)  # [m] 15 ft
        los_h_m: float = Field(60.96, gt=0.0)  # [m] 200 ft
        los_v_m: float = Field(15.24, gt=0.0)  # [m] 50 ft
        los_piloted_h_m: float = Field(609.6, gt=0.0)  # [m] 2000 ft
        los_piloted_v_m: float = Field(76.2, gt=0.0)  # [m] 250 ft
        backend: str | None = "air"
        halo_mps: float = Field(1500.0, gt=0.0)  # [m/s] sharded runs: the halo is halo_mps * dt wide
        region_margin_m: float = Field(500.0, gt=0.0)  # [m] sharded runs: a rank's trees reach this far out of its strip

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.prev: np.ndarray | None = None
        self.min_h = self.min_3d = np.inf
        self.los = self.nmac = 0
        self.in_los: np.ndarray = np.zeros(0, dtype=np.int64)  # pair keys i * N + j inside now
        self.in_nmac: np.ndarray = np.zeros(0, dtype=np.int64)
        self.nn: np.ndarray | None = None
        self.quad_s = 0.0  # [s] quadcopter flight time
        self.strips: Strips | None = None  # a sharded run's regions (corridor.shards)
        self.halo_m = 0.0  # [m] a sharded run's halo: halo_mps * dt
        self._edges_seen = np.zeros(0)  # [m] the strip edges at the last tick (a balanced split moves them)

    def tick(self, ctx: RunContext) -> None:
        s = ctx.snapshot
        air = np.flatnonzero((s.kind == Kind.UAV) | (s.kind == Kind.AIRCRAFT))
        if len(air) < 2:
            return
        pos, piloted = s.position[air], s.kind[air] == Kind.AIRCRAFT
        self.ids = s.ids[air]
        if self.prev is None or len(self.prev) != len(pos):
            self.prev, self.nn = pos.copy(), np.full(len(pos), np.inf)
        self.quad_s += float(np.count_nonzero(~piloted)) * ctx.dt
        if ctx.shard is not None:
            self._tick_region(ctx, pos, piloted)
        else:
            with ctx.part(f"{self.name}.pairs"):
                i, j, d0, d1, tree, reach = self._candidates(self.prev, pos, piloted)
            with ctx.part(f"{self.name}.nearest"):
                self._nearest(pos, tree, reach, np.concatenate([i, j]))
            with ctx.part(f"{self.name}.check"):
                if len(i):
                    self._check(ctx, i, j, d0, d1, piloted, len(pos))
        self.prev = pos.copy()

    # ---- a sharded run: this rank's region ---------------------------------------------------------------
    def _region(self, comm: ShardComm, pos: np.ndarray, piloted: np.ndarray, teleport: np.ndarray,
                reach_m: float) -> Region:
        if self.strips is None:
            self.strips = comm.strips or Strips(pos[:, 0], comm.size)
            self._edges_seen = self.strips.edges.copy()
        if self.params.region_margin_m < self.halo_m + reach_m:
            raise ValueError(f"{self.name}: params.region_margin_m ({self.params.region_margin_m} m) must cover the halo "
                             f"and the candidate radius ({self.halo_m + reach_m:.1f} m)")
        x, always = pos[:, 0], piloted | teleport
        return Region(owned=self.strips.within(x, comm.rank),
                      checked=self.strips.within(x, comm.rank, self.halo_m) | always,
                      local=np.flatnonzero(self.strips.within(x, comm.rank, self.params.region_margin_m) | always))

    def _tick_region(self, ctx: RunContext, pos: np.ndarray, piloted: np.ndarray) -> None:
        """The one-process tick's checks for the pairs whose lower row this rank checks, on k-d trees
        of its local rows only; the same candidate radius (from every aircraft's move) as one process."""
        p = self.params
        self.halo_m = p.halo_mps * ctx.dt
        move = np.linalg.norm(pos - self.prev, axis=1)
        teleport = move > MAX_STEP_M
        step = float(move[~teleport].max(initial=0.0))
        reach = float(np.hypot(p.los_h_m, p.los_v_m) + 2.0 * step)
        reg = self._region(ctx.shard, pos, piloted, teleport, reach)
        edge_move = float(np.abs(self.strips.edges - self._edges_seen).max(initial=0.0))  # [m] a balanced split's
        self._edges_seen = self.strips.edges.copy()
        if step + edge_move > self.halo_m:
            raise ValueError(f"{self.name}: an aircraft moved {step:.1f} m and a strip edge {edge_move:.1f} m in one "
                             f"tick, more than the shards' halo ({self.halo_m:.1f} m = halo_mps * dt): raise "
                             "params.halo_mps")
        with ctx.part(f"{self.name}.pairs"):
            lp = pos[reg.local]
            tree = cKDTree(lp)
            ij = [tree.query_pairs(reach, output_type="ndarray")]
            r_piloted = np.hypot(p.los_piloted_h_m, p.los_piloted_v_m) + 2.0 * step
            for k in np.flatnonzero(piloted[reg.local]):
                js = np.asarray(tree.query_ball_point(lp[k], r_piloted), dtype=np.int64)
                js = js[js != k]
                ij.append(np.column_stack([np.minimum(js, k), np.maximum(js, k)]))
            m = len(reg.local)
            key = np.unique(np.concatenate(ij).reshape(-1, 2).astype(np.int64) @ np.array([m, 1], dtype=np.int64))
            pairs = reg.local[np.column_stack([key // m, key % m])]  # sorted (i, j), as np.unique(axis=0) gives them
            pairs = pairs[reg.checked[pairs[:, 0]]]
            i, j = pairs[:, 0], pairs[:, 1]
            d1 = pos[i] - pos[j]
            ok = ~(teleport[i] | teleport[j])
            d0 = np.where(ok[:, None], self.prev[i] - self.prev[j], d1)
        with ctx.part(f"{self.name}.nearest"):
            self._nearest_region(pos, reg, tree, reach, np.concatenate([i, j]))
        with ctx.part(f"{self.name}.check"):
            self._check(ctx, i, j, d0, d1, piloted, len(pos), reg.owned)

    def _nearest_region(self, pos: np.ndarray, reg: Region, tree: cKDTree, reach_m: float, paired: np.ndarray) -> None:
        """``_nearest`` for this rank's rows, on its local trees. A local nearest neighbour within the
        margin W is the true one (every other row is farther than W from an owned row); a farther one
        can only matter while a minimum is above W, and then the whole fleet's tree answers. The
        minima over the ranks are the one-process ones: every value a rank adds is a real distance
        that the one-process run also takes, or one above the minimum it updates."""
        w = self.params.region_margin_m
        local_of = np.full(len(pos), -1)
        local_of[reg.local] = np.arange(len(reg.local))
        far_mask = self.nn > reach_m  # the one-process union1d(nn > reach, paired), as a mask
        far_mask[paired] = True
        far = np.flatnonzero(far_mask & reg.owned)
        if len(far):
            d3 = tree.query(pos[far], k=2)[0][:, 1]
            out = (d3 > w) & ((self.nn[far] > w) | (self.min_3d > w))
            if out.any():
                d3[out] = cKDTree(pos).query(pos[far[out]], k=2)[0][:, 1]
            self.nn[far] = np.minimum(self.nn[far], d3)
            self.min_3d = min(self.min_3d, float(d3.min()))
        xy = pos[reg.local, :2]
        tree_h = cKDTree(xy)
        if np.isfinite(self.min_h) and self.min_h <= w:
            rows = np.unique(tree_h.query_pairs(self.min_h, output_type="ndarray"))
            rows = rows[reg.owned[reg.local[rows]]]
        else:
            rows = local_of[np.flatnonzero(reg.owned)]
        if len(rows):
            dh = tree_h.query(xy[rows], k=2)[0][:, 1]
            out = dh > w
            if out.any() and self.min_h > w:
                dh[out] = cKDTree(pos[:, :2]).query(xy[rows[out]], k=2)[0][:, 1]
            self.min_h = min(self.min_h, float(dh.min()))

    def _combine(self, comm: ShardComm) -> None:
        """Every rank's counts and minima (collectives: the one-process run's values on every rank)."""
        self.los, self.nmac = round(comm.sum(self.los)), round(comm.sum(self.nmac))
        self.min_h, self.min_3d = (float(v) for v in comm.min_array(np.array([self.min_h, self.min_3d])))
        if self.nn is not None:
            self.nn = comm.min_array(self.nn)

    def _candidates(self, prev: np.ndarray, pos: np.ndarray, piloted: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, cKDTree, float]:
        """Candidate pairs (i, j, relative position at the last and this tick), the k-d tree of ``pos``
        and the radius [m] within which every pair is a candidate."""
        p = self.params
        move = np.linalg.norm(pos - prev, axis=1)
        teleport = move > MAX_STEP_M
        step = float(move[~teleport].max(initial=0.0))
        tree = cKDTree(pos)
        reach = float(np.hypot(p.los_h_m, p.los_v_m) + 2.0 * step)
        ij = [tree.query_pairs(reach, output_type="ndarray")]
        for k in np.flatnonzero(piloted):
            js = np.asarray(tree.query_ball_point(pos[k], np.hypot(p.los_piloted_h_m, p.los_piloted_v_m) + 2.0 * step),
                            dtype=np.int64)
            js = js[js != k]
            ij.append(np.column_stack([np.minimum(js, k), np.maximum(js, k)]))
        pairs = np.unique(np.concatenate(ij).reshape(-1, 2).astype(np.int64), axis=0)
        i, j = pairs[:, 0], pairs[:, 1]
        d1 = pos[i] - pos[j]
        ok = ~(teleport[i] | teleport[j])
        d0 = np.where(ok[:, None], prev[i] - prev[j], d1)
        return i, j, d0, d1, tree, reach

    def _nearest(self, pos: np.ndarray, tree: cKDTree, reach_m: float, paired: np.ndarray) -> None:
        """Per-aircraft and global minima at the tick (nearest neighbours, horizontal and 3-D).

        Only what can lower a minimum is queried; the result equals a nearest-neighbour query of
        every aircraft. 3-D: every pair within ``reach_m`` is a candidate pair (``paired``: the rows of
        the candidate pairs), so an aircraft in none has its nearest neighbour beyond ``reach_m``,
        which lowers its ``nn`` only if ``nn > reach_m``: the aircraft in a candidate pair and those
        are queried (and ``min_3d <= min(nn)``). Horizontal: only a pair closer than ``min_h`` can
        lower it, so once it is finite only the aircraft of such pairs are queried."""
        far = np.union1d(np.flatnonzero(self.nn > reach_m), paired)
        if len(far):
            d3, _ = tree.query(pos[far], k=2)
            self.nn[far] = np.minimum(self.nn[far], d3[:, 1])
            self.min_3d = min(self.min_3d, float(d3[:, 1].min()))
        xy = pos[:, :2]
        tree_h = cKDTree(xy)
        rows = (np.unique(tree_h.query_pairs(self.min_h, output_type="ndarray"))
                if np.isfinite(self.min_h) else np.arange(len(xy)))
        if len(rows):
            dh, _ = tree_h.query(xy[rows], k=2)
            self.min_h = min(self.min_h, float(dh[:, 1].min()))

    def _check(self, ctx: RunContext, i: np.ndarray, j: np.ndarray, d0: np.ndarray, d1: np.ndarray,
               piloted: np.ndarray, n: int, owned: np.ndarray | None = None) -> None:
        """The pairs' minima and LoS / NMAC entries; ``owned`` (a sharded run): count and log only the
        entries of pairs whose lower row is in it (the others are another rank's)."""
        p = self.params
        _, dh_min = closest_approach(d0[:, :2], d1[:, :2])
        _, d3_min = closest_approach(d0, d1)
        self.min_h = min(self.min_h, float(dh_min.min(initial=np.inf)))
        self.min_3d = min(self.min_3d, float(d3_min.min(initial=np.inf)))
        np.minimum.at(self.nn, i, d3_min)
        np.minimum.at(self.nn, j, d3_min)
        mixed = piloted[i] | piloted[j]
        key = i * n + j
        los = _passes(d0, d1, np.where(mixed, p.los_piloted_h_m, p.los_h_m), np.where(mixed, p.los_piloted_v_m, p.los_v_m))
        nmac = _passes(d0, d1, p.nmac_h_m, p.nmac_v_m)
        self.in_los, new_los = _entries(key, los, self.in_los)
        self.in_nmac, new_nmac = _entries(key, nmac, self.in_nmac)
        if owned is not None:
            new_los, new_nmac = new_los[owned[new_los // n]], new_nmac[owned[new_nmac // n]]
        self.los += len(new_los)
        self.nmac += len(new_nmac)
        for kind, new in (("los", new_los), ("nmac", new_nmac)):
            for k in new.tolist():
                a, b = str(self.ids[k // n]), str(self.ids[k % n])
                ctx.events.emit(ctx.t, self.name, kind, f"{a} - {b}: {kind}", pair=(a, b))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        if ctx.shard is not None:
            self._combine(ctx.shard)
        fh = self.quad_s / 3600.0
        nn = self.nn if self.nn is not None else np.zeros(0)
        out = {"nmac": self.nmac, "los": self.los,
               "nmac_per_fh": self.nmac / fh if fh > 0 else float("nan"),
               "los_per_fh": self.los / fh if fh > 0 else float("nan"),
               "sep_min_h_m": self.min_h, "sep_min_3d_m": self.min_3d,
               "sep_nn_median_m": float(np.median(nn)) if len(nn) else float("nan"),
               "sep_nn_p05_m": float(np.quantile(nn, 0.05)) if len(nn) else float("nan")}
        missions = getattr(self.air, "missions", None)
        if missions is not None:
            d = missions.delays()
            out.update({"missions_done": len(d), "mission_delay_mean_s": float(d.mean()) if len(d) else float("nan"),
                        "mission_delay_p95_s": float(np.quantile(d, 0.95)) if len(d) else float("nan")})
        return out


def _passes(d0: np.ndarray, d1: np.ndarray, r_h: np.ndarray | float, r_v: np.ndarray | float) -> np.ndarray:
    """Pairs whose straight relative motion from d0 to d1 passes through the cylinder (r_h, r_v)."""
    lo_a, hi_a = interval_below(d0[:, :2], d1[:, :2], r_h)
    lo_b, hi_b = interval_below(d0[:, 2:], d1[:, 2:], r_v)
    inside_now = (np.hypot(d1[:, 0], d1[:, 1]) < r_h) & (np.abs(d1[:, 2]) < r_v)
    return (np.maximum(lo_a, lo_b) < np.minimum(hi_a, hi_b)) | inside_now


def _entries(key: np.ndarray, inside: np.ndarray, before: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pairs inside now, pairs that entered in this interval) as sorted pair keys."""
    now = np.unique(key[inside])
    return now, now[~np.isin(now, before, assume_unique=True)]
