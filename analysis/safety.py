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
                      z: np.ndarray | None = None, height: np.ndarray | None = None,
                      involving: np.ndarray | None = None) -> np.ndarray:
    """Index pairs (M, 2), i < j, of rectangles that overlap (separating-axis test), optionally also
    overlapping in altitude.  A circle pre-filter keeps the exact test to near pairs.

    ``involving``: only pairs with at least one of these rows (a few controlled vehicles among many:
    the pre-filter is then (k, N) instead of (N, N)); the pairs come in the same (i, j) order."""
    n = len(center_xy)
    if n < 2:
        return np.zeros((0, 2), dtype=int)
    radius = 0.5 * np.hypot(length, width)
    if involving is None and tree_is_cheaper(n, n):
        i, j = _near_pairs_tree(center_xy, radius, z, height)
    elif involving is None:
        d = np.linalg.norm(center_xy[:, None, :] - center_xy[None, :, :], axis=-1)
        near = np.triu(d <= radius[:, None] + radius[None, :], k=1)
        if z is not None and height is not None:
            near &= np.abs(z[:, None] - z[None, :]) <= 0.5 * (height[:, None] + height[None, :])
        i, j = np.nonzero(near)
    else:
        i, j = _near_pairs_involving(np.asarray(involving, dtype=np.int64), center_xy, radius, z, height)
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


DENSE_FIXED_CELLS = 1000  # [cells] the k-d tree's fixed cost (build, query set-up: ~0.15 ms) in dense cells
DENSE_CELLS_PER_ROW = 6  # [cells] its cost per row (~1 us) in dense cells (~0.17 us each: distances, closest approaches)


def tree_is_cheaper(k: int, n: int) -> bool:
    """Whether the pairs of ``k`` rows with ``n`` rows are found faster by a k-d tree over the ``n``
    rows than by the dense (k, n) matrix (here and in ``ccd.swept_overlaps``; both give the same pairs
    and values, bit for bit). The dense cost grows with k * n, the tree's with n: a few controlled
    vehicles among many stay dense, a sharded city rank's 450 aircraft among its 450 rows (50 ms
    dense, 0.4 ms with the tree, measured) do not."""
    return k * n > DENSE_FIXED_CELLS + DENSE_CELLS_PER_ROW * n


def _near_pairs_tree(center_xy: np.ndarray, radius: np.ndarray, z: np.ndarray | None,
                     height: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The (N, N) circle pre-filter of ``obb_overlap_pairs`` for many rows: a k-d tree proposes the
    pairs closer than the largest radius sum, then the same test as the dense path, term by term, in
    the same row-major (i, j) order (a city of 10,000 aircraft: 10^8 distances per tick otherwise)."""
    from scipy.spatial import cKDTree

    reach = 2.0 * float(radius.max())
    ij = cKDTree(center_xy).query_pairs(reach * (1.0 + 1e-9) + 1e-9, output_type="ndarray").reshape(-1, 2)
    i, j = np.minimum(ij[:, 0], ij[:, 1]), np.maximum(ij[:, 0], ij[:, 1])
    near = np.linalg.norm(center_xy[i] - center_xy[j], axis=-1) <= radius[i] + radius[j]
    if z is not None and height is not None:
        near &= np.abs(z[i] - z[j]) <= 0.5 * (height[i] + height[j])
    i, j = i[near], j[near]
    order = np.lexsort((j, i))
    return i[order].astype(np.int64), j[order].astype(np.int64)


def _near_pairs_involving(rows: np.ndarray, center_xy: np.ndarray, radius: np.ndarray, z: np.ndarray | None,
                          height: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The circle pre-filter of ``obb_overlap_pairs`` for the pairs with a row of ``rows``: (i, j),
    i < j, in row-major order (the same distances and sums as the full (N, N) test, term by term)."""
    n = len(center_xy)
    if tree_is_cheaper(len(rows), n):
        i, j = _near_pairs_tree(center_xy, radius, z, height)
        listed = np.zeros(n, dtype=bool)
        listed[rows] = True
        keep = listed[i] | listed[j]
        return i[keep], j[keep]
    d = np.linalg.norm(center_xy[rows][:, None, :] - center_xy[None, :, :], axis=-1)
    near = d <= radius[rows][:, None] + radius[None, :]
    if z is not None and height is not None:
        near &= np.abs(z[rows][:, None] - z[None, :]) <= 0.5 * (height[rows][:, None] + height[None, :])
    a, b = np.nonzero(near)
    a = rows[a]
    keep = a != b
    lo, hi = np.minimum(a[keep], b[keep]), np.maximum(a[keep], b[keep])
    key = np.unique(lo * n + hi)  # a pair of two listed rows is found from both ends once; sorted (i, j)
    return key // n, key % n


def _edge_normals(corners: np.ndarray) -> np.ndarray:
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 3] - corners[:, 0]
    return np.stack([e1, e2], axis=1)  # rectangle: two edge directions are the two axes


def lane_leaders(code: np.ndarray, lane_pos: np.ndarray,
                 group: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(follower, leader) row indices of consecutive vehicles on the same lane (integer lane codes
    >= 0); with ``group`` (integers >= 0, e.g. the tick of each row of several ticks' rows), within
    the same group only.  Rows at the same position on a lane keep their row order."""
    if len(code) < 2:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    if group is None:
        order = np.lexsort((lane_pos, code))
        same = code[order[:-1]] == code[order[1:]]
        return order[:-1][same], order[1:][same]
    key = group * (int(np.maximum.reduce(code)) + 1) + code  # (group, lane) as one integer
    order = _lane_order(key, lane_pos)
    k = key[order]
    same = k[:-1] == k[1:]
    return order[:-1][same], order[1:][same]


def _lane_order(key: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``np.lexsort((pos, key))``, 5-10x faster on thousands of rows: numpy's SIMD quicksort of the
    positions, then a stable sort of the integer keys (a radix sort when they fit 16 bits).  The
    quicksort orders equal positions arbitrarily; if a lane has any, lexsort's row order is used."""
    order = np.argsort(pos)
    top = int(np.maximum.reduce(key))
    k = key.astype(np.uint16) if top < 2**16 else key
    order = order[np.argsort(k[order], kind="stable")]
    same = key[order[:-1]] == key[order[1:]]
    if np.any(same & (pos[order[:-1]] == pos[order[1:]])) or np.isnan(pos).any():
        return np.lexsort((pos, key))
    return order


def ttc_drac(gap_m: np.ndarray, v_follow: np.ndarray, v_lead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time to collision [s] (inf when not closing) and DRAC [m/s²] (0 when not closing)."""
    closing = v_follow - v_lead
    gap = np.maximum(gap_m, 1e-3)
    closes = closing > 0  # divide only there (no warnings to silence: errstate costs more than the math)
    ttc = np.divide(gap, closing, out=np.full(closing.shape, np.inf), where=closes)
    drac = np.divide(closing * closing, 2 * gap, out=np.zeros(closing.shape), where=closes)
    return ttc, drac
