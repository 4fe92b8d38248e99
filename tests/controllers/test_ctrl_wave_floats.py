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
