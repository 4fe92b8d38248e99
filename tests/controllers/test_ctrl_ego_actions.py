"""highway-env's action conventions as plain functions (corridor.controllers.ego_actions): closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.controllers.ego_actions import (
    FASTER,
    IDLE,
    LANE_LEFT,
    LANE_RIGHT,
    SLOWER,
    MetaTarget,
    apply_meta,
    continuous,
    nearest_speed_index,
    speed_control,
    speed_reward,
    steering_control,
)
from corridor.vehicles.ground.bicycle import BicycleParams, rk4_step

SPEEDS = (10.0, 20.0, 30.0)


def test_meta_actions_move_the_targets_and_clamp() -> None:
    t = MetaTarget(SPEEDS, 1, 0)
    assert apply_meta(t, FASTER, 2).speed_mps == 30.0 and apply_meta(t, SLOWER, 2).speed_mps == 10.0
    assert apply_meta(apply_meta(t, FASTER, 2), FASTER, 2).speed_index == 2  # the top speed stays
    assert apply_meta(t, LANE_LEFT, 2).lane == 1 and apply_meta(t, LANE_RIGHT, 2).lane == 0
    assert apply_meta(MetaTarget(SPEEDS, 1, 1), LANE_LEFT, 2).lane == 1
    assert apply_meta(t, IDLE, 2) == t
    with pytest.raises(ValueError, match="meta-action 5"):
        apply_meta(t, 5, 2)
    assert nearest_speed_index(SPEEDS, 24.0) == 1


def test_speed_and_reward_terms() -> None:
    assert speed_control(20.0, 26.0) == pytest.approx(10.0)  # (26 - 20) / 0.6 s
    assert speed_reward(25.0, 20.0, 30.0) == 0.5 and speed_reward(35.0, 20.0, 30.0) == 1.0
    assert continuous([-1.0, 1.0], (-5.0, -0.3), (3.0, 0.3)) == (-5.0, 0.3)
    assert continuous([0.0, 2.0], (-5.0, -0.3), (3.0, 0.3)) == (-1.0, 0.3)  # clipped to [-1, 1]
    with pytest.raises(ValueError, match="expected 2 values"):
        continuous([0.0], (-1.0, -1.0), (1.0, 1.0))


def test_the_lateral_controller_brings_the_bicycle_onto_the_lane_centre() -> None:
    """A bicycle 3.5 m right of the target lane's centre, steered by it for 6 s at 20 m/s, ends on it."""
    p = BicycleParams()
    x = np.array([0.0, -3.5, 0.0, 20.0])  # rear axle x, y [m], yaw [rad], v [m/s]
    assert steering_control(x[1], x[2], x[3], p.wheelbase_m) > 0.0  # right of the centre: steer left
    for _ in range(60):
        u = np.array([0.0, float(np.clip(steering_control(x[1], x[2], x[3], p.wheelbase_m), -p.steer_max_rad,
                                         p.steer_max_rad))])
        x = rk4_step(x, u, 0.1, p)
    assert abs(x[1]) < 0.1 and abs(x[2]) < math.radians(2.0)
