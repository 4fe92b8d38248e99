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
    monkeypatch.setattr(safety, "_DENSE_MAX", 10 * n)
    dense = safety.obb_overlap_pairs(xy, yaw, length, width, z, h)
    assert len(dense) > 20
    np.testing.assert_array_equal(tree, dense)
