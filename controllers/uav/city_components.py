"""Fleet-wide avoidance for a city's drones: ``city_potential_field`` and ``city_none``.

The engine glue of :mod:`corridor.controllers.uav.potential_field_fleet`. At every decision it takes

- each drone's own state from the world snapshot and its goal from the air backend's delivery
  missions (``missions.goal``),
- the other aircraft only as the city link delivered them (``CityLink.picture``: the newest report
  per source, extrapolated, with its uncertainty radius; never ground truth),

finds each drone's relevant others with a k-d tree (UAVs within the field's reach,
``uav_safety_radius + uav_cutoff + 2 tau v_bound + relevance_margin_m``; piloted aircraft within
``influence_m``; and only within the link's range), computes every command in one pass and puts one
:class:`~corridor.vehicles.air.mf_backend.FleetVelocityCommand` on the bus. ``city_none`` flies straight
to the goal at cruise speed (the baseline). Every cruise <-> avoid transition is a ``mode`` event;
the vertical geofence of the per-UAV controllers applies.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from corridor.controllers.uav.potential_field import PotentialFieldParams
from corridor.controllers.uav.potential_field_fleet import fleet_commands, goal_flow
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.shards import Strips
from corridor.vehicles.air.mf_backend import FleetVelocityCommand, MultiFidelityAirBackend


class CityAvoidanceParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: str = "air"
    link: str = "link"
    min_alt_m: float = 15.0  # [m] vertical geofence (as the per-UAV controllers)
    max_alt_m: float = 150.0  # [m]
    fence_gain_per_s: float = Field(0.5, gt=0.0)  # [1/s]
    speed_bound_mps: float = Field(12.0, gt=0.0)  # [m/s] bounds the other UAVs' speed in the reach
    relevance_margin_m: float = Field(15.0, ge=0.0)  # [m]
    potential_field: PotentialFieldParams = Field(default_factory=PotentialFieldParams)


class CityNone(Controller):
    """Straight to the mission goal at cruise speed; never looks at the others."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('avoid_share', '1', 'Share of the UAV decisions that avoided (not straight to the goal).'),
    )
    Params = CityAvoidanceParams
    needs: ClassVar[dict[str, Need]] = {"backend": Need(role="air", name_at="params.backend")}
    period = 0.5  # [s]
    backend: MultiFidelityAirBackend

    def __init__(self, name: str, params: CityAvoidanceParams, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.decisions = self.avoid_decisions = 0

    def setup(self, ctx: RunContext) -> None:
        b = self.backend
        if getattr(b, "missions", None) is None:
            raise ValueError(f"{self.name}: the air backend {b.name!r} has no city missions (params.city)")
        self.rows = b.quad_rows
        spec = b.params.city
        self.pf = self.params.potential_field.model_copy(update={"max_speed_h_mps": spec.speed_mps})
        self.avoiding = np.zeros(len(self.rows), dtype=bool)
        self.comm = ctx.shard  # a sharded run (corridor.shards): each rank decides for its strip's drones
        self.strips: Strips | None = None
        super().setup(ctx)

    def observe(self, ctx: RunContext) -> tuple[float, np.ndarray, np.ndarray, np.ndarray] | None:
        s = ctx.snapshot
        if len(s) == 0:  # t = 0: no state yet
            return None
        return ctx.t, s.position[self.rows], s.velocity[self.rows], self.backend.missions.goal

    def commands(self, t: float, x: np.ndarray, v: np.ndarray, goal: np.ndarray, egos: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Commands and avoid flags of the drones ``egos`` (rows of ``x``; None: all)."""
        if egos is not None:
            x, goal = x[egos], goal[egos]
        g = goal_flow(x, goal, self.pf)
        h = np.hypot(g[:, 0], g[:, 1])
        g[:, :2] *= np.minimum(1.0, self.pf.max_speed_h_mps / np.maximum(h, 1e-12))[:, None]
        g[:, 2] = np.clip(g[:, 2], -self.pf.max_climb_mps, self.pf.max_climb_mps)
        return g, np.zeros(len(x), dtype=bool)

    def step(self, obs: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None) -> list[Any]:
        if obs is None:
            return []
        t, x, v, goal = obs
        cmd, avoiding = self.commands(t, x, v, goal) if self.comm is None else self._gathered(t, x, v, goal)
        cmd = self.fence(x, cmd)
        self._track_modes(t, avoiding)
        return [FleetVelocityCommand(self.rows, cmd)]

    def _gathered(self, t: float, x: np.ndarray, v: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A sharded run: this rank's drones (its strip of the city) decided here, the others' commands
        from their ranks (each drone's command depends on its own pairs only: the one-process values)."""
        if self.strips is None:
            self.strips = self.comm.strips or Strips(x[:, 0], self.comm.size)
        own = np.flatnonzero(self.strips.within(x[:, 0], self.comm.rank))
        cmd, avoiding = np.zeros_like(x), np.zeros(len(x), dtype=bool)
        for rows, c, a in self.comm.allgather((own, *self.commands(t, x, v, goal, own))):
            cmd[rows], avoiding[rows] = c, a
        return cmd, avoiding

    def fence(self, x: np.ndarray, cmd: np.ndarray) -> np.ndarray:
        p = self.params
        cmd[:, 2] = np.clip(cmd[:, 2], p.fence_gain_per_s * (p.min_alt_m - x[:, 2]),
                            p.fence_gain_per_s * (p.max_alt_m - x[:, 2]))
        return cmd

    def _track_modes(self, t: float, avoiding: np.ndarray) -> None:
        self.decisions += len(avoiding)
        self.avoid_decisions += int(avoiding.sum())
        ids = self.backend.ids
        for k in np.flatnonzero(avoiding != self.avoiding).tolist():
            new, old = ("avoid", "cruise") if avoiding[k] else ("cruise", "avoid")
            uid = str(ids[self.rows[k]])
            self.events.emit(t, self.name, "mode", f"{uid}: {old} -> {new}", uav=uid, mode=new)
        self.avoiding = avoiding

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"avoid_share": self.avoid_decisions / max(self.decisions, 1)}


class CityPotentialField(CityNone):
    """The potential field over the fleet, the others as the city link delivered them."""

    needs: ClassVar[dict[str, Need]] = {**CityNone.needs, "link": Need(role="city_link", name_at="params.link")}
    link: Any

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        p, pf = self.params, self.pf
        self.piloted_src = ~self.backend.is_quad
        self.reach_uav_m = (pf.uav_safety_radius_m + (pf.uav_cutoff_m or pf.influence_m)
                            + 2.0 * pf.uav_lookahead_s * p.speed_bound_mps + p.relevance_margin_m)

    def commands(self, t: float, x: np.ndarray, v: np.ndarray, goal: np.ndarray, egos: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        pic = self.link.picture(t)
        rows = self.rows
        if egos is not None:
            x, v, goal, rows = x[egos], v[egos], goal[egos], rows[egos]
        ego, src = self._pairs(x, pic, rows)
        out = fleet_commands(x, v, goal, ego, pic.pos[src], pic.vel[src], pic.sigma_m[src], self.piloted_src[src],
                             self.pf)
        return out.v_cmd, out.avoiding

    def _pairs(self, x: np.ndarray, pic: Any, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ego row, source row) of every relevant report: never the ego itself (``rows``: each ego's
        snapshot row), stale ones dropped."""
        reach = min(self.reach_uav_m, pic.range_m)
        uav_src = np.flatnonzero(pic.valid & ~self.piloted_src)
        e, s = _ball_pairs(x, pic.pos[uav_src], reach)
        ego, src = [e], [uav_src[s]]
        pil_src = np.flatnonzero(pic.valid & self.piloted_src)
        if len(pil_src):
            e, s = _ball_pairs(x, pic.pos[pil_src], min(self.pf.influence_m + self.params.relevance_margin_m,
                                                        pic.range_m))
            ego.append(e)
            src.append(pil_src[s])
        ego_a, src_a = np.concatenate(ego), np.concatenate(src)
        keep = rows[ego_a] != src_a
        return ego_a[keep], src_a[keep]


def _ball_pairs(x: np.ndarray, y: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with |x_i - y_j| <= r, i ascending."""
    if len(x) == 0 or len(y) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    m = cKDTree(x).sparse_distance_matrix(cKDTree(y), r, output_type="ndarray")
    order = np.lexsort((m["j"], m["i"]))
    return m["i"][order].astype(int), m["j"][order].astype(int)
