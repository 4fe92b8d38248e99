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

    def _near(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices of edges whose bounding box meets the box [lo, hi]."""
        emin, emax = np.minimum(self.a, self.b), np.maximum(self.a, self.b)
        return np.flatnonzero(np.all((emax >= lo) & (emin <= hi), axis=1))

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
        inside = self._contains(centre, np.flatnonzero(np.isin(self.owner, polys)))
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
        ax, ay, bx, by = self.a[idx, 0], self.a[idx, 1], self.b[idx, 0], self.b[idx, 1]
        px, py = pts[:, 0:1], pts[:, 1:2]
        straddle = (ay[None] > py) != (by[None] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = ax[None] + (py - ay[None]) * (bx - ax)[None] / (by - ay)[None]
        cross = straddle & (px < xc)
        onehot = self.owner[idx][:, None] == np.arange(self.n_polygons)[None]
        counts = cross.astype(np.int32) @ onehot.astype(np.int32)
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
