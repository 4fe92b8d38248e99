"""Spot detection from side-looking range sensors: exact slots without noise, the same slots with
range noise, dropouts and ghost echoes; precision/recall scoring."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.parking.clearance import box_polygons
from corridor.controllers.parking.spot_detection import (
    DetectorParams,
    Slot,
    SlotDetector,
    match_slots,
    true_slots,
)
from corridor.vehicles.sensors.range_sensors import RangeSensorParams, scan

# a kerb row on the right of a street along +x: parked cars 4.5 m x 1.8 m, centred 2.6 m right of the
# driving line; gaps: 3 m (too short), 7.0 m (a parallel slot), 2 m, 8.5 m (a slot), the rest closed
CAR_X = np.array([5.0, 12.5, 24.0, 30.5, 43.5, 48.5, 53.5])
ROW_Y = -2.6


def cars() -> np.ndarray:
    n = len(CAR_X)
    return box_polygons(np.column_stack([CAR_X, np.full(n, ROW_Y)]), np.zeros(n), np.full(n, 4.5), np.full(n, 1.8))


def drive(sp: RangeSensorParams, rng: np.random.Generator | None, step_m: float = 0.1) -> SlotDetector:
    # the kerb line 1.5 m right of the driving line; the cars' near sides are 0.2 m beyond it
    det = SlotDetector(np.array([0.0, -1.5]), np.array([1.0, 0.0]), -1, 60.0,
                       DetectorParams(probe_m=2.0, parallel_length_m=6.0))
    polys = cars()
    for x in np.arange(-5.0, 60.0, step_m):  # rear axle from -5 m: the sensors cover 0 .. 60 m
        sc = scan(sp, np.array([x, 0.0, 0.0]), polys, rng)
        det.add(sc.origin, sc.axis, sc.range_m, sc.max_range_m)
    return det


def truth() -> list[Slot]:
    return true_slots(cars(), np.array([0.0, 0.0]), np.array([1.0, 0.0]), -1, (1.0, 4.0), (0.0, 60.0), 6.0)


def test_true_slots_are_the_long_gaps() -> None:
    gt = truth()
    assert [(round(s.s0_m, 2), round(s.s1_m, 2)) for s in gt] == [(14.75, 21.75), (32.75, 41.25)]


def test_noise_free_sensors_find_exactly_the_slots() -> None:
    sp = RangeSensorParams(half_angle_rad=0.0, rays=1, noise_m=0.0)
    found = drive(sp, None).slots("parallel")
    gt = truth()
    assert len(found) == len(gt)
    for f, g in zip(found, gt):  # to the cell size (0.2 m)
        assert abs(f.s0_m - g.s0_m) <= 0.2 + 1e-9 and abs(f.s1_m - g.s1_m) <= 0.2 + 1e-9
    assert match_slots(found, gt) == (2, 2, 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_sensors_still_find_the_slots(seed: int) -> None:
    sp = RangeSensorParams(noise_m=0.05, dropout=0.15, spurious=0.05)
    det = drive(sp, np.random.default_rng(seed))
    found = det.slots("parallel")
    tp, n_found, n_true = match_slots(found, truth(), min_iou=0.7)
    assert (tp, n_found, n_true) == (2, 2, 2), found


def test_without_filters_noise_breaks_slots() -> None:
    """The evidence filters do the work: a single-reading detector (any echo occupies the cell) with
    the same noise loses slots or invents short ones."""
    sp = RangeSensorParams(noise_m=0.05, dropout=0.15, spurious=0.05)
    naive = DetectorParams(occupied_ratio=1e-9, min_object_m=0.0, min_gap_m=0.0)
    det = drive(sp, np.random.default_rng(0))
    det.p = naive
    tp, n_found, n_true = match_slots(det.slots("parallel"), truth(), min_iou=0.7)
    assert tp < n_true or n_found > tp


def test_scan_ranges_closed_form() -> None:
    """A sensor at the car's side, 1.0 m right of the centre line, sees a car whose near side is at
    y = -1.7: range 0.7 m; nothing in front of the left sensors."""
    sp = RangeSensorParams(x_m=(0.0,), half_angle_rad=0.0, rays=1, noise_m=0.0)
    sc = scan(sp, np.array([12.5, 0.0, 0.0]), cars(), None)
    right = sc.side < 0
    assert sc.range_m[right][0] == pytest.approx(2.6 - 0.9 - 1.0)
    assert np.isnan(sc.range_m[~right]).all()


def test_true_slots_only_within_the_extent() -> None:
    gt = true_slots(cars(), np.array([0.0, 0.0]), np.array([1.0, 0.0]), -1, (1.0, 4.0), (10.0, 30.0), 6.0)
    assert [(round(s.s0_m, 2), round(s.s1_m, 2)) for s in gt] == [(14.75, 21.75)]
