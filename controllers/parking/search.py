"""Hybrid A* with Reeds–Shepp analytic expansions (Dolgov et al. 2008), forward and reverse.

Nodes are continuous poses binned into (x, y, θ) cells; a node's children are constant-curvature arcs
(steering angles × forward/reverse), all collision-checked in one vectorised call. The cost counts
length, a direction-change penalty and steering effort; the heuristic is the maximum of the
Reeds–Shepp length without obstacles and the holonomic grid distance around the obstacles. Every few
expansions the shortest collision-free Reeds–Shepp path to the goal ends the search.

The result is a list of `Segment`s (constant curvature, signed length): exact arcs, from which the
time parametrisation and the optimiser's warm start are sampled.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass

import numpy as np

from corridor.controllers.parking import reeds_shepp as rs
from corridor.controllers.parking.geometry import Obstacles, VehicleGeometry
from corridor.controllers.parking.heuristic import HolonomicGrid, RsTable


@dataclass(frozen=True)
class SearchParams:
    xy_res_m: float = 0.4
    n_heading: int = 72
    step_m: float = 0.8  # arc length of one primitive
    check_m: float = 0.2  # collision-check spacing along a primitive
    n_steer: int = 7  # steering angles per direction, spread over ±max
    reverse_weight: float = 1.0
    switch_cost_m: float = 4.0  # direction change
    steer_cost_m: float = 0.3  # per primitive at full lock
    steer_change_cost_m: float = 0.6  # per primitive, full-lock to straight
    heuristic_weight: float = 1.5
    margin_m: float = 0.05  # footprint growth for the search (the optimiser keeps its own)
    rs_every: int = 3  # try an analytic expansion every n expansions (when near)
    rs_near_m: float = 25.0


@dataclass(frozen=True)
class Segment:
    start: tuple[float, float, float]
    kappa: float  # [1/m], >0 left
    length_m: float  # signed: <0 reverse

    def poses(self, step_m: float) -> np.ndarray:
        """Poses (n+1, 3) at most ``step_m`` apart, both ends included."""
        n = max(1, int(np.ceil(abs(self.length_m) / step_m)))
        s = np.linspace(0.0, self.length_m, n + 1)
        return rs.arc(*self.start, s, self.kappa)

    @property
    def end(self) -> tuple[float, float, float]:
        return tuple(float(v) for v in rs.arc(*self.start, np.array([self.length_m]), self.kappa)[0])


class SearchFailed(Exception):
    pass


def _primitives(vehicle: VehicleGeometry, p: SearchParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Curvatures (P,), signed lengths (P,), local poses (P, m, 3) of the motion primitives."""
    steer = np.linspace(-vehicle.max_steer_rad, vehicle.max_steer_rad, p.n_steer)
    kap = np.tan(steer) / vehicle.wheelbase_m
    kappas = np.concatenate([kap, kap])
    lengths = np.concatenate([np.full(p.n_steer, p.step_m), np.full(p.n_steer, -p.step_m)])
    m = int(np.ceil(p.step_m / p.check_m))
    local = np.stack([rs.arc(0.0, 0.0, 0.0, np.linspace(0, L, m + 1)[1:], k) for k, L in zip(kappas, lengths)])
    return kappas, lengths, local


def _compose(base: np.ndarray, local: np.ndarray) -> np.ndarray:
    c, s = np.cos(base[2]), np.sin(base[2])
    return np.stack([base[0] + c * local[..., 0] - s * local[..., 1],
                     base[1] + s * local[..., 0] + c * local[..., 1], base[2] + local[..., 2]], axis=-1)


def hybrid_astar(start: tuple[float, float, float], goal: tuple[float, float, float], obstacles: Obstacles,
                 vehicle: VehicleGeometry, bounds: tuple[float, float, float, float], deadline: float,
                 p: SearchParams | None = None) -> list[Segment]:
    """Segments from ``start`` to ``goal`` (local frame), or raise SearchFailed with a reason."""
    p = p or SearchParams()
    box = vehicle.box(p.margin_m)
    for name, pose in (("start", start), ("goal", goal)):
        if obstacles.collides_boxes(np.array([pose]), vehicle.box(0.0))[0]:
            raise SearchFailed(f"the {name} pose collides with an obstacle")
    radius = vehicle.min_turn_radius_m
    grid = HolonomicGrid(obstacles.polygons, goal[:2], bounds, res_m=0.3, clearance_m=0.5,
                         free_xy=start[:2])
    if not np.isfinite(grid(np.array([start[:2]]))[0]):
        raise SearchFailed("the goal cannot be reached from the start (no free corridor around the obstacles)")
    rs_h = RsTable(goal, radius)
    kappas, lengths, local = _primitives(vehicle, p)
    steer_of = np.arctan(kappas * vehicle.wheelbase_m) / vehicle.max_steer_rad
    x0, x1, y0, y1 = bounds
    yaw_res = 2 * np.pi / p.n_heading

    def key(pose: np.ndarray) -> tuple[int, int, int]:
        return (int(np.floor(pose[0] / p.xy_res_m)), int(np.floor(pose[1] / p.xy_res_m)),
                int(np.floor((pose[2] % (2 * np.pi)) / yaw_res)) % p.n_heading)

    def h(poses: np.ndarray) -> np.ndarray:
        return np.maximum(grid(poses[:, :2]), rs_h(poses))

    s0 = np.asarray(start, float)
    # node: pose, g, parent, kappa, length, steer (normalised)
    nodes = [(s0, 0.0, -1, 0.0, 0.0, 0.0)]
    heap = [(float(h(s0[None])[0]) * p.heuristic_weight, 0)]
    best_g = {key(s0): 0.0}
    expansions = 0
    while heap:
        if time.perf_counter() > deadline:
            raise SearchFailed(f"the search ran out of time after {expansions} expansions")
        _, ni = heapq.heappop(heap)
        pose, g, _, _, length, steer = nodes[ni]
        if g > best_g.get(key(pose), np.inf) + 1e-9:
            continue
        expansions += 1
        if expansions % p.rs_every == 1 and np.hypot(*(pose[:2] - goal[:2])) < p.rs_near_m:
            tail = _analytic(pose, goal, obstacles, box, radius, bounds)
            if tail is not None:
                return _backtrack(nodes, ni) + tail
        ends = _compose(pose, local)  # (P, m, 3)
        flat = ends.reshape(-1, 3)
        inb = (flat[:, 0] >= x0) & (flat[:, 0] <= x1) & (flat[:, 1] >= y0) & (flat[:, 1] <= y1)
        bad = (obstacles.collides_boxes(flat, box) | ~inb).reshape(ends.shape[:2]).any(axis=1)
        child = ends[:, -1, :]
        hc = h(child)
        for k in np.flatnonzero(~bad & np.isfinite(hc)):
            cost = abs(lengths[k]) * (1.0 if lengths[k] > 0 else p.reverse_weight)
            cost += p.steer_cost_m * abs(steer_of[k]) + p.steer_change_cost_m * abs(steer_of[k] - steer) / 2
            if length != 0.0 and np.sign(length) != np.sign(lengths[k]):
                cost += p.switch_cost_m
            gk = g + cost
            ck = key(child[k])
            if gk < best_g.get(ck, np.inf) - 1e-9:
                best_g[ck] = gk
                nodes.append((child[k], gk, ni, kappas[k], lengths[k], steer_of[k]))
                heapq.heappush(heap, (gk + p.heuristic_weight * hc[k], len(nodes) - 1))
    raise SearchFailed(f"the search space is exhausted after {expansions} expansions: no path")


def _analytic(pose: np.ndarray, goal: tuple[float, float, float], obstacles: Obstacles,
              box: tuple[float, float, float, float], radius: float,
              bounds: tuple[float, float, float, float]) -> list[Segment] | None:
    """The shortest collision-free Reeds–Shepp path from ``pose`` to ``goal`` as segments, if any."""
    x0, x1, y0, y1 = bounds
    for path in rs.paths(tuple(pose), goal, radius, max_paths=6):
        pts, _, _ = rs.sample(tuple(pose), path, radius, step_m=0.1)
        if np.any((pts[:, 0] < x0) | (pts[:, 0] > x1) | (pts[:, 1] < y0) | (pts[:, 1] > y1)):
            continue
        if not obstacles.collides_boxes(pts, box).any():
            segs, at = [], tuple(float(v) for v in pose)
            for ch, L in zip(path.word, path.lengths_m):
                if abs(L) < 1e-9:
                    continue
                seg = Segment(at, {"L": 1.0, "S": 0.0, "R": -1.0}[ch] / radius, L)
                segs.append(seg)
                at = seg.end
            return segs
    return None


def _backtrack(nodes: list, ni: int) -> list[Segment]:
    chain = []
    while nodes[ni][2] >= 0:
        _, _, parent, kappa, length, _ = nodes[ni]
        chain.append(Segment(tuple(float(v) for v in nodes[parent][0]), float(kappa), float(length)))
        ni = parent
    return chain[::-1]


def reverse(segments: list[Segment]) -> list[Segment]:
    """The same path driven the other way (from its end to its start)."""
    return [Segment(seg.end, seg.kappa, -seg.length_m) for seg in reversed(segments)]


def merge(segments: list[Segment]) -> list[Segment]:
    """Join consecutive segments of equal curvature and direction."""
    out: list[Segment] = []
    for s in segments:
        if out and abs(out[-1].kappa - s.kappa) < 1e-9 and np.sign(out[-1].length_m) == np.sign(s.length_m):
            out[-1] = Segment(out[-1].start, s.kappa, out[-1].length_m + s.length_m)
        else:
            out.append(s)
    return out
