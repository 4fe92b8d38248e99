"""The UAV camera: footprint geometry, and estimates that converge to the ground truth as the
detection probability goes to 1 and the noise to 0."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.traffic.networks.beltway import DIRECTIONS, BeltwayParams, carriageway_arcs
from corridor.traffic.networks.segments import RingSegments
from corridor.vehicles.sensors.camera import CameraParams, in_footprint, observe, optical_axis

P = BeltwayParams(circumference_m=10000, interchanges=8, lanes=2, ramp_length_m=1200, ramp_span_m=300,
                  accel_lane_length_m=100)


def ring() -> RingSegments:
    """The segments of the ramp-metering beltway, built from its geometry (no network needed)."""
    radius, sign, merge, span = [], [], [], []
    for d in DIRECTIONS:
        r, sg, a = carriageway_arcs(P, d)
        a = np.asarray(a)
        nxt = np.roll(a, -1) if sg > 0 else np.roll(a, 1)
        radius.append(r), sign.append(sg), merge.append(a), span.append(np.mod(sg * (nxt - a), 2 * np.pi))
    return RingSegments(8, 1, 2, tuple(radius), tuple(sign), np.array(merge), np.array(span),
                        (frozenset(), frozenset()))


def traffic(seg: RingSegments, rng: np.random.Generator, n: int = 1500):
    dirn = rng.integers(0, 2, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    r = np.asarray(seg.radius_m)[dirn]
    xy = np.column_stack([r * np.cos(theta), r * np.sin(theta)])
    return xy, dirn, rng.uniform(5.0, 30.0, n)


def test_nadir_axis_and_footprint_radius():
    assert np.allclose(optical_axis(0.0, 0.0, 1.0), [0, 0, -1])
    cam = np.array([0.0, 0.0, 100.0])
    ground = np.array([[99.0, 0.0], [101.0, 0.0], [0.0, -99.0]])
    inside, rng, cos_off = in_footprint(cam, optical_axis(0, 0, 0), ground, fov_deg=90.0)  # radius = h tan 45
    assert inside.tolist() == [True, False, True]
    assert rng[0] == pytest.approx(np.hypot(99.0, 100.0))
    # pitching nose down (negative pitch) by 10 deg moves the footprint backwards (-x for yaw 0)
    axis = optical_axis(0.0, np.radians(-10.0), 0.0)
    assert axis[0] < 0 and axis[2] < 0
    assert np.degrees(np.arccos(-axis[2])) == pytest.approx(10.0)


def _errors(p_max: float, pos_sigma: float, speed_sigma: float, seeds: int = 20) -> tuple[float, float]:
    """Mean absolute density error [veh/km/lane] and speed error [m/s] of a camera seeing the whole ring."""
    seg = ring()
    arc_xy, arc_seg, spacing = seg.arc_points(2.0)
    cam = CameraParams(fov_deg=160.0, p_max=p_max, off_nadir_exp=0.0, half_range_m=None, pos_sigma_m=pos_sigma,
                       speed_sigma_mps=speed_sigma, min_observed_m=0.0)
    e_rho, e_v = [], []
    for s in range(seeds):
        rng = np.random.default_rng(s)
        xy, dirn, speed = traffic(seg, rng)
        true_seg = seg.segment_of(xy, dirn)
        count = np.bincount(true_seg, minlength=seg.n_seg)
        truth = count / (seg.length_km() * seg.lanes)
        v_truth = np.bincount(true_seg, weights=speed, minlength=seg.n_seg) / count
        frame = observe(cam, np.array([0.0, 0.0, 2000.0]), optical_axis(0, 0, 0), arc_xy, arc_seg, spacing, xy, dirn,
                        speed, seg.segment_of, seg.n_seg, seg.n * seg.m, seg.lanes, rng)
        assert len(frame.estimates) == seg.n_seg  # the whole ring is in view
        for e in frame.estimates:
            e_rho.append(abs(e.density - truth[e.segment]))
            e_v.append(abs(e.speed_mps - v_truth[e.segment]))
    return float(np.mean(e_rho)), float(np.mean(e_v))


def test_estimates_converge_to_truth_as_detection_becomes_perfect():
    errs = [_errors(p, sp, sv) for p, sp, sv in [(0.5, 20.0, 4.0), (0.8, 5.0, 1.0), (0.95, 1.0, 0.2), (1.0, 0.0, 0.0)]]
    rho_err = [e[0] for e in errs]
    v_err = [e[1] for e in errs]
    assert rho_err == sorted(rho_err, reverse=True), rho_err
    assert v_err == sorted(v_err, reverse=True), v_err
    # perfect camera: exact up to the arc discretisation (2 m points on ~1.25 km segments)
    assert rho_err[-1] < 0.01 * 18.0  # mean density is ~18 veh/km/lane here
    assert v_err[-1] < 1e-9


def test_density_variance_is_honest():
    """The reported variance matches the spread of the estimate over repeated frames of one scene."""
    seg = ring()
    arc_xy, arc_seg, spacing = seg.arc_points(5.0)
    xy, dirn, speed = traffic(seg, np.random.default_rng(0))
    cam = CameraParams(fov_deg=160.0, p_max=0.6, off_nadir_exp=0.0, half_range_m=None, pos_sigma_m=0.0,
                       speed_sigma_mps=0.0, min_observed_m=0.0)
    rng = np.random.default_rng(1)
    frames = [observe(cam, np.array([0.0, 0.0, 2000.0]), optical_axis(0, 0, 0), arc_xy, arc_seg, spacing, xy, dirn,
                      speed, seg.segment_of, seg.n_seg, seg.n * seg.m, seg.lanes, rng) for _ in range(400)]
    est = np.array([[e.density for e in f.estimates] for f in frames])
    miss_var = np.array([[e.density_var for e in f.estimates] for f in frames]).mean(axis=0)
    # the detection part of the variance alone is (1 - p) / p^2 per vehicle; the reported one adds the
    # Poisson term of the stretch (not random here: one fixed scene), so it bounds the spread from above
    assert np.all(est.var(axis=0) <= miss_var)
    n = est.mean(axis=0) * seg.length_km() * seg.lanes * 0.6  # detected vehicles
    expected = n / 0.6 * (1 - 0.6) / 0.6 / (seg.length_km() * seg.lanes) ** 2
    assert np.allclose(est.var(axis=0), expected, rtol=0.25)
