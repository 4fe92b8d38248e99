"""Clearance between a vehicle footprint and polygonal obstacles, vectorised with numpy.

The distance between two convex polygons that do not overlap is the smallest distance from a vertex
of one to an edge of the other; overlapping polygons (separating-axis test) have clearance 0.
"""

from __future__ import annotations

import numpy as np


def _point_edge_dist(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (P, E) from points (P, 2) to segments a-b (E, 2)."""
    ab = b - a
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("pek,ek->pe", ap, ab) / np.maximum(np.einsum("ek,ek->e", ab, ab), 1e-12), 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=-1)


def _overlap(p: np.ndarray, polys: np.ndarray) -> np.ndarray:
    """Separating-axis overlap of convex polygon ``p`` (k, 2) with each of ``polys`` (m, j, 2)."""
    def normals(q: np.ndarray) -> np.ndarray:
        e = np.roll(q, -1, axis=-2) - q
        return np.stack([-e[..., 1], e[..., 0]], axis=-1)

    m = len(polys)
    axes = np.concatenate([np.broadcast_to(normals(p), (m, *p.shape)), normals(polys)], axis=1)  # (m, A, 2)
    pa = np.einsum("kd,mad->mka", p, axes)
    pb = np.einsum("mjd,mad->mja", polys, axes)
    sep = (pa.max(axis=1) < pb.min(axis=1)) | (pb.max(axis=1) < pa.min(axis=1))
    return ~sep.any(axis=1)


def clearances(footprint: np.ndarray, polys: np.ndarray) -> np.ndarray:
    """Distance [m] from the convex ``footprint`` (k, 2) to each convex polygon of ``polys``
    (m, j, 2; all with j vertices); 0 where they overlap."""
    polys = np.asarray(polys, dtype=float)
    if polys.size == 0:
        return np.zeros(0)
    m, j, _ = polys.shape
    fa, fb = footprint, np.roll(footprint, -1, axis=0)
    oa, ob = polys.reshape(-1, 2), np.roll(polys, -1, axis=1).reshape(-1, 2)
    d1 = _point_edge_dist(footprint, oa, ob).reshape(len(footprint), m, j).min(axis=(0, 2))
    d2 = _point_edge_dist(polys.reshape(-1, 2), fa, fb).reshape(m, j, -1).min(axis=(1, 2))
    d = np.minimum(d1, d2)
    d[_overlap(footprint, polys)] = 0.0
    return d


def box_polygons(centre_xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """(n, 4, 2) corners of oriented boxes (counter-clockwise)."""
    centre_xy = np.atleast_2d(centre_xy)
    c, s = np.cos(heading), np.sin(heading)
    lx = np.array([-0.5, 0.5, 0.5, -0.5])[None, :] * np.atleast_1d(length)[:, None]
    ly = np.array([-0.5, -0.5, 0.5, 0.5])[None, :] * np.atleast_1d(width)[:, None]
    x = centre_xy[:, 0:1] + lx * np.atleast_1d(c)[:, None] - ly * np.atleast_1d(s)[:, None]
    y = centre_xy[:, 1:2] + lx * np.atleast_1d(s)[:, None] + ly * np.atleast_1d(c)[:, None]
    return np.stack([x, y], axis=-1)
