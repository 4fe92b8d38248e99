"""Kalman track table: convergence and consistency, extrapolation, out-of-order and stale handling."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.tracks.table import TrackTable, process_cov, transition


def _track_cv(table: TrackTable, rng: np.random.Generator, n: int, sigma_m: float) -> tuple[np.ndarray, ...]:
    """Feed noisy positions of a 2-D constant-velocity target; return errors and 3-sigma hits."""
    p0, v = np.array([0.0, 5.0]), np.array([20.0, -1.0])
    err, inside = [], []
    for k in range(n):
        t = 0.1 * k
        truth = p0 + v * t
        table.update("x", t, truth + rng.normal(0.0, sigma_m, 2))
        tr = table.predict_all(t)["x"]
        e = tr.pos - truth
        err.append(np.linalg.norm(e))
        inside.append(np.all(np.abs(e) <= 3 * np.sqrt(np.diag(tr.pos_cov))))
    return np.array(err), np.array(inside), tr.vel


def test_constant_velocity_target_converges_and_is_consistent() -> None:
    sigma = 2.0
    table = TrackTable(dim=2, process_noise=0.01, meas_noise=sigma, stale_after_s=1.0)
    err, inside, vel = _track_cv(table, np.random.default_rng(4), 300, sigma)
    assert err[-100:].mean() < 0.5 * sigma * np.sqrt(2)  # filtered error well below raw noise
    assert err[-100:].mean() < err[:5].mean()
    assert inside[20:].mean() > 0.95  # 3-sigma bounds hold (nominally 99.5 % for 2 axes)
    assert vel == pytest.approx([20.0, -1.0], abs=0.5)


def test_prediction_extrapolates_without_mutating() -> None:
    table = TrackTable(dim=1, process_noise=0.1, meas_noise=0.5, stale_after_s=5.0, model="ca")
    rng = np.random.default_rng(0)
    for k in range(100):  # x = 2 t + 0.25 t^2 (a = 0.5 m/s²)
        t = 0.1 * k
        table.update("car", t, [2 * t + 0.25 * t**2 + rng.normal(0, 0.5)])
    t_last = 9.9
    a = table.predict("car", t_last + 2.0)
    b = table.predict_all(t_last + 2.0)["car"]
    assert a.pos == pytest.approx(b.pos) and a.age_s == pytest.approx(2.0)
    truth = 2 * (t_last + 2) + 0.25 * (t_last + 2) ** 2
    assert abs(a.pos[0] - truth) < 3 * np.sqrt(a.pos_cov[0, 0])
    assert a.acc is not None and a.acc[0] == pytest.approx(0.5, abs=0.3)
    # uncertainty grows with the horizon; the filter itself did not move
    assert a.pos_cov[0, 0] > table.predict("car", t_last).pos_cov[0, 0]
    assert table.last_update_s("car") == pytest.approx(t_last)


def test_out_of_order_measurement_is_ignored_and_velocity_measurements_fused() -> None:
    table = TrackTable(dim=3, process_noise=0.5, meas_noise=1.0, stale_after_s=2.0, vel_noise=0.2)
    assert table.update("uav", 1.0, [0, 0, 100], vel=[10, 0, 0])
    assert table.update("uav", 2.0, [10, 0, 100], vel=[10, 0, 0])
    before = table.predict("uav", 2.0)
    assert not table.update("uav", 1.5, [500, 500, 500])
    after = table.predict("uav", 2.0)
    assert after.pos == pytest.approx(before.pos) and after.vel == pytest.approx([10, 0, 0], abs=0.3)
    assert table.predict("uav", 3.0).pos == pytest.approx([20, 0, 100], abs=1.0)


def test_stale_tracks_are_dropped() -> None:
    table = TrackTable(dim=1, process_noise=0.1, meas_noise=1.0, stale_after_s=1.0)
    table.update("a", 0.0, [0.0])
    table.update("b", 0.8, [5.0])
    assert table.drop_stale(1.5) == ["a"]
    assert "a" not in table and "b" in table and len(table) == 1
    assert table.drop_stale(1.8) == []
    assert table.drop_stale(1.81) == ["b"]


def test_discretisation_matches_closed_forms_and_composes() -> None:
    dt, q = 0.3, 2.0
    assert process_cov(dt, 2, 1, q) == pytest.approx(q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))
    assert transition(dt, 3, 1) == pytest.approx(np.array([[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]]))
    # Q(2dt) = F(dt) Q(dt) F(dt)^T + Q(dt): splitting an interval does not change the prediction
    for order in (2, 3):
        f, qd = transition(dt, order, 2), process_cov(dt, order, 2, q)
        assert process_cov(2 * dt, order, 2, q) == pytest.approx(f @ qd @ f.T + qd)


def test_batched_prediction_equals_per_track_prediction() -> None:
    """predict_arrays / predict_all (one stacked matmul for every track) give exactly what predict
    gives track by track, for tracks of different ages, and leave the filters untouched."""
    table = TrackTable(dim=3, process_noise=2.0, meas_noise=0.5, stale_after_s=3.0, vel_noise=0.3)
    rng = np.random.default_rng(7)
    for k in range(30):
        for i, tid in enumerate(("a", "b", "c", "d")):
            if (k + i) % 3:  # irregular, different update times per track
                table.update(tid, 0.1 * k + 0.01 * i, rng.normal(0.0, 50.0, 3), rng.normal(0.0, 5.0, 3))
    before = {tid: table._tracks[tid].kf.x.copy() for tid in table.ids}
    t = 3.25
    ids, x, cov, age = table.predict_arrays(t)
    batch = table.predict_all(t)
    assert ids == table.ids == list(batch)
    for i, tid in enumerate(ids):
        one = table.predict(tid, t)
        assert np.array_equal(np.concatenate([one.pos, one.vel]), x[i])
        assert np.array_equal(one.cov, cov[i]) and one.age_s == age[i] == batch[tid].age_s
        assert np.array_equal(batch[tid].pos, one.pos) and np.array_equal(batch[tid].cov, one.cov)
        assert np.array_equal(table._tracks[tid].kf.x, before[tid])
    assert TrackTable(dim=1, process_noise=1.0, meas_noise=1.0, stale_after_s=1.0).predict_arrays(0.0)[0] == []


def test_filters_invert_the_innovation_covariance_like_numpy() -> None:
    """The filters' ``inv`` (LAPACK gesv, filterpy's hook) is numpy.linalg.inv's computation: same
    inverse, and a singular matrix raises as numpy does."""
    from corridor.vehicles.tracks.table import _inverse

    rng = np.random.default_rng(0)
    for _ in range(50):
        a = rng.normal(size=(6, 6))
        s = a @ a.T + 0.1 * np.eye(6)
        np.testing.assert_allclose(_inverse(s), np.linalg.inv(s), rtol=1e-12, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        _inverse(np.zeros((6, 6)))
    table = TrackTable(dim=3, process_noise=1.0, meas_noise=0.5, stale_after_s=5.0, vel_noise=0.3)
    table.update("x", 0.0, np.zeros(3), np.ones(3))
    assert table._tracks["x"].kf.inv is _inverse
