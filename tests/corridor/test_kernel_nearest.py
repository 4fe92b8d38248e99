"""`corridor.snapshot.nearest_indices`: the nearest rows the Gymnasium observations are built from."""

from __future__ import annotations

import numpy as np

from corridor.snapshot import nearest_indices


def test_nearest_first_self_excluded_ties_in_row_order() -> None:
    pos = np.array([[0.0, 0.0], [3.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, 3.0]])
    # rows 2 and 3 are both 1 m from row 0: row order breaks the tie; row 0 itself never appears
    assert nearest_indices(pos, 0, 3).tolist() == [2, 3, 1]
    assert nearest_indices(pos, 1, 10).tolist() == [0, 3, 2, 4]


def test_non_finite_rows_left_out() -> None:
    pos = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [np.inf, 0.0, 0.0], [5.0, 0.0, 0.0]])
    assert nearest_indices(pos, 0, 4).tolist() == [3]
    assert nearest_indices(pos[:1], 0, 2).tolist() == []
