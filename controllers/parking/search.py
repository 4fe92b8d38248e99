"""Hybrid A* with Reeds–Shepp analytic expansions (Dolgov et al. 2008), forward and reverse.

Nodes are continuous poses binned into (x, y, θ) cells; a node's children are constant-curvature arcs
(steering angles × forward/reverse), all collision-checked in one vectorised call. The cost counts
length, a direction-change penalty and steering effort; the heuristic is the maximum of the
Reeds–Shepp length without obstacles and the holonomic grid distances around the obstacles of the
footprint's centre and of the rear-axle centre (gaps narrower than the car closed). Every few
expansions the shortest collision-free Reeds–Shepp path to the goal ends the search.

The result is a list of `Segment`s (constant curvature, signed length): exact arcs, from which the
time parametrisation and the optimiser's warm start are sampled.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from corridor.controllers.parking import reeds_shepp as rs
from corridor.controllers.parking.geometry import FootprintChecker, Obstacles, VehicleGeometry
from corridor.controllers.parking.heuristic import HolonomicGrid, RsTable

GRID_M = 0.3  # cells of the holonomic heuristic's grid
MICRO_CELL_M, MICRO_HEADING_RAD = 0.05, np.pi / 180  # cells of the search near its first pose


@dataclass(frozen=True)
class SearchParams:
    xy_res_m: float = 0.4
    n_heading: int = 72
    step_m: float = 0.8  # arc length of one primitive
    short_step_m: float = 0.3  # ... and of the short ones, tried where a long one collides
    check_m: float = 0.2  # collision-check spacing along a primitive
    n_steer: int = 7  # steering angles per direction, spread over ±max
    reverse_weight: float = 1.0
    switch_cost_m: float = 4.0  # direction change
    steer_cost_m: float = 0.3  # per primitive at full lock
    steer_change_cost_m: float = 0.6  # per primitive, full-lock to straight
    heuristic_weight: float = 1.5  # weighted A* (> 1: faster, longer paths)
    max_expansions: int = 1_000_000  # the search's budget (deterministic, unlike a time limit)
    margin_m: float = 0.05  # footprint growth for the search (the optimiser keeps its own)
    rs_every: int = 4  # try an analytic expansion every n expansions (when near)
    rs_near_m: float = 25.0
    micro_step_m: float = 0.1  # arc length of the primitives tried where the short ones collide ...
    micro_near_m: float = 2.0  # ... within this distance of the search's first pose (a tight start / goal)
    micro: bool = False  # use them (and finer cells there): for an end the normal search cannot leave


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


class Exhausted(SearchFailed):
    """Every reachable cell expanded (before the budget was spent)."""


def _primitives(vehicle: VehicleGeometry, p: SearchParams,
                step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Curvatures (P,), signed lengths (P,), local poses (P, m, 3) of the motion primitives."""
    steer = np.linspace(-vehicle.max_steer_rad, vehicle.max_steer_rad, p.n_steer)
    kap = np.tan(steer) / vehicle.wheelbase_m
    kappas = np.concatenate([kap, kap])
    lengths = np.concatenate([np.full(p.n_steer, step_m), np.full(p.n_steer, -step_m)])
    m = int(np.ceil(step_m / p.check_m))
    local = np.stack([rs.arc(0.0, 0.0, 0.0, np.linspace(0, L, m + 1)[1:], k) for k, L in zip(kappas, lengths)])
    return kappas, lengths, local


def _compose(base: np.ndarray, local: np.ndarray) -> np.ndarray:
    c, s = np.cos(base[2]), np.sin(base[2])
    return np.stack([base[0] + c * local[..., 0] - s * local[..., 1],
                     base[1] + s * local[..., 0] + c * local[..., 1], base[2] + local[..., 2]], axis=-1)


class HybridAStar:
    """One search from ``start`` to ``goal`` (local frame) that can be run in slices (`run`), so that
    searches from both ends can take turns."""

    def __init__(self, start: tuple[float, float, float], goal: tuple[float, float, float], obstacles: Obstacles,
                 vehicle: VehicleGeometry, bounds: tuple[float, float, float, float],
                 p: SearchParams | None = None, collides: FootprintChecker | None = None) -> None:
        self.p = p = p or SearchParams()
        self.goal, self.bounds = goal, bounds
        self.collides = collides or FootprintChecker(obstacles, vehicle, p.margin_m, bounds)
        for name, pose in (("start", start), ("goal", goal)):
            if obstacles.collides_boxes(np.array([pose]), vehicle.box(0.0))[0]:
                raise SearchFailed(f"the {name} pose collides with an obstacle")
        self.radius = vehicle.min_turn_radius_m
        # holonomic distances around the obstacles of two points of the footprint (grown by the
        # margin): its centre, which keeps half the width from every obstacle, and the rear-axle
        # centre, which keeps the smaller of the rear overhang and the half-width. Gaps narrower than
        # the car are closed to both, so the search is not drawn into them.
        bx0, bx1, by0, by1 = vehicle.box(p.margin_m)
        self.ahead_m = (bx0 + bx1) / 2
        self.grid = HolonomicGrid(obstacles.polygons, tuple(self._centre(np.array([goal]))[0]), bounds, res_m=GRID_M,
                                  clearance_m=(by1 - by0) / 2, free_xy=tuple(self._centre(np.array([start]))[0]))
        self.rgrid = HolonomicGrid(obstacles.polygons, goal[:2], bounds, res_m=GRID_M,
                                  clearance_m=min(-bx0, by1), free_xy=start[:2])
        if not np.isfinite(self.grid(self._centre(np.array([start])))[0]):
            raise SearchFailed("start and goal are not connected around the obstacles (holonomic grid)")
        self.rs_h = RsTable(goal, self.radius)
        self.sets = (_primitives(vehicle, p, p.step_m), _primitives(vehicle, p, p.short_step_m),
                     _primitives(vehicle, p, p.micro_step_m))

        self.steer_of = np.arctan(self.sets[0][0] * vehicle.wheelbase_m) / vehicle.max_steer_rad
        self.root = s0 = np.asarray(start, float)
        self.nodes = [(s0, 0.0, -1, 0.0, 0.0, 0.0)]  # pose, g, parent, kappa, length, steer (normalised)
        self.heap = [(float(self._h(s0[None])[0]) * p.heuristic_weight, 0)]
        self.best_g = {self._key(s0): 0.0}
        self.expansions = 0
        self.dead: set[int] = set()  # nodes cut off with their subtrees (`prune`)
        self.last = 0  # the node the last path found leaves the tree from

    def _key(self, pose: np.ndarray) -> tuple[int, ...]:
        p = self.p
        if p.micro and np.hypot(pose[0] - self.root[0], pose[1] - self.root[1]) <= p.micro_near_m:
            # near a tight end: cells fine enough for the micro primitives to leave them
            q = MICRO_CELL_M
            return (int(np.floor(pose[0] / q)), int(np.floor(pose[1] / q)),
                    int(np.floor((pose[2] % (2 * np.pi)) / MICRO_HEADING_RAD)), 1)
        return (int(np.floor(pose[0] / p.xy_res_m)), int(np.floor(pose[1] / p.xy_res_m)),
                int(np.floor((pose[2] % (2 * np.pi)) / (2 * np.pi / p.n_heading))) % p.n_heading)

    def _centre(self, poses: np.ndarray) -> np.ndarray:
        return poses[:, :2] + self.ahead_m * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])

    def _h(self, poses: np.ndarray) -> np.ndarray:
        return np.maximum(np.maximum(self.grid(self._centre(poses)), self.rgrid(poses[:, :2])), self.rs_h(poses))

    def prune(self, segment: int) -> bool:
        """Cut off the tree below segment number ``segment`` of the last path found (a primitive that
        proved unusable, e.g. clipping an obstacle between its collision checks), so that the search
        can go on without it; False when that segment is not a primitive of the tree (the path's
        analytic tail, which the search will not try again from that node)."""
        chain = []
        ni = self.last
        while ni > 0:
            chain.append(ni)
            ni = self.nodes[ni][2]
        chain.reverse()  # chain[k] is the end node of segment k
        if segment >= len(chain):
            return False
        self.dead.add(chain[segment])
        return True

    def _below_dead(self, ni: int) -> bool:
        while ni > 0:
            if ni in self.dead:
                return True
            ni = self.nodes[ni][2]
        return False

    def run(self, expansions: int) -> list[Segment] | None:
        """Up to ``expansions`` more expansions: the path if found, None if not yet; SearchFailed when
        the space is exhausted or the expansion budget (``max_expansions``) is spent."""
        p = self.p
        stop = self.expansions + expansions
        while self.heap:
            if self.expansions >= stop:
                return None
            _, ni = heapq.heappop(self.heap)
            pose, g, _, _, length, steer = self.nodes[ni]
            if g > self.best_g.get(self._key(pose), np.inf) + 1e-9 or (self.dead and self._below_dead(ni)):
                continue
            self.expansions += 1
            if self.expansions > p.max_expansions:
                raise SearchFailed(f"no path within {p.max_expansions} expansions")
            if self.expansions % p.rs_every == 1 and np.hypot(*(pose[:2] - np.asarray(self.goal[:2]))) < p.rs_near_m:
                tail = _analytic(pose, self.goal, self.collides, self.radius, self.bounds)
                if tail is not None:
                    self.last = ni
                    self._expand(ni, pose, g, length, steer)  # so that the search can go on from here
                    return _backtrack(self.nodes, ni) + tail
            self._expand(ni, pose, g, length, steer)
        raise Exhausted(f"the search space is exhausted after {self.expansions} expansions: no path")

    def _expand(self, ni: int, pose: np.ndarray, g: float, length: float, steer: float) -> None:
        p, (x0, x1, y0, y1) = self.p, self.bounds
        near_root = p.micro and np.hypot(*(pose[:2] - self.root[:2])) <= p.micro_near_m
        for kappas, lengths, local in self.sets[:3 if near_root else 2]:
            ends = _compose(pose, local)  # (P, m, 3)
            flat = ends.reshape(-1, 3)
            inb = (flat[:, 0] >= x0) & (flat[:, 0] <= x1) & (flat[:, 1] >= y0) & (flat[:, 1] <= y1)
            bad = (self.collides(flat) | ~inb).reshape(ends.shape[:2]).any(axis=1)
            child = ends[:, -1, :]
            hc = self._h(child)
            for k in np.flatnonzero(~bad & np.isfinite(hc)):
                cost = abs(lengths[k]) * (1.0 if lengths[k] > 0 else p.reverse_weight)
                cost += p.steer_cost_m * abs(self.steer_of[k]) + p.steer_change_cost_m * abs(self.steer_of[k] - steer) / 2
                if length != 0.0 and np.sign(length) != np.sign(lengths[k]):
                    cost += p.switch_cost_m
                gk = g + cost
                ck = self._key(child[k])
                if gk < self.best_g.get(ck, np.inf) - 1e-9:
                    self.best_g[ck] = gk
                    self.nodes.append((child[k], gk, ni, kappas[k], lengths[k], self.steer_of[k]))
                    heapq.heappush(self.heap, (gk + p.heuristic_weight * hc[k], len(self.nodes) - 1))
            if not bad.any():
                return  # open space: the long primitives are enough


def hybrid_astar(start: tuple[float, float, float], goal: tuple[float, float, float], obstacles: Obstacles,
                 vehicle: VehicleGeometry, bounds: tuple[float, float, float, float],
                 p: SearchParams | None = None) -> list[Segment]:
    """Segments from ``start`` to ``goal`` (local frame), or raise SearchFailed with a reason."""
    search = HybridAStar(start, goal, obstacles, vehicle, bounds, p)
    while True:
        path = search.run(10_000)
        if path is not None:
            return path


def _analytic(pose: np.ndarray, goal: tuple[float, float, float], collides: FootprintChecker, radius: float,
              bounds: tuple[float, float, float, float]) -> list[Segment] | None:
    """The shortest collision-free Reeds–Shepp path from ``pose`` to ``goal`` as segments, if any."""
    x0, x1, y0, y1 = bounds
    for path in rs.paths(tuple(pose), goal, radius, max_paths=4):
        coarse, _, _ = rs.sample(tuple(pose), path, radius, step_m=0.5)
        if collides(coarse).any():  # most candidates fail here, cheaply
            continue
        pts, _, _ = rs.sample(tuple(pose), path, radius, step_m=0.1)
        if np.any((pts[:, 0] < x0) | (pts[:, 0] > x1) | (pts[:, 1] < y0) | (pts[:, 1] > y1)):
            continue
        if not collides(pts).any():
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
