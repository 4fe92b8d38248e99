"""The k-d tree pre-filter of ``obb_overlap_pairs`` (many rows) gives the dense path's pairs, in order."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from corridor.analysis import safety


@pytest.mark.parametrize("with_z", [False, True])
def test_tree_prefilter_equals_dense(monkeypatch: pytest.MonkeyPatch, with_z: bool) -> None:
    rng = np.random.default_rng(3)
    n = 1500
    xy = rng.uniform(0.0, 300.0, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    length, width = rng.uniform(0.3, 6.0, n), rng.uniform(0.3, 2.5, n)
    z, h = (rng.uniform(0.0, 5.0, n), rng.uniform(0.2, 3.0, n)) if with_z else (None, None)
    tree = safety.obb_overlap_pairs(xy, yaw, length, width, z, h)
    monkeypatch.setattr(safety, "DENSE_FIXED_CELLS", 10 * n * n)  # the dense path
    dense = safety.obb_overlap_pairs(xy, yaw, length, width, z, h)
    assert len(dense) > 20
    np.testing.assert_array_equal(tree, dense)


def _moving_boxes(n: int, seed: int, side_m: float = 200.0) -> tuple[Any, Any]:
    from corridor.analysis.ccd import Poses

    rng = np.random.default_rng(seed)
    p0 = np.column_stack([rng.uniform(0.0, side_m, (n, 2)), rng.uniform(0.0, 3.0, n)])
    p1 = p0 + rng.normal(0.0, 1.5, (n, 3))
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    yaw1 = yaw0 + rng.normal(0.0, 0.2, n)
    size = np.column_stack([rng.uniform(0.3, 5.0, n), rng.uniform(0.3, 2.0, n), rng.uniform(0.2, 2.0, n)])
    ids = np.array([f"v{k}" for k in range(n)], dtype=object)
    return Poses(0.0, ids, p0, yaw0, size), Poses(0.1, ids, p1, yaw1, size)


@pytest.mark.parametrize(("n", "k", "tree"), [(450, 450, True), (300, 120, True), (1000, 3, False), (30, 30, False)])
def test_path_follows_cost(monkeypatch: pytest.MonkeyPatch, n: int, k: int, tree: bool) -> None:
    """A sharded city rank checks all of its few hundred rows (k = n = 450: 50 ms of CPU per tick on
    the dense (k, n) matrices, 0.4 ms with the k-d trees, measured): the trees, with the dense
    path's pairs and contact fractions bit for bit; a few controlled vehicles among many, or a small
    scene, stay on the dense matrices."""
    from corridor.analysis import ccd
    from corridor.analysis.ccd import swept_overlaps

    prev, cur = _moving_boxes(n, seed=n + k, side_m=9.0 * np.sqrt(n))
    special = np.sort(np.random.default_rng(k).choice(n, k, replace=False))
    calls: list[str] = []
    for mod, name in ((safety, "_near_pairs_tree"), (ccd, "_sphere_pairs_tree")):
        real = getattr(mod, name)
        monkeypatch.setattr(mod, name, lambda *a, _real=real, _name=name: calls.append(_name) or _real(*a))
    p = cur.position
    inv = safety.obb_overlap_pairs(p[:, :2], cur.heading, cur.size[:, 0], cur.size[:, 1], p[:, 2], cur.size[:, 2],
                                   involving=special)
    swept = swept_overlaps(prev, cur, special)
    assert calls == (["_near_pairs_tree", "_sphere_pairs_tree"] if tree else [])
    monkeypatch.setattr(safety, "DENSE_FIXED_CELLS", 10 * n * n)  # the dense paths
    inv_dense = safety.obb_overlap_pairs(p[:, :2], cur.heading, cur.size[:, 0], cur.size[:, 1], p[:, 2],
                                         cur.size[:, 2], involving=special)
    swept_dense = swept_overlaps(prev, cur, special)
    if tree:
        assert len(inv_dense) > 0 and len(swept_dense[0]) > 0
    np.testing.assert_array_equal(inv, inv_dense)
    for a, b in zip(swept, swept_dense, strict=True):
        np.testing.assert_array_equal(a, b)


def test_involving_and_swept_tree_paths_equal_dense(monkeypatch: pytest.MonkeyPatch) -> None:
    from corridor.analysis.ccd import Poses, swept_overlaps

    rng = np.random.default_rng(5)
    n = 1500
    p0 = np.column_stack([rng.uniform(0.0, 200.0, (n, 2)), rng.uniform(0.0, 3.0, n)])
    p1 = p0 + rng.normal(0.0, 1.5, (n, 3))
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    yaw1 = yaw0 + rng.normal(0.0, 0.2, n)
    size = np.column_stack([rng.uniform(0.3, 5.0, n), rng.uniform(0.3, 2.0, n), rng.uniform(0.2, 2.0, n)])
    ids = np.array([f"v{k}" for k in range(n)], dtype=object)
    prev, cur = Poses(0.0, ids, p0, yaw0, size), Poses(0.1, ids, p1, yaw1, size)
    special = np.sort(rng.choice(n, 400, replace=False))
    inv = safety.obb_overlap_pairs(p1[:, :2], yaw1, size[:, 0], size[:, 1], p1[:, 2], size[:, 2], involving=special)
    swept = swept_overlaps(prev, cur, special)
    monkeypatch.setattr(safety, "DENSE_FIXED_CELLS", 10 * n * n)  # the dense paths (ccd asks safety)
    inv_dense = safety.obb_overlap_pairs(p1[:, :2], yaw1, size[:, 0], size[:, 1], p1[:, 2], size[:, 2],
                                         involving=special)
    swept_dense = swept_overlaps(prev, cur, special)
    assert len(inv_dense) > 5 and len(swept_dense[0]) > 5
    np.testing.assert_array_equal(inv, inv_dense)
    for a, b in zip(swept, swept_dense, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
