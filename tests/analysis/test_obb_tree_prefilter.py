"""The k-d tree pre-filter of ``obb_overlap_pairs`` (many rows) gives the dense path's pairs, in order."""

from __future__ import annotations

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
    monkeypatch.setattr(safety, "_DENSE_MAX", 10 * n * n)
    dense = safety.obb_overlap_pairs(xy, yaw, length, width, z, h)
    assert len(dense) > 20
    np.testing.assert_array_equal(tree, dense)


def test_involving_and_swept_tree_paths_equal_dense(monkeypatch: pytest.MonkeyPatch) -> None:
    from corridor.analysis import ccd
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
    monkeypatch.setattr(safety, "_DENSE_MAX", 10 * n * n)
    monkeypatch.setattr(ccd, "SPARSE_ABOVE", 10 * n * n)
    inv_dense = safety.obb_overlap_pairs(p1[:, :2], yaw1, size[:, 0], size[:, 1], p1[:, 2], size[:, 2],
                                         involving=special)
    swept_dense = swept_overlaps(prev, cur, special)
    assert len(inv_dense) > 5 and len(swept_dense[0]) > 5
    np.testing.assert_array_equal(inv, inv_dense)
    for a, b in zip(swept, swept_dense, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
