"""Fundamental-diagram calibration: the fit finds the density of maximum flow even when the loops'
time-mean speeds overstate the congested speeds (as SUMO's loops do in stop-and-go traffic)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.traffic.macro.calibrate import detector_points, fit_fundamental_diagram


def _metanet_speed(rho: np.ndarray, vf: float = 100.0, rc: float = 40.0, a: float = 1.8) -> np.ndarray:
    return vf * np.exp(-(1.0 / a) * (rho / rc) ** a)


def test_fit_recovers_exact_diagram() -> None:
    rho = np.linspace(2.0, 90.0, 60)
    v = _metanet_speed(rho)
    fit = fit_fundamental_diagram(rho, v, q_vph=rho * v)
    assert fit.rho_crit == pytest.approx(40.0, rel=1e-3)
    assert fit.v_free_kmh == pytest.approx(100.0, rel=1e-3)
    assert fit.capacity_vph_per_lane == pytest.approx(100.0 * 40.0 * math.exp(-1 / 1.8), rel=1e-3)


def test_flow_residuals_pin_rho_crit_when_loop_speeds_are_biased() -> None:
    rho = np.linspace(2.0, 90.0, 90)
    v_true = _metanet_speed(rho)
    q = rho * v_true  # counts: the true flow
    # time-mean speeds above the space-mean speed in congestion, up to +80 % in the jam
    v_loop = v_true * (1.0 + 0.8 * np.clip((rho - 40.0) / 50.0, 0.0, 1.0))
    speed_only = fit_fundamental_diagram(rho, v_loop)
    with_flow = fit_fundamental_diagram(rho, v_loop, q_vph=q)
    assert speed_only.rho_crit > 45.0  # dragged into the congested branch
    assert with_flow.rho_crit == pytest.approx(40.0, abs=3.0)
    rho_qmax = rho[np.argmax(q)]
    assert abs(with_flow.rho_crit - rho_qmax) < abs(speed_only.rho_crit - rho_qmax)


def test_detector_points_by_side() -> None:
    hist = [(60.0, "ccw0", "down", 20.0, 3600.0, 20.0), (60.0, "ccw0", "up", 10.0, 1800.0, 25.0),
            (60.0, "ccw1", "up", 0.0, 0.0, -1.0)]  # nobody passed: dropped
    pts = detector_points(hist, lanes=2, vehicle_length_m=5.0, side="down")
    assert pts["rho"].tolist() == [40.0] and pts["q"].tolist() == [1800.0] and pts["v_kmh"].tolist() == [72.0]
    assert len(detector_points(hist, 2, 5.0)["rho"]) == 2
