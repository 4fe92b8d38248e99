"""The wave-damping controller's Python-float paths give the numpy functions' values bit for bit:
``downstream_speed_floats`` against ``wave_damping.downstream_speed`` (a mean of up to 12 cells, NaN
cells skipped, every window position)."""

from __future__ import annotations

import math

import numpy as np

from corridor.controllers.merging.wave_components import downstream_speed_floats
from corridor.controllers.merging.wave_damping import downstream_speed


def test_downstream_speed_floats_is_downstream_speed() -> None:
    rng = np.random.default_rng(3)
    n_cmp = 0
    for _ in range(3000):
        n = int(rng.integers(1, 15))
        cell_x = np.arange(n) * 50.0 + 25.0 + rng.uniform(-100, 100)
        speed = rng.uniform(0.0, 30.0, n) * 10.0 ** rng.integers(-2, 2, n)  # magnitudes apart: rounding shows
        speed[rng.random(n) < 0.2] = np.nan
        horizon = float(rng.choice([60.0, 150.0, 420.0, 800.0]))  # up to 16 cells ahead
        known = [(cx, cv) for cx, cv in zip(cell_x.tolist(), speed.tolist(), strict=True) if math.isfinite(cv)]
        for x in rng.uniform(cell_x[0] - 200.0, cell_x[-1] + 10.0, 5).tolist() + cell_x.tolist():
            ref = downstream_speed(x, cell_x, speed, horizon, 30.0)
            got = downstream_speed_floats(x, known, horizon, 30.0)
            assert got == ref, (x, horizon, cell_x, speed)
            n_cmp += 1
    assert n_cmp > 10000


def test_road_ahead_kernel_is_the_numpy_measurement() -> None:
    """The compiled RSU measurement (cells' mean speeds, ramp arrival times) against the numpy code, bit
    for bit: vehicles before, in and past the cells, ramp vehicles past the merge, speeds 0 to 35 m/s."""
    from types import SimpleNamespace

    from corridor.controllers.merging.rsu_kernel import road_ahead
    from corridor.controllers.merging.wave_components import WaveDamping

    rng = np.random.default_rng(5)
    merge_x, cell_m = 600.0, 50.0
    cells = np.arange(merge_x - 300.0, 700.0, cell_m) + 0.5 * cell_m
    rsu = SimpleNamespace(cells=cells, _cell_base=float(cells[0] - 0.5 * cell_m), p=SimpleNamespace(cell_m=cell_m),
                          merge_x=merge_x, cos_ramp=float(np.cos(np.radians(rng.uniform(5, 30)))))
    for _ in range(2000):
        n = int(rng.integers(0, 60))
        front = rng.uniform(0.0, 760.0, n)
        front[rng.random(n) < 0.1] = cells[0] - 0.5 * cell_m + cell_m * rng.integers(0, 10)  # on cell edges
        v = np.maximum(rng.uniform(-1.0, 35.0, n) * 10.0 ** rng.integers(-2, 1, n), 0.0)
        on_ramp = rng.random(n) < 0.2
        t = float(rng.uniform(0, 750))
        ref_cells, ref_eta, _, _ = WaveDamping._road_ahead_numpy(rsu, t, front, v, on_ramp)  # type: ignore[arg-type]
        got_cells, got_eta = np.empty(len(cells)), np.empty(int(on_ramp.sum()))
        road_ahead(front, v, on_ramp, rsu._cell_base, cell_m, merge_x, rsu.cos_ramp, t, got_cells, got_eta)
        assert np.array_equal(got_cells, ref_cells, equal_nan=True)
        assert np.array_equal(got_eta, ref_eta)
