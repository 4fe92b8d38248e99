"""Admissible cost-to-go estimates for the Hybrid A* search, both towards one goal pose.

- `HolonomicGrid`: shortest 8-connected grid distance from each cell to the goal around the obstacles
  for a point of the footprint that keeps a known clearance from every obstacle (the footprint's
  centre keeps half the car's width), by Dijkstra over a sparse graph (scipy). Cells are blocked
  from exact point-to-polygon distances, only where no point of the cell has that clearance.
- `RsTable`: Reeds–Shepp length without obstacles, tabulated once per turning radius over poses
  relative to the goal (the table depends on nothing else, so it is cached per process); poses
  outside the table fall back to the straight-line distance, a lower bound of it.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from matplotlib.path import Path as MplPath
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from corridor.controllers.parking import reeds_shepp as rs


class HolonomicGrid:
    """Shortest 8-connected grid distance [m] from a point to ``goal_xy`` around the obstacles, for a
    point that must keep ``clearance_m`` from every obstacle. A node is blocked only when every point
    of its cell is closer than that (exact point-to-polygon distances at the nodes), so no reachable
    point is ever cut off; ``goal_xy`` and ``free_xy`` are never blocked."""

    def __init__(self, polygons: list[np.ndarray], goal_xy: tuple[float, float],
                 bounds: tuple[float, float, float, float], res_m: float, clearance_m: float,
                 free_xy: tuple[float, float] | None = None) -> None:
        x0, x1, y0, y1 = bounds
        self.res_m, self.origin = res_m, np.array([x0, y0])
        nx, ny = int(np.ceil((x1 - x0) / res_m)) + 1, int(np.ceil((y1 - y0) / res_m)) + 1
        self.shape = (nx, ny)
        need_m = clearance_m - res_m / np.sqrt(2)  # a node this far away leaves room somewhere in its cell
        blocked = distance_field(polygons, self.origin, res_m, self.shape, need_m) < need_m
        for xy in (goal_xy, free_xy):
            if xy is not None:
                ci = self.cell(np.asarray(xy, float)[None])[0]
                blocked[max(ci[0] - 1, 0):ci[0] + 2, max(ci[1] - 1, 0):ci[1] + 2] = False
        gi = self.cell(np.asarray(goal_xy, float)[None])[0]
        self.cost_m = self._dijkstra(blocked, int(gi[0] * ny + gi[1]))

    def _dijkstra(self, blocked: np.ndarray, goal_index: int) -> np.ndarray:
        nx, ny = blocked.shape
        idx = np.arange(nx * ny).reshape(nx, ny)
        rows, cols, w = [], [], []
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            a = idx[max(0, -dx):nx - max(0, dx), max(0, -dy):ny - max(0, dy)]
            b = idx[max(0, dx):nx - max(0, -dx) or None, max(0, dy):ny - max(0, -dy) or None]
            ok = ~blocked.ravel()[a.ravel()] & ~blocked.ravel()[b.ravel()]
            rows.append(a.ravel()[ok])
            cols.append(b.ravel()[ok])
            w.append(np.full(ok.sum(), self.res_m * np.hypot(dx, dy)))
        r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
        graph = coo_matrix((ww, (r, c)), shape=(nx * ny, nx * ny)).tocsr()
        cost = dijkstra(graph, directed=False, indices=goal_index)
        return cost.reshape(nx, ny)

    def cell(self, xy: np.ndarray) -> np.ndarray:
        ij = np.rint((xy - self.origin) / self.res_m).astype(int)
        return np.clip(ij, 0, np.array(self.shape) - 1)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        ij = self.cell(xy)
        return self.cost_m[ij[:, 0], ij[:, 1]]


def distance_field(polygons: list[np.ndarray], origin: np.ndarray, res_m: float, shape: tuple[int, int],
                   upto_m: float) -> np.ndarray:
    """Exact distance [m] from each grid node ``origin + res_m * (i, j)`` to the nearest polygon (0
    inside one), computed only where it is below ``upto_m`` (elsewhere ``inf``)."""
    dist = np.full(shape, np.inf)
    hi_ij = np.array(shape) - 1
    for poly in polygons:
        lo = np.clip(np.floor((poly.min(axis=0) - upto_m - origin) / res_m).astype(int), 0, hi_ij)
        hi = np.clip(np.ceil((poly.max(axis=0) + upto_m - origin) / res_m).astype(int), 0, hi_ij)
        gi, gj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        pts = origin + res_m * np.column_stack([gi.ravel(), gj.ravel()])
        a, b = poly, np.roll(poly, -1, axis=0)
        ab = b - a
        ap = pts[:, None, :] - a[None]
        t = np.clip(np.einsum("pek,ek->pe", ap, ab) / np.maximum(np.einsum("ek,ek->e", ab, ab), 1e-12), 0.0, 1.0)
        d = np.hypot(*np.moveaxis(ap - t[..., None] * ab[None], -1, 0)).min(axis=1)
        d[MplPath(poly).contains_points(pts)] = 0.0
        view = dist[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1]
        np.minimum(view, d.reshape(view.shape), out=view)
    return dist


@lru_cache(maxsize=4)
def _rs_table(radius_m: float, half_m: float, res_m: float, n_heading: int) -> np.ndarray:
    xs = np.arange(-half_m, half_m + 1e-9, res_m)
    th = np.arange(n_heading) * 2 * np.pi / n_heading
    gx, gy, gt = np.meshgrid(xs, xs, th, indexing="ij")
    poses = np.stack([gx, gy, gt], axis=-1).reshape(-1, 3)
    lengths = rs.shortest_lengths(np.zeros_like(poses), poses, radius_m)
    return lengths.reshape(gx.shape)


class RsTable:
    """Reeds–Shepp length [m] from a pose to ``goal`` (equal to the length from the goal to it)."""

    def __init__(self, goal: tuple[float, float, float], radius_m: float, half_m: float = 12.0,
                 res_m: float = 1.0, n_heading: int = 36) -> None:
        self.goal, self.half_m, self.res_m, self.n_heading = np.asarray(goal, float), half_m, res_m, n_heading
        self.table = _rs_table(round(radius_m, 6), half_m, res_m, n_heading)

    def __call__(self, poses: np.ndarray) -> np.ndarray:
        dx, dy = poses[:, 0] - self.goal[0], poses[:, 1] - self.goal[1]
        c, s = np.cos(self.goal[2]), np.sin(self.goal[2])
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        dth = (poses[:, 2] - self.goal[2]) % (2 * np.pi)
        n = self.table.shape[0]
        i = np.rint((lx + self.half_m) / self.res_m).astype(int)
        j = np.rint((ly + self.half_m) / self.res_m).astype(int)
        k = np.rint(dth / (2 * np.pi / self.n_heading)).astype(int) % self.n_heading
        inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        val = self.table[np.clip(i, 0, n - 1), np.clip(j, 0, n - 1), k]
        # the table is sampled: subtract the largest change of length within half a cell (Lipschitz 1
        # in position) so the estimate stays (nearly) a lower bound
        return np.where(inside, np.maximum(val - self.res_m * 0.71, 0.0), np.hypot(dx, dy))
