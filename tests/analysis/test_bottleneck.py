"""Breakdown and capacity drop from loop series (``corridor.analysis.bottleneck``): closed-form cases."""

from __future__ import annotations

import math

import numpy as np

from corridor.analysis.bottleneck import analyse, breakdown_time, moving_mean


def _series(n: int = 40, t_break: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = 60.0 * np.arange(1, n + 1)  # [s] interval ends
    speed = np.where(t < 60.0 * t_break, 30.0, 12.0)  # [m/s] 60 % below 30 m/s from interval 20 on
    flow = np.where(t < 60.0 * t_break, 2000.0, 1800.0)  # [veh/h] 10 % lower after the breakdown
    return t, speed, flow


def test_a_sustained_drop_is_a_breakdown_with_its_capacity_drop() -> None:
    t, speed, flow = _series()
    flow[5:10] = 2100.0  # the pre-breakdown maximum: a 5-interval (300 s) plateau
    b = analyse(t, speed, flow, 60.0, 30.0)
    assert b.breakdown_s == 1200.0
    assert b.prebreakdown_flow_vph == 2100.0
    assert b.discharge_flow_vph == 1800.0
    assert math.isclose(b.capacity_drop, 1 - 1800 / 2100)


def test_a_short_dip_is_not_a_breakdown() -> None:
    t, speed, flow = _series()
    speed[:] = 30.0
    speed[10:13] = 10.0  # 3 min below: shorter than the 5 min the definition asks
    b = analyse(t, speed, flow, 60.0, 30.0)
    assert not b.occurred and math.isnan(b.capacity_drop)


def test_a_drop_of_less_than_25_percent_is_not_a_breakdown() -> None:
    t, speed, flow = _series()
    speed[19:] = 23.0  # 23.3 % below 30 m/s (from t = 1200 s)
    assert math.isnan(breakdown_time(t, speed, 30.0, 0.25, 300.0))
    speed[19:] = 22.4  # 25.3 % below
    assert breakdown_time(t, speed, 30.0, 0.25, 300.0) == 1200.0


def test_an_interval_nobody_crossed_counts_as_standing_queue() -> None:
    t, speed, flow = _series()
    speed[25:27] = np.nan
    assert breakdown_time(t, speed, 30.0, 0.25, 300.0) == 1200.0


def test_moving_mean() -> None:
    assert np.allclose(moving_mean(np.array([1.0, 2.0, 3.0, 4.0]), 2), [1.5, 2.5, 3.5])
    assert len(moving_mean(np.array([1.0]), 2)) == 0
