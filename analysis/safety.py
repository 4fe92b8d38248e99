"""Safety measures on the world snapshot, vectorised: oriented-box overlap (collisions between any
entities), in-lane time-to-collision and deceleration-rate-to-avoid-crash, hard braking."""

from __future__ import annotations

import numpy as np


def box_corners(center_xy: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Corners (N, 4, 2) of oriented rectangles."""
    c, s = np.cos(yaw), np.sin(yaw)
    ax = np.stack([c, s], axis=-1) * (0.5 * length)[:, None]  # half-length along heading
    ay = np.stack([-s, c], axis=-1) * (0.5 * width)[:, None]
    ctr = center_xy[:, None, :]
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=float)
    return ctr + signs[None, :, 0:1] * ax[:, None, :] + signs[None, :, 1:2] * ay[:, None, :]


def obb_overlap_pairs(center_xy: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray,
                      z: np.ndarray | None = None, height: np.ndarray | None = None) -> np.ndarray:
    """Index pairs (M, 2), i < j, of rectangles that overlap (separating-axis test), optionally also
    overlapping in altitude.  A circle pre-filter keeps the exact test to near pairs."""
    n = len(center_xy)
    if n < 2:
        return np.zeros((0, 2), dtype=int)
    radius = 0.5 * np.hypot(length, width)
    d = np.linalg.norm(center_xy[:, None, :] - center_xy[None, :, :], axis=-1)
    near = np.triu(d <= radius[:, None] + radius[None, :], k=1)
    if z is not None and height is not None:
        near &= np.abs(z[:, None] - z[None, :]) <= 0.5 * (height[:, None] + height[None, :])
    i, j = np.nonzero(near)
    if len(i) == 0:
        return np.zeros((0, 2), dtype=int)
    corners = box_corners(center_xy, yaw, length, width)
    ci, cj = corners[i], corners[j]
    axes = np.concatenate([_edge_normals(ci), _edge_normals(cj)], axis=1)  # (M, 4, 2)
    pi = np.einsum("mkd,mad->mka", ci, axes)  # projections (M, 4 corners, 4 axes)
    pj = np.einsum("mkd,mad->mka", cj, axes)
    separated = (pi.max(axis=1) < pj.min(axis=1)) | (pj.max(axis=1) < pi.min(axis=1))
    hit = ~separated.any(axis=1)
    return np.column_stack([i[hit], j[hit]])


def _edge_normals(corners: np.ndarray) -> np.ndarray:
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 3] - corners[:, 0]
    return np.stack([e1, e2], axis=1)  # rectangle: two edge directions are the two axes


def lane_leaders(code: np.ndarray, lane_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(follower, leader) row indices of consecutive vehicles on the same lane (integer lane codes)."""
    if len(code) < 2:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    order = np.lexsort((lane_pos, code))
    same = code[order[:-1]] == code[order[1:]]
    return order[:-1][same], order[1:][same]


def ttc_drac(gap_m: np.ndarray, v_follow: np.ndarray, v_lead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time to collision [s] (inf when not closing) and DRAC [m/s²] (0 when not closing)."""
    closing = v_follow - v_lead
    gap = np.maximum(gap_m, 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, gap / closing, np.inf)
        drac = np.where(closing > 0, closing**2 / (2 * gap), 0.0)
    return ttc, drac
