"""The fleet-wide potential field gives the per-UAV method's command for every ego."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.uav.models import AvoidanceObservation
from corridor.controllers.uav.potential_field import PotentialFieldAvoidance, PotentialFieldParams
from corridor.controllers.uav.potential_field_fleet import fleet_commands
from corridor.vehicles.tracks.agent import TrackedAgent


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fleet_field_equals_per_uav_method(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, p = 30, PotentialFieldParams(max_speed_h_mps=7.0)
    x = np.column_stack([rng.uniform(0, 300, (n, 2)) * np.where(np.arange(n) < n - 2, 1.0, 8.0)[:, None], rng.uniform(55, 70, n)])
    x[0] = (5000.0, 5000.0, 60.0)  # a lone ego: cruise only
    v = rng.normal(0, 4, (n, 3))
    goal = x + rng.uniform(-400, 400, (n, 3)) * [1, 1, 0.02]
    sigma = rng.uniform(0.5, 4.0, n)
    piloted = np.zeros(n, dtype=bool)
    piloted[-2:] = True
    ego, other = (a.ravel() for a in np.meshgrid(np.arange(n - 2), np.arange(n), indexing="ij"))
    keep = ego != other
    ego, other = ego[keep], other[keep]
    out = fleet_commands(x[: n - 2], v[: n - 2], goal[: n - 2], ego, x[other], v[other], sigma[other],
                         piloted[other], p)
    method = PotentialFieldAvoidance(p)
    avoiding = 0
    for e in range(n - 2):
        others = tuple(TrackedAgent(str(o), x[o], v[o], float(sigma[o]), bool(piloted[o])) for o in range(n) if o != e)
        ref = method.step(AvoidanceObservation(0.0, x[e], v[e], goal[e], others))
        np.testing.assert_allclose(out.v_cmd[e], ref.vel_mps, rtol=1e-9, atol=1e-9)
        assert out.avoiding[e] == ref.avoiding
        avoiding += int(ref.avoiding)
    assert 0 < avoiding < n - 2  # the scene has both
