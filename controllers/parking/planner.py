"""Parking planner: Hybrid A* search, then a CasADi/IPOPT time-and-effort optimisation.

Public API (stable; the parking controllers build on it): `plan`, `Trajectory`, `NoSolution`.
Everything runs in a local frame whose origin is the start position (cases may sit at ~1e9 m: the
origin is subtracted in float64 before anything else and added back to the output).

Plans do not depend on the machine's speed or load: the search is bounded by expansions and the
optimisation by IPOPT iterations (`PlanBudget`), never by a clock. The clock is read only to report
the planning time.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from corridor.controllers.parking import optimise, profile, warm_start
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, FootprintChecker, Obstacles, VehicleGeometry
from corridor.controllers.parking.search import (
    Exhausted,
    HybridAStar,
    SearchFailed,
    SearchParams,
    merge,
    reverse,
)
from corridor.errors import CorridorError

BOUNDS_PAD_M = 8.0  # default search area: the box around start, goal and obstacles, grown by this
MIN_RUN_M = 0.01  # shortest run in one direction that counts in direction_changes
MIN_DT_S = 1e-3  # finest output step [s] (rows grow as 1 / dt)
MAX_GRID_CELLS = 4_000_000  # bound on the search area: 0.1 m cells of the collision grid (400 x 100 m)
GRID_RES_M = 0.1  # the collision grid's cell (`FootprintChecker`)
SAME_POSE_M, SAME_POSE_RAD = 1e-9, 1e-9  # a goal this close to the start is the start: one row
# search resolutions (the expansion budgets are in `PlanBudget`)
COARSE = SearchParams(heuristic_weight=3.0)
FINE = SearchParams(heuristic_weight=3.0, xy_res_m=0.2, n_heading=144, step_m=0.5, short_step_m=0.15, check_m=0.1)
SLICE = 100  # expansions per turn ...
MICRO_TURNS = 4  # ... times this for a search with micro primitives (the end the other cannot reach)
CLEARANCE_STEPS_M = (0.1, 0.2, 0.4, 0.8, 1.6)  # to rank how tight the start and the goal are
MARGIN_M = 0.03  # footprint growth inside the optimisation's corridors (a hard constraint of the NLP)
END_SHARE = 0.5  # margins are at most this share of the start's and the goal's clearance (tight ends)
# warm starts tried in turn: (builder, node spacing in the warm start's time [s])
TRIES = ((warm_start.by_runs, 0.25), (warm_start.by_profile, 0.25), (warm_start.by_profile, 0.12))
MIN_NODES, MAX_NODES = 40, 400
REFINE_MAX = 2  # re-solves with corridors around the last solution ...
REFINE_GAIN = 0.02  # ... while each shortens the manoeuvre by more than this share
DENSE_M = 0.02  # spacing of the collision check of the optimised trajectory


@dataclass(frozen=True)
class PlanBudget:
    """Deterministic work bounds of one plan (the same plan on an idle or a loaded machine)."""

    coarse_expansions: int = 4000  # per search (from the start, from the goal) at 0.4 m cells
    fine_expansions: int = 8000  # per search at 0.2 m cells (after the coarse one failed)
    ipopt_iter: int = 150  # IPOPT iterations of a first solve (per warm start tried)
    refine_iter: int = 60  # IPOPT iterations of a re-solve (it starts from a solution)

    def __post_init__(self) -> None:
        for name in ("coarse_expansions", "fine_expansions", "ipopt_iter", "refine_iter"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise InputError(f"PlanBudget.{name} must be an integer >= 1 (got {getattr(self, name)!r})")


class NoSolution(Exception):
    """No trajectory: the message is a one-line reason."""


class InputError(CorridorError, ValueError):
    """A request the planner refuses before any work (bad step, search area over its bound): one line."""


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Rear-axle-centre states at times t [s]: x, y [m], theta [rad], v [m/s] (<0 reverse),
    a [m/s²], steer [rad]; all numpy arrays of one length."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    v: np.ndarray
    a: np.ndarray
    steer: np.ndarray
    search_time_s: float
    optimise_time_s: float
    stage: str = "optimised"  # or "search" (time-parametrised search path, the fallback), "at goal" (one row)
    expansions: int = 0  # of all the searches that made the path (the deterministic measure of their work)

    def direction_changes(self, min_run_m: float = MIN_RUN_M) -> int:
        """Changes between forward and reverse motion, counting only runs in one direction that
        travel at least ``min_run_m`` (the optimiser's sub-centimetre shuffles while it turns the wheels
        standing are not manoeuvres)."""
        ds = self.v[:-1] * np.diff(self.t)  # signed distance of each step
        sign = np.sign(self.v[:-1])
        runs: list[tuple[float, float]] = []  # (direction, distance)
        for sg, d in zip(sign, ds):
            if sg == 0:
                continue
            if runs and runs[-1][0] == sg:
                runs[-1] = (sg, runs[-1][1] + abs(d))
            else:
                runs.append((sg, abs(d)))
        dirs = [sg for sg, d in runs if d >= min_run_m]
        return int(sum(a != b for a, b in zip(dirs[:-1], dirs[1:])))

    def length_m(self) -> float:
        return float(np.hypot(np.diff(self.x), np.diff(self.y)).sum())

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    def as_array(self) -> np.ndarray:
        """(n, 7) columns t, x, y, theta, v, a, steer."""
        return np.column_stack([self.t, self.x, self.y, self.theta, self.v, self.a, self.steer])


def _default_bounds(start: np.ndarray, goal: np.ndarray, polys: list[np.ndarray]) -> tuple[float, ...]:
    pts = np.vstack([start[None, :2], goal[None, :2], *polys])
    lo, hi = pts.min(axis=0) - BOUNDS_PAD_M, pts.max(axis=0) + BOUNDS_PAD_M
    return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


def plan(start: tuple[float, float, float], goal: tuple[float, float, float], obstacles: Sequence[np.ndarray],
         vehicle: VehicleGeometry = TPCAP_VEHICLE, *, dt_s: float = 0.1,
         bounds: tuple[float, float, float, float] | None = None, budget: PlanBudget | None = None) -> Trajectory:
    """A collision-free, limit-respecting trajectory from ``start`` to ``goal`` (rear-axle poses x [m],
    y [m], heading [rad]) around ``obstacles`` (polygons, (k, 2) vertices [m]), or raise NoSolution.

    ``bounds`` (x_min, x_max, y_min, y_max) [m] is the area the search may use (default: the box
    around start, goal and obstacles grown by `BOUNDS_PAD_M`); more than `MAX_GRID_CELLS` cells of
    `GRID_RES_M` raise InputError, as does ``dt_s`` below `MIN_DT_S`. The trajectory starts at rest
    with straight wheels exactly at ``start`` (theta continuous from ``start[2]``, so it ends at
    ``goal[2]`` modulo 2π) and stops at ``goal``; rows are ≤ ``dt_s`` apart (one row when the goal is
    the start). The work is bounded by ``budget`` (expansions, IPOPT iterations), not by time. Only
    the vehicle's geometry and limits come from ``vehicle``."""
    t0 = time.perf_counter()
    budget = budget or PlanBudget()
    if not (dt_s >= MIN_DT_S):
        raise InputError(f"the output step dt must be >= {MIN_DT_S:g} s (got {dt_s:g})")
    if not np.all(np.isfinite([*start, *goal])):
        raise InputError("start and goal must be finite numbers")
    origin = np.array([start[0], start[1]], dtype=np.float64)
    s = np.array([0.0, 0.0, float(start[2])])
    g = np.array([goal[0] - origin[0], goal[1] - origin[1], float(goal[2])])
    polys = [np.asarray(p, dtype=np.float64).reshape(-1, 2) - origin for p in obstacles]
    if bounds is None:
        lb = _default_bounds(s, g, polys)
    else:
        lb = (bounds[0] - origin[0], bounds[1] - origin[0], bounds[2] - origin[1], bounds[3] - origin[1])
    _check_area(lb, bounds is None)
    obs = Obstacles(polys)
    for name, pose in (("start", s), ("goal", g)):
        if obs.collides(pose[None], vehicle)[0]:
            raise NoSolution(f"the {name} pose collides with an obstacle")
        if not (lb[0] <= pose[0] <= lb[1] and lb[2] <= pose[1] <= lb[3]):
            raise NoSolution(f"the {name} pose is outside the bounds")
    if np.hypot(g[0], g[1]) <= SAME_POSE_M and abs(_wrap(g[2] - s[2])) <= SAME_POSE_RAD:
        z = np.zeros(1)
        states = {"t": z, "x": z.copy(), "y": z.copy(), "theta": s[2:3].copy(), "v": z.copy(), "a": z.copy(),
                  "steer": z.copy()}
        return _to_world(states, origin, time.perf_counter() - t0, 0.0, stage="at goal")
    end_clear = min(_exact_clearance(s, obs, vehicle), _exact_clearance(g, obs, vehicle))
    search_margin = min(COARSE.margin_m, END_SHARE * end_clear)
    opt_margin = min(MARGIN_M, END_SHARE * end_clear)
    segments, expansions = _search(tuple(s), tuple(g), obs, vehicle, lb, budget, search_margin, opt_margin)
    t_search = time.perf_counter() - t0
    states, stage = _optimise(segments, obs, vehicle, dt_s, budget, opt_margin)
    t_opt = time.perf_counter() - t0 - t_search
    # a path searched from the goal reaches the start's heading modulo 2π: start from it exactly
    turns = np.round((float(start[2]) - states["theta"][0]) / (2 * np.pi))
    states["theta"] = states["theta"] + 2 * np.pi * turns
    return _to_world(states, origin, t_search, t_opt, stage=stage, expansions=expansions)


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def _check_area(lb: tuple[float, ...], default: bool) -> None:
    """InputError when the search area needs more than `MAX_GRID_CELLS` cells (before any is made)."""
    w, h = lb[1] - lb[0], lb[3] - lb[2]
    if not (w >= 0 and h >= 0):
        raise InputError(f"the bounds are empty ({w:g} x {h:g} m)")
    cells = (w / GRID_RES_M + 1) * (h / GRID_RES_M + 1)
    if cells > MAX_GRID_CELLS:
        what = ("the box around start, goal and obstacles, grown by "
                f"{BOUNDS_PAD_M:g} m" if default else "the given bounds")
        raise InputError(f"the search area is {w:.0f} m x {h:.0f} m ({what}): {cells:.3g} cells of {GRID_RES_M:g} m "
                         f"exceed the bound of {MAX_GRID_CELLS:.0f} (MAX_GRID_CELLS); bring the goal and "
                         "obstacles closer to the start")


def _optimise(segments: list, obs: Obstacles, vehicle: VehicleGeometry, dt_s: float,
              budget: PlanBudget, margin_m: float) -> tuple[dict[str, np.ndarray], str]:
    """The optimised trajectory, else the stop-and-steer search path (which meets every limit by
    construction). Warm starts are tried in turn (`TRIES`); a solution is accepted when it is
    collision-free sampled densely, then refined while it improves: the corridors re-grown around it,
    so the nodes are no longer tied to the warm start's timing."""
    best = None
    for build, node_dt in TRIES:
        ws, T0 = build(segments, vehicle, node_dt, MIN_NODES, MAX_NODES)
        best = _solve_checked(ws, T0, obs, vehicle, dt_s, budget.ipopt_iter, margin_m)
        if best is not None:
            break
    if best is None:
        states = profile.sample(profile.phases(segments, vehicle), segments[0].start, vehicle, dt_s)
        if _collides_densely(states, obs, vehicle):  # the search's margin should make this impossible
            raise NoSolution("the optimisation failed and the search path clips an obstacle between its checks")
        return states, "search"
    for _ in range(REFINE_MAX):
        sol, _ = best
        better = _solve_checked(sol.states, sol.h_s * len(sol.inputs), obs, vehicle, dt_s, budget.refine_iter,
                                margin_m)
        if better is None or better[0].h_s > sol.h_s * (1 - REFINE_GAIN):
            if better is not None and better[0].h_s < sol.h_s:
                best = better
            break
        best = better
    return best[1], "optimised"


def _solve_checked(ws: np.ndarray, T0: float, obs: Obstacles, vehicle: VehicleGeometry, dt_s: float,
                   max_iter: int, margin_m: float) -> tuple[optimise.Solution, dict[str, np.ndarray]] | None:
    try:
        sol = optimise.solve(ws, T0, obs, vehicle, optimise.OptimiseParams(margin_m=margin_m, max_iter=max_iter))
    except optimise.OptimiseFailed:
        return None
    states = optimise.sample(sol, vehicle, dt_s)
    return None if _collides_densely(states, obs, vehicle) else (sol, states)


def _collides_densely(states: dict[str, np.ndarray], obs: Obstacles, vehicle: VehicleGeometry) -> bool:
    x, y, th = states["x"], states["y"], states["theta"]
    n = np.maximum(1, np.ceil(np.hypot(np.diff(x), np.diff(y)) / DENSE_M).astype(int))
    k = np.repeat(np.arange(len(n)), n)
    f = np.concatenate([np.arange(m) / m for m in n])
    poses = np.column_stack([x[k] + f * np.diff(x)[k], y[k] + f * np.diff(y)[k], th[k] + f * np.diff(th)[k]])
    return bool(obs.collides(np.vstack([poses, [[x[-1], y[-1], th[-1]]]]), vehicle).any())


def _search(s: tuple[float, float, float], g: tuple[float, float, float], obs: Obstacles,
            vehicle: VehicleGeometry, lb: tuple[float, ...], budget: PlanBudget, search_margin_m: float,
            opt_margin_m: float) -> tuple[list, int]:
    """Searches from both ends take turns (`SLICE` expansions each, the tighter end first: leaving a
    bay is easier than entering it; a path found from the goal is driven backwards) until one finds a
    path. A path that clips an obstacle between the search's collision checks is dropped and its
    search goes on without the primitive that clipped (`HybridAStar.prune`). A search that fails at
    `COARSE` resolution is replaced by one at `FINE` resolution from the same end. Each search stops
    at its expansion budget. Returns the path and the expansions of all searches."""
    reasons: list[str] = []
    made: list[HybridAStar] = []  # every search started (their expansions are the work done)
    goal_first = _clearance(g, obs, vehicle) <= _clearance(s, obs, vehicle)
    checkers: dict[float, FootprintChecker] = {}

    def start_search(backwards: bool, params: SearchParams) -> HybridAStar | None:
        checker = checkers.setdefault(params.margin_m, FootprintChecker(obs, vehicle, params.margin_m, lb))
        try:
            made.append(HybridAStar(*((g, s) if backwards else (s, g)), obs, vehicle, lb, params, checker))
            return made[-1]
        except SearchFailed as exc:
            reasons.append(_reason(backwards, params, exc))
            return None

    coarse = replace(COARSE, max_expansions=budget.coarse_expansions, margin_m=search_margin_m)
    fine = replace(FINE, max_expansions=budget.fine_expansions, margin_m=search_margin_m)
    searches = {b: start_search(b, coarse) for b in (goal_first, not goal_first)}
    while any(searches.values()):
        for backwards, search in list(searches.items()):
            if search is None:
                continue
            try:
                path = search.run(SLICE * (MICRO_TURNS if search.p.micro else 1))
            except SearchFailed as exc:
                reasons.append(_reason(backwards, search.p, exc))
                searches[backwards] = start_search(backwards, nxt) if (nxt := _next(search.p, exc, fine)) else None
                continue
            if path is None:
                continue
            clip = _first_clip(path, obs, vehicle, opt_margin_m)
            if clip is None:
                return merge(reverse(path) if backwards else path), sum(m.expansions for m in made)
            search.prune(clip)  # and go on without that primitive (or that analytic tail)
    raise NoSolution(f"no path ({'; '.join(reasons)})")


def _next(p: SearchParams, exc: SearchFailed, fine: SearchParams) -> SearchParams | None:
    """The search that replaces a failed one from the same end: with micro primitives near the end if
    it was exhausted (a tight start or goal it could not leave), else at `FINE` resolution."""
    if isinstance(exc, Exhausted) and not p.micro:
        return replace(p, micro=True)
    if p.xy_res_m > fine.xy_res_m:
        return replace(fine, check_m=min(fine.check_m, p.check_m), micro=p.micro)
    return None


def _reason(backwards: bool, p: SearchParams, exc: Exception | str) -> str:
    micro = f", {p.micro_step_m:g} m steps near it" if p.micro else ""
    return f"from the {'goal' if backwards else 'start'}, {p.xy_res_m:g} m cells{micro}: {exc}"


def _first_clip(segments: list, obs: Obstacles, vehicle: VehicleGeometry, margin_m: float) -> int | None:
    """The first segment along which the footprint, grown by the optimisation's margin, meets an
    obstacle (sampled every `DENSE_M`), or None."""
    for k, seg in enumerate(segments):
        if obs.collides(seg.poses(DENSE_M), vehicle, margin_m).any():
            return k
    return None


def _exact_clearance(pose: np.ndarray, obs: Obstacles, vehicle: VehicleGeometry, upto_m: float = 0.2) -> float:
    """The largest footprint growth [m] (to 1e-4 m, at most ``upto_m``) free of obstacles at ``pose``
    (bisection on the exact collision test): the margins never exceed `END_SHARE` of it."""
    if not obs.collides(np.asarray(pose)[None], vehicle, upto_m)[0]:
        return upto_m
    lo, hi = 0.0, upto_m
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if not obs.collides(np.asarray(pose)[None], vehicle, mid)[0] else (lo, mid)
    return lo


def _clearance(pose: tuple[float, float, float], obs: Obstacles, vehicle: VehicleGeometry) -> float:
    """The largest of `CLEARANCE_STEPS_M` by which the footprint can grow at ``pose`` (0 if none)."""
    free = [m for m in CLEARANCE_STEPS_M if not obs.collides(np.asarray(pose)[None], vehicle, m)[0]]
    return max(free, default=0.0)


def _to_world(states: dict[str, np.ndarray], origin: np.ndarray, t_search: float, t_opt: float,
              stage: str, expansions: int = 0) -> Trajectory:
    return Trajectory(t=states["t"], x=states["x"] + origin[0], y=states["y"] + origin[1],
                      theta=states["theta"], v=states["v"], a=states["a"], steer=states["steer"],
                      search_time_s=t_search, optimise_time_s=t_opt, stage=stage, expansions=expansions)
