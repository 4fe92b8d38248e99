"""TrackStack (all pairs' constant-velocity Kalman filters updated in one stacked pass) against the
reference, filterpy through ``TrackTable``: same states, covariances and rejections."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.tracks.stack import TrackStack, cv_matrices
from corridor.vehicles.tracks.table import TrackTable, model_matrices

Q, R_POS, R_VEL = 2.0, 0.5, 0.3


def test_cv_matrices_match_the_generic_model_matrices() -> None:
    dts = np.array([0.0, 0.1, 0.2999999999, 1.7])
    f, q = cv_matrices(dts, 3, Q)
    for k, dt in enumerate(dts):
        f_ref, q_ref = model_matrices(float(dt), 2, 3, Q)
        assert np.array_equal(f[k], f_ref)
        assert q[k] == pytest.approx(q_ref, rel=1e-12, abs=1e-15)


def test_stacked_updates_match_filterpy_track_by_track() -> None:
    """3 receivers x 4 sources, irregular, out-of-order and repeated-time reports, fused in random
    subsets per call: every pair's state and covariance equal filterpy's (within 1e-9)."""
    rng = np.random.default_rng(11)
    n_rx, n_src = 3, 4
    stack = TrackStack(n_rx, n_src, 3, Q, R_POS, R_VEL)
    ref = [TrackTable(3, Q, R_POS, stale_after_s=1e9, vel_noise=R_VEL) for _ in range(n_rx)]
    t_last = np.zeros((n_rx, n_src))
    calls = 0
    for step in range(120):
        pick = rng.random((n_rx, n_src)) < 0.6
        rows, cols = np.nonzero(pick)
        jitter = rng.choice([-0.15, 0.0, 0.1, 0.1, 0.2], size=rows.size)  # some older than the track
        t = np.maximum(0.0, 0.1 * step + jitter)
        z = np.column_stack([rng.normal(0.0, 20.0, (rows.size, 3)), rng.normal(0.0, 3.0, (rows.size, 3))])
        used = stack.fuse(rows, cols, t, z, np.full(rows.size, calls))
        calls += 1
        for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True)):
            assert used[i] == ref[r].update(str(c), t[i], z[i, :3], z[i, 3:])
            if used[i]:
                t_last[r, c] = t[i]
    worst_x = worst_p = 0.0
    for r in range(n_rx):
        for c in range(n_src):
            if not stack.alive[r, c]:
                assert str(c) not in ref[r]
                continue
            kf = ref[r]._tracks[str(c)].kf
            worst_x = max(worst_x, float(np.abs(stack.x[r, c] - kf.x).max()))
            worst_p = max(worst_p, float(np.abs(stack.P[r, c] - kf.P).max()))
            assert stack.t_s[r, c] == t_last[r, c] == ref[r].last_update_s(str(c))
    assert worst_x < 1e-9 and worst_p < 1e-9
    # prediction to a common time, as TrackTable.predict_arrays
    rows, cols = np.nonzero(stack.alive)
    x, p = stack.predict(rows, cols, 13.0)
    for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True)):
        tr = ref[r].predict(str(c), 13.0)
        assert x[i] == pytest.approx(np.r_[tr.pos, tr.vel], abs=1e-9)
        assert p[i] == pytest.approx(tr.cov, abs=1e-9)


def test_stale_tracks_are_dropped_per_receiver_row() -> None:
    stack = TrackStack(2, 2, 3, Q, R_POS, R_VEL)
    z = np.zeros((4, 6))
    stack.fuse(np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), np.array([0.0, 2.0, 0.0, 0.0]), z, np.zeros(4, int))
    stack.drop_stale(np.array([0]), 4.0, 3.0)
    assert stack.alive.tolist() == [[False, True], [True, True]]  # row 1 not asked: kept
