"""Lane leaders: consecutive vehicles on a lane, per tick or over the rows of many ticks at once."""

from __future__ import annotations

import numpy as np

from corridor.analysis.safety import lane_leaders


def test_leaders_of_one_lane_closed_form() -> None:
    code = np.array([1, 0, 1, 1, 0])
    pos = np.array([50.0, 10.0, 20.0, 80.0, 5.0])
    f, lead = lane_leaders(code, pos)
    assert list(zip(f.tolist(), lead.tolist(), strict=True)) == [(4, 1), (2, 0), (0, 3)]


def test_grouped_leaders_equal_lexsorts_including_tied_positions_and_wide_keys() -> None:
    rng = np.random.default_rng(7)
    for trial in range(60):
        ticks, per_tick = int(rng.integers(1, 120)), int(rng.integers(1, 80))
        group = np.repeat(np.arange(ticks), per_tick)
        code = rng.integers(0, int(rng.integers(1, 9)), len(group)) * (3000 if trial % 5 == 0 else 1)
        pos = rng.random(len(group)) * 2500.0
        if trial % 3 == 0:
            pos = np.round(pos / 400.0) * 400.0  # equal positions on a lane: row order decides
        order = np.lexsort((pos, code, group))
        same = (code[order[:-1]] == code[order[1:]]) & (group[order[:-1]] == group[order[1:]])
        f, lead = lane_leaders(code, pos, group=group)
        assert np.array_equal(f, order[:-1][same]) and np.array_equal(lead, order[1:][same])
        k = int(rng.integers(ticks))  # and each group's pairs are that tick's own pairs
        rows = np.flatnonzero(group == k)
        fk, lk = lane_leaders(code[rows], pos[rows])
        mine = group[f] == k
        assert np.array_equal(f[mine], rows[fk]) and np.array_equal(lead[mine], rows[lk])
