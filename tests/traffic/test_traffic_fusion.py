"""Segment fusion (loops + UAV camera estimates) and loop faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.traffic.macro.fusion import FusionParams, SegmentFilter
from corridor.traffic.sensing.loop_faults import LoopFaults, Reading, apply_fault, draw_faults


def test_one_update_is_the_scalar_kalman_formula():
    kf = SegmentFilter(1, FusionParams(rho_init=10.0, rho_init_sigma=5.0, loop_sigma=5.0))
    kf.update_loop("a", 0, 30.0, math.nan)
    # prior 10 +- 5, measurement 30 +- 5: the mean is halfway, the variance halves
    assert kf.rho[0] == pytest.approx(20.0)
    assert kf.P_rho[0] == pytest.approx(12.5)


def test_age_of_information_inflates_a_camera_estimate():
    fresh, old = SegmentFilter(1), SegmentFilter(1)
    for kf in (fresh, old):
        kf.update_loop("a", 0, 20.0, math.nan)
        kf.predict(100.0)
    fresh.update_uav(0, 100.0, 40.0, 4.0, math.nan, math.nan)
    old.update_uav(0, 40.0, 40.0, 4.0, math.nan, math.nan)  # taken 60 s ago
    assert 20.0 < old.rho[0] < fresh.rho[0] < 40.0


def test_a_failed_loop_is_down_weighted():
    """Two stations on one segment; one sticks at zero.  With camera estimates of the true density the
    stuck station's weight falls and the fused density follows the truth, not the average."""
    rng = np.random.default_rng(0)
    kf = SegmentFilter(1, FusionParams(loop_sigma=4.0))  # the healthy station's noise here is 3
    truth = 30.0
    for t in range(60, 1260, 60):
        kf.predict(float(t))
        kf.update_loops([("healthy", 0, truth + rng.normal(0, 3), 60.0), ("stuck", 0, 0.0, math.nan)])
        for dt in range(5, 60, 10):  # a camera pass every 10 s
            kf.predict(float(t + dt))
            kf.update_uav(0, float(t + dt) - 2.0, truth + rng.normal(0, 3), 9.0, 60.0, 25.0)
    assert kf.station_weight("stuck") < 0.05
    assert kf.station_weight("healthy") > 0.5
    assert kf.rho[0] == pytest.approx(truth, abs=3.0)


def _camera_mean(truth: float, with_area: bool, area_km_lane: float = 0.286) -> float:
    """Time-mean fused density from camera counts alone: a Poisson count of the stretch every 2 s, with
    the camera's variance (N + 1) / A^2 evaluated at its own count N, as ``corridor.vehicles.sensors.camera``."""
    rng = np.random.default_rng(0)
    kf, out = SegmentFilter(1), []
    for k in range(3000):
        kf.predict(2.0 * k)
        n = rng.poisson(truth * area_km_lane)
        kf.update_uav(0, 2.0 * k, n / area_km_lane, (n + 1) / area_km_lane**2, math.nan, math.nan,
                      area_km_lane if with_area else None)
        if k >= 100:
            out.append(kf.rho[0])
    return float(np.mean(out))


@pytest.mark.parametrize("truth", [10.0, 30.0, 80.0])
def test_camera_counts_fuse_without_bias(truth):
    """Variances taken at the observed count make low counts look precise: the fused mean drifts low
    (-2.5 to -3.6 veh/km/lane here).  Re-evaluated at the filter's prior (the observed area given), the
    mean is the truth."""
    assert _camera_mean(truth, with_area=False) < truth - 2.0
    assert _camera_mean(truth, with_area=True) == pytest.approx(truth, abs=0.6)


def test_without_cameras_a_stuck_loop_drags_the_estimate():
    """The counterpart: two stations alone can only out-vote each other (why the cameras matter)."""
    kf = SegmentFilter(1)
    for t in range(60, 1260, 60):
        kf.predict(float(t))
        kf.update_loops([("healthy", 0, 30.0, math.nan), ("stuck", 0, 0.0, math.nan)])
    assert kf.rho[0] < 20.0  # truth 30: dragged towards the stuck station's zero


def test_fault_draws_share_and_modes():
    stations = [f"s{i}" for i in range(32)]
    faults = draw_faults(LoopFaults(share=0.3), stations, np.random.default_rng(1))
    assert len(faults) == round(0.3 * 32)
    assert all(30.0 <= f.t_fail_s <= 300.0 for f in faults.values())
    assert draw_faults(LoopFaults(share=0.0), stations, np.random.default_rng(1)) == {}
    # the same stream gives the same faults (common random numbers across variants)
    assert faults == draw_faults(LoopFaults(share=0.3), stations, np.random.default_rng(1))


def test_fault_modes():
    from corridor.traffic.sensing.loop_faults import StationFault

    true, held = Reading(20.0, 1500.0, 25.0), Reading(5.0, 600.0, 30.0)
    assert apply_fault(StationFault("stuck_zero", 100.0), 50.0, true, held, 0.4) == true  # before the failure
    z = apply_fault(StationFault("stuck_zero", 100.0), 150.0, true, held, 0.4)
    assert (z.occupancy_pct, z.flow_vph, math.isnan(z.speed_mps)) == (0.0, 0.0, True)
    b = apply_fault(StationFault("bias", 100.0), 150.0, true, held, 0.4)
    assert (b.occupancy_pct, b.flow_vph, b.speed_mps) == pytest.approx((8.0, 600.0, 25.0))
    d = apply_fault(StationFault("dropout", 100.0), 150.0, true, held, 0.4)
    assert (d.occupancy_pct, d.flow_vph, d.ok) == (5.0, 600.0, False)


def test_fault_window_is_checked():
    with pytest.raises(ValueError, match="start_s"):
        LoopFaults(start_s=(600.0, 60.0))


def _ring(flow_vph: float, occ_pct: float) -> list:
    from corridor.traffic.sensing.detectors import RampMeasurement

    return [RampMeasurement(key=f"{d}{k}", direction=d, interchange=k, tls="", storage_veh=40.0,
                            occupancy_down_pct=occ_pct, flow_down_vph=flow_vph, occupancy_up_pct=occ_pct,
                            flow_up_vph=flow_vph) for k in range(8) for d in ("ccw", "cw")]


def test_zero_test_rejects_a_stuck_station_only_when_its_carriageway_is_busy():
    from corridor.traffic.macro.fusion_component import SegmentFusion

    fusion = SegmentFusion("fusion", SegmentFusion.Params(), None)
    ring = _ring(1800.0, 12.0)
    ring[3].flow_down_vph, ring[3].occupancy_down_pct = 0.0, 0.0  # cw1/down stuck at zero
    ring[5].flow_up_vph, ring[5].occupancy_up_pct = 0.0, 95.0  # cw2/up: a vehicle standing on the loop
    kept = {(k, side) for k, side, _ in fusion._plausible(ring)}
    assert ("cw1", "down") not in kept and len(kept) == 31 and ("cw2", "up") in kept
    assert fusion.zero_stations == {"cw1/down"} and fusion.zero_rejected == 1
    quiet = _ring(0.0, 0.0)  # nobody anywhere (a quiet interval): zeros are plausible
    assert len(fusion._plausible(quiet)) == 32
    off = SegmentFusion("fusion", SegmentFusion.Params(zero_check_vph=None), None)
    assert len(off._plausible(ring)) == 32
