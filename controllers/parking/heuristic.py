"""Admissible cost-to-go estimates for the Hybrid A* search, both towards one goal pose.

- `HolonomicGrid`: shortest 8-connected grid distance from each cell to the goal around the obstacles
  (grown by a fraction of the car's half-width: no rear-axle centre can be closer than that to an
  obstacle), by Dijkstra over a sparse graph (scipy).
- `RsTable`: Reeds–Shepp length without obstacles, tabulated once per turning radius over poses
  relative to the goal (the table depends on nothing else, so it is cached per process); poses
  outside the table fall back to the straight-line distance, a lower bound of it.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from matplotlib.path import Path as MplPath
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from corridor.controllers.parking import reeds_shepp as rs


class HolonomicGrid:
    def __init__(self, polygons: list[np.ndarray], goal_xy: tuple[float, float],
                 bounds: tuple[float, float, float, float], res_m: float, clearance_m: float,
                 free_xy: tuple[float, float] | None = None) -> None:
        x0, x1, y0, y1 = bounds
        self.res_m, self.origin = res_m, np.array([x0, y0])
        nx, ny = int(np.ceil((x1 - x0) / res_m)) + 1, int(np.ceil((y1 - y0) / res_m)) + 1
        gx, gy = np.meshgrid(x0 + res_m * np.arange(nx), y0 + res_m * np.arange(ny), indexing="ij")
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        self.shape = (nx, ny)
        occ = np.zeros((nx, ny), dtype=bool)
        for poly in polygons:  # cells inside: tested only within the polygon's bounding box
            lo, hi = self.cell(poly.min(axis=0)[None])[0], self.cell(poly.max(axis=0)[None])[0] + 1
            gi, gj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
            gi, gj = gi.ravel().clip(0, nx - 1), gj.ravel().clip(0, ny - 1)
            occ[gi, gj] |= MplPath(poly).contains_points(pts[gi * ny + gj])
        for poly in polygons:  # edges too, so thin obstacles are not missed between cell centres
            a, b = poly, np.roll(poly, -1, axis=0)
            n = max(2, int(np.ceil(np.hypot(*(b - a).T).max() / (0.5 * res_m))) + 1)
            t = np.linspace(0, 1, n)[None, :, None]
            ij = self.cell((a[:, None] + t * (b - a)[:, None]).reshape(-1, 2))
            occ[ij[:, 0], ij[:, 1]] = True
        dist_m = ndimage.distance_transform_edt(~occ) * res_m
        blocked = occ | (dist_m < clearance_m)
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
