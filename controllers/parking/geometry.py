"""Vehicle footprint and vectorised collision checks of many poses against polygonal obstacles.

Poses are rear-axle centres (x, y, θ). A pose collides with a polygon when any polygon edge meets the
footprint rectangle (each edge clipped against the rectangle in the vehicle frame, Liang–Barsky,
vectorised over poses × edges) or when the rectangle lies wholly inside the polygon (its centre
inside the polygon, crossing number). This is exact for convex and non-convex simple polygons; the
independent checker (`check.py`) uses shapely instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VehicleGeometry:
    """Size and limits of the car; defaults are the TPCAP benchmark vehicle."""

    wheelbase_m: float = 2.8
    front_hang_m: float = 0.96  # front axle to front bumper
    rear_hang_m: float = 0.929  # rear axle to rear bumper
    width_m: float = 1.942
    max_steer_rad: float = 0.75
    max_speed_mps: float = 2.5
    max_accel_mps2: float = 1.0
    max_steer_rate_rps: float = 0.5

    @property
    def length_m(self) -> float:
        return self.rear_hang_m + self.wheelbase_m + self.front_hang_m

    @property
    def min_turn_radius_m(self) -> float:
        """Radius [m] of the rear-axle centre's circle at full steering."""
        return self.wheelbase_m / float(np.tan(self.max_steer_rad))

    def box(self, margin_m: float = 0.0) -> tuple[float, float, float, float]:
        """Footprint in the vehicle frame as (x_min, x_max, y_min, y_max) [m], grown by ``margin_m``."""
        hw = self.width_m / 2 + margin_m
        return (-self.rear_hang_m - margin_m, self.wheelbase_m + self.front_hang_m + margin_m, -hw, hw)


TPCAP_VEHICLE = VehicleGeometry()  # frozen: safe as a shared default


def footprint(poses: np.ndarray, vehicle: VehicleGeometry, margin_m: float = 0.0) -> np.ndarray:
    """Corners (n, 4, 2) of the footprints at poses (n, 3), counter-clockwise from rear right."""
    x0, x1, y0, y1 = vehicle.box(margin_m)
    return box_corners(np.atleast_2d(poses), np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))


def box_corners(poses: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Points ``local`` (k, 2) given in each pose's frame, in the world frame: (n, k, 2)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    lx, ly = local[None, :, 0], local[None, :, 1]
    return np.stack([poses[:, 0:1] + c * lx - s * ly, poses[:, 1:2] + s * lx + c * ly], axis=-1)


class Obstacles:
    """Polygons flattened to edges once, for many collision queries."""

    def __init__(self, polygons: Sequence[np.ndarray]) -> None:
        starts, ends, owner = [], [], []
        for i, poly in enumerate(polygons):
            p = np.asarray(poly, dtype=float).reshape(-1, 2)
            if len(p) >= 2:
                starts.append(p)
                ends.append(np.roll(p, -1, axis=0))
                owner.append(np.full(len(p), i))
        self.polygons = [np.asarray(p, dtype=float).reshape(-1, 2) for p in polygons]
        self.a = np.vstack(starts) if starts else np.zeros((0, 2))
        self.b = np.vstack(ends) if ends else np.zeros((0, 2))
        self.owner = np.concatenate(owner) if owner else np.zeros(0, dtype=int)
        self.n_polygons = len(self.polygons)
        lo = np.array([p.min(axis=0) for p in self.polygons]) if self.polygons else np.zeros((0, 2))
        hi = np.array([p.max(axis=0) for p in self.polygons]) if self.polygons else np.zeros((0, 2))
        self._poly_lo, self._poly_hi = lo, hi
        self._emin, self._emax = np.minimum(self.a, self.b), np.maximum(self.a, self.b)

    def _near(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices of edges whose bounding box meets the box [lo, hi]."""
        return np.flatnonzero(np.all((self._emax >= lo) & (self._emin <= hi), axis=1))

    def collides_boxes(self, poses: np.ndarray, box: tuple[float, float, float, float] | np.ndarray) -> np.ndarray:
        """Boolean (n,): does the rectangle ``box`` (x_min, x_max, y_min, y_max in each pose's
        frame; one for all poses or one row (n, 4) per pose) at each pose (n, 3) meet any polygon?"""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        n = len(poses)
        if n == 0 or len(self.a) == 0:
            return np.zeros(n, dtype=bool)
        ext = np.broadcast_to(np.asarray(box, dtype=float), (n, 4))
        x0, x1, y0, y1 = (ext[:, j:j + 1] for j in range(4))
        reach = float(np.hypot(np.abs(ext[:, :2]).max(), np.abs(ext[:, 2:]).max()))
        lo, hi = poses[:, :2].min(axis=0) - reach, poses[:, :2].max(axis=0) + reach
        idx = self._near(lo, hi)
        # containment needs every edge of a polygon (parity), so whole polygons near the poses
        polys = np.flatnonzero(np.all((self._poly_hi >= lo) & (self._poly_lo <= hi), axis=1))
        if len(polys) == 0:
            return np.zeros(n, dtype=bool)
        cx, cy = (x0[:, 0] + x1[:, 0]) / 2, (y0[:, 0] + y1[:, 0]) / 2
        c0, s0 = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        centre = np.column_stack([poses[:, 0] + c0 * cx - s0 * cy, poses[:, 1] + s0 * cx + c0 * cy])
        in_bbox = np.all((centre[:, None] >= self._poly_lo[polys][None]) & (centre[:, None] <= self._poly_hi[polys][None]),
                         axis=2).any(axis=1)
        inside = np.zeros(n, dtype=bool)
        if in_bbox.any():  # only centres within some polygon's bounding box can be inside it
            inside[in_bbox] = self._contains(centre[in_bbox], np.flatnonzero(np.isin(self.owner, polys)))
        if len(idx) == 0:
            return inside
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        ax, ay = self.a[idx, 0][None] - poses[:, 0:1], self.a[idx, 1][None] - poses[:, 1:2]
        bx, by = self.b[idx, 0][None] - poses[:, 0:1], self.b[idx, 1][None] - poses[:, 1:2]
        pax, pay = c * ax + s * ay, -s * ax + c * ay  # edge ends in the vehicle frame
        pbx, pby = c * bx + s * by, -s * bx + c * by
        hit = _segments_meet_box(pax, pay, pbx - pax, pby - pay, (x0, x1, y0, y1))
        return hit.any(axis=1) | inside

    def collides(self, poses: np.ndarray, vehicle: VehicleGeometry, margin_m: float = 0.0) -> np.ndarray:
        """Boolean (n,): does the footprint at each pose (n, 3), grown by ``margin_m``, meet a polygon?"""
        return self.collides_boxes(poses, vehicle.box(margin_m))

    def _contains(self, pts: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Boolean (n,): is each point inside any polygon owning an edge in ``idx`` (crossing number)?"""
        if len(idx) == 0:
            return np.zeros(len(pts), dtype=bool)
        ax, ay, bx, by = self.a[idx, 0], self.a[idx, 1], self.b[idx, 0], self.b[idx, 1]
        px, py = pts[:, 0:1], pts[:, 1:2]
        straddle = (ay[None] > py) != (by[None] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = ax[None] + (py - ay[None]) * (bx - ax)[None] / (by - ay)[None]
        cross = straddle & (px < xc)
        # crossings per polygon: ``idx`` is sorted and each polygon's edges are contiguous
        own = self.owner[idx]
        first = np.flatnonzero(np.r_[True, own[1:] != own[:-1]])
        counts = np.add.reduceat(cross.astype(np.int32), first, axis=1)
        return np.any(counts % 2 == 1, axis=1)


def _segments_meet_box(x: np.ndarray, y: np.ndarray, dx: np.ndarray, dy: np.ndarray,
                       box: tuple[float | np.ndarray, ...]) -> np.ndarray:
    """Liang–Barsky: does segment (x, y) + t (dx, dy), t in [0, 1], meet the axis-aligned box?"""
    x0, x1, y0, y1 = box
    t_in, t_out = np.zeros_like(x), np.ones_like(x)
    ok = np.ones(x.shape, dtype=bool)
    for p, d, lo, hi in ((x, dx, x0, x1), (y, dy, y0, y1)):
        flat = np.abs(d) < 1e-12
        ok &= ~flat | ((p >= lo) & (p <= hi))
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (lo - p) / d, (hi - p) / d
        t_in = np.where(flat, t_in, np.maximum(t_in, np.minimum(ta, tb)))
        t_out = np.where(flat, t_out, np.minimum(t_out, np.maximum(ta, tb)))
    return ok & (t_in <= t_out)


class FootprintChecker:
    """Collision checks of the footprint for many poses, exact but mostly answered by a distance grid.

    The footprint (grown by ``margin_m``) lies between three inscribed discs (radius = half-width)
    and four covering discs along its axis. With the obstacles' distance field on a grid: a pose
    whose covering discs all clear the obstacles (by the grid's error) is free; one with an inscribed
    disc overlapping an obstacle collides; only the poses in between get the exact edge test.
    """

    def __init__(self, obstacles: Obstacles, vehicle: VehicleGeometry, margin_m: float,
                 bounds: tuple[float, float, float, float], res_m: float = 0.1) -> None:
        from matplotlib.path import Path as MplPath
        from scipy import ndimage

        self.obstacles, self.box, self.res_m = obstacles, vehicle.box(margin_m), res_m
        x0, x1, y0, y1 = self.box
        half_w, length = (y1 - y0) / 2, x1 - x0
        self.inner_x = np.linspace(x0 + half_w, x1 - half_w, 3)
        self.inner_r = half_w
        seg = length / 4
        self.outer_x = x0 + seg * (np.arange(4) + 0.5)
        self.outer_r = float(np.hypot(seg / 2, half_w))
        bx0, bx1, by0, by1 = bounds
        pad = self.outer_r + 1.0
        self.origin = np.array([bx0 - pad, by0 - pad])
        nx = int(np.ceil((bx1 - bx0 + 2 * pad) / res_m)) + 1
        ny = int(np.ceil((by1 - by0 + 2 * pad) / res_m)) + 1
        occ = np.zeros((nx, ny), dtype=bool)
        for poly in obstacles.polygons:
            lo = np.clip(np.floor((poly.min(axis=0) - self.origin) / res_m).astype(int), 0, [nx - 1, ny - 1])
            hi = np.clip(np.ceil((poly.max(axis=0) - self.origin) / res_m).astype(int), 0, [nx - 1, ny - 1])
            gi, gj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
            pts = self.origin + res_m * np.column_stack([gi.ravel(), gj.ravel()])
            occ[gi.ravel(), gj.ravel()] |= MplPath(poly).contains_points(pts)
            a, b = poly, np.roll(poly, -1, axis=0)
            n = max(2, int(np.ceil(np.hypot(*(b - a).T).max() / (0.25 * res_m))) + 1)
            t = np.linspace(0.0, 1.0, n)[None, :, None]
            ij = np.rint(((a[:, None] + t * (b - a)[:, None]).reshape(-1, 2) - self.origin) / res_m).astype(int)
            ok = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
            occ[ij[ok, 0], ij[ok, 1]] = True
        # distance from each cell centre to the nearest occupied cell centre; the true distance of a
        # point to the obstacles differs by at most one cell diagonal
        self.dist_m = ndimage.distance_transform_edt(~occ) * res_m
        self.err_m = 1.5 * res_m * np.sqrt(2)
        self.shape = (nx, ny)

    def _dist(self, poses: np.ndarray, along: np.ndarray) -> np.ndarray:
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        px, py = poses[:, 0:1] + c * along[None], poses[:, 1:2] + s * along[None]
        i = np.rint((px - self.origin[0]) / self.res_m).astype(int)
        j = np.rint((py - self.origin[1]) / self.res_m).astype(int)
        inside = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        d = self.dist_m[np.clip(i, 0, self.shape[0] - 1), np.clip(j, 0, self.shape[1] - 1)]
        return np.where(inside, d, np.inf)  # off the grid: farther than the padding from everything

    def __call__(self, poses: np.ndarray) -> np.ndarray:
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        free = np.all(self._dist(poses, self.outer_x) > self.outer_r + self.err_m, axis=1)
        hit = np.any(self._dist(poses, self.inner_x) < self.inner_r - self.err_m, axis=1)
        out = hit.copy()
        unsure = ~free & ~hit
        if unsure.any():
            out[unsure] = self.obstacles.collides_boxes(poses[unsure], self.box)
        return out
