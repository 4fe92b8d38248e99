"""Parking planner: Hybrid A* search, then a CasADi/IPOPT time-and-effort optimisation.

Public API (stable; the parking controllers build on it): `plan`, `Trajectory`, `NoSolution`.
Everything runs in a local frame whose origin is the start position (cases may sit at ~1e9 m: the
origin is subtracted in float64 before anything else and added back to the output).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from corridor.controllers.parking import optimise, profile
from corridor.controllers.parking.geometry import TPCAP_VEHICLE, Obstacles, VehicleGeometry
from corridor.controllers.parking.search import SearchFailed, hybrid_astar, merge, reverse

BOUNDS_PAD_M = 8.0  # default search area: the box around start, goal and obstacles, grown by this
SEARCH_SHARE = 0.6  # of the time limit; the rest is for the optimisation
MARGINS_M = (0.03, 0.08)  # corridor margins tried in turn by the optimisation
DENSE_M = 0.02  # spacing of the collision check of the optimised trajectory


class NoSolution(Exception):
    """No trajectory: the message is a one-line reason."""


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
    stage: str = "optimised"  # or "search" (time-parametrised search path, the fallback)

    def direction_changes(self) -> int:
        signs = np.sign(self.v[np.abs(self.v) > 1e-6])
        return int(np.count_nonzero(signs[1:] != signs[:-1]))

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
         vehicle: VehicleGeometry = TPCAP_VEHICLE, *, time_limit_s: float = 30.0, dt_s: float = 0.1,
         bounds: tuple[float, float, float, float] | None = None) -> Trajectory:
    """A collision-free trajectory from ``start`` to ``goal`` (rear-axle poses), or raise NoSolution."""
    t0 = time.perf_counter()
    if dt_s <= 0 or time_limit_s <= 0:
        raise NoSolution(f"dt_s and time_limit_s must be > 0 (got {dt_s}, {time_limit_s})")
    origin = np.array([start[0], start[1]], dtype=np.float64)
    s = np.array([0.0, 0.0, float(start[2])])
    g = np.array([goal[0] - origin[0], goal[1] - origin[1], float(goal[2])])
    polys = [np.asarray(p, dtype=np.float64).reshape(-1, 2) - origin for p in obstacles]
    if bounds is None:
        lb = _default_bounds(s, g, polys)
    else:
        lb = (bounds[0] - origin[0], bounds[1] - origin[0], bounds[2] - origin[1], bounds[3] - origin[1])
    obs = Obstacles(polys)
    for name, pose in (("start", s), ("goal", g)):
        if obs.collides(pose[None], vehicle)[0]:
            raise NoSolution(f"the {name} pose collides with an obstacle")
        if not (lb[0] <= pose[0] <= lb[1] and lb[2] <= pose[1] <= lb[3]):
            raise NoSolution(f"the {name} pose is outside the bounds")
    segments = _search(tuple(s), tuple(g), obs, vehicle, lb, t0, time_limit_s)
    t_search = time.perf_counter() - t0
    states, stage = _optimise(segments, obs, vehicle, dt_s, deadline=t0 + time_limit_s)
    t_opt = time.perf_counter() - t0 - t_search
    return _to_world(states, origin, t_search, t_opt, stage=stage)


def _optimise(segments: list, obs: Obstacles, vehicle: VehicleGeometry, dt_s: float,
              deadline: float) -> tuple[dict[str, np.ndarray], str]:
    """The optimised trajectory if IPOPT solves it and it is collision-free when sampled densely (a
    second try with a wider margin otherwise); else the stop-and-steer search path, which meets every
    limit by construction."""
    for margin in MARGINS_M:
        try:
            sol = optimise.solve(segments, obs, vehicle, deadline, optimise.OptimiseParams(margin_m=margin))
        except optimise.OptimiseFailed:
            continue
        states = optimise.sample(sol, vehicle, dt_s)
        if not _collides_densely(states, obs, vehicle):
            return states, "optimised"
    return profile.sample(profile.phases(segments, vehicle), segments[0].start, vehicle, dt_s), "search"


def _collides_densely(states: dict[str, np.ndarray], obs: Obstacles, vehicle: VehicleGeometry) -> bool:
    x, y, th = states["x"], states["y"], states["theta"]
    n = np.maximum(1, np.ceil(np.hypot(np.diff(x), np.diff(y)) / DENSE_M).astype(int))
    k = np.repeat(np.arange(len(n)), n)
    f = np.concatenate([np.arange(m) / m for m in n])
    poses = np.column_stack([x[k] + f * np.diff(x)[k], y[k] + f * np.diff(y)[k], th[k] + f * np.diff(th)[k]])
    return bool(obs.collides(np.vstack([poses, [[x[-1], y[-1], th[-1]]]]), vehicle).any())


def _search(s: tuple[float, float, float], g: tuple[float, float, float], obs: Obstacles,
            vehicle: VehicleGeometry, lb: tuple[float, ...], t0: float, time_limit_s: float) -> list:
    """Search from the goal out (the tight end of a parking manoeuvre, where leaving is easier than
    entering) and drive the path backwards; if that fails in half the search budget, search forward."""
    budget = SEARCH_SHARE * time_limit_s
    try:
        return merge(reverse(hybrid_astar(g, s, obs, vehicle, lb, t0 + 0.5 * budget)))
    except SearchFailed as exc:
        first = str(exc)
    try:
        return merge(hybrid_astar(s, g, obs, vehicle, lb, t0 + budget))
    except SearchFailed as exc:
        raise NoSolution(f"{exc} (searched from the goal: {first}; time limit {time_limit_s:g} s)") from None


def _to_world(states: dict[str, np.ndarray], origin: np.ndarray, t_search: float, t_opt: float,
              stage: str) -> Trajectory:
    return Trajectory(t=states["t"], x=states["x"] + origin[0], y=states["y"] + origin[1],
                      theta=states["theta"], v=states["v"], a=states["a"], steer=states["steer"],
                      search_time_s=t_search, optimise_time_s=t_opt, stage=stage)
