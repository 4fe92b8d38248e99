"""The highway-env parking-lot backend: seeded lot, snapshot and landmarks, highway-env's kinematics
against closed forms, its own success criterion and crash report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.engine import RunContext
from corridor.snapshot import Kind, Role
from corridor.vehicles.ground.highway_env_parking import EGO_ID, HighwayEnvParking, ParkingInput


def make(seed: int = 3, **params: object) -> tuple[HighwayEnvParking, RunContext]:
    ctx = RunContext(run_seed=seed, dt=0.1, duration=30.0)
    b = HighwayEnvParking("lot", HighwayEnvParking.Params(**params), None)
    b.setup(ctx)
    return b, ctx


def drive(b: HighwayEnvParking, ctx: RunContext, accel: float, steer: float, steps: int) -> None:
    for _ in range(steps):
        b.apply([ParkingInput(EGO_ID, accel, steer)], ctx)
        b.tick(ctx)
        ctx.t += b.period


def test_same_seed_same_lot_and_snapshot_rows() -> None:
    a, _ = make(7, vehicles_count=12)
    b, _ = make(7, vehicles_count=12)
    c, _ = make(8, vehicles_count=12)
    sa, sb = a.snapshot_part(), b.snapshot_part()
    assert a.lot.goal_bay == b.lot.goal_bay and np.array_equal(a.lot.occupied, b.lot.occupied)
    assert np.array_equal(sa.position, sb.position) and np.array_equal(sa.heading, sb.heading)
    assert (a.lot.goal_bay, tuple(a.lot.occupied)) != (c.lot.goal_bay, tuple(c.lot.occupied))
    lot = a.lot
    assert len(lot.bay_centres) == 28 and lot.occupied.sum() == 12 and not lot.occupied[lot.goal_bay]
    cars = sa.kind == Kind.CAR
    assert cars.sum() == 13 and (sa.role == Role.CONTROLLED).sum() == 1 and sa.ids[0] == EGO_ID
    assert (sa.kind == Kind.OBSTACLE).sum() == 4  # the walls
    road = sa.road
    assert road is not None and road.tables.landmarks is lot and len(road) == 13
    # every parked car stands in an occupied bay, the ego in the aisle
    assert road.lane[0] == -1 and set(road.lane[1:]) == set(np.flatnonzero(lot.occupied))


def test_kinematics_straight_line_closed_form() -> None:
    """1 m/s^2 from rest for 2 s on a straight line: 2 m/s and 2 m along the heading (Euler with
    the speed updated after the position, at 20 Hz: 1.9 m)."""
    b, ctx = make(3, vehicles_count=0)
    s0 = b.snapshot_part()
    h = float(s0.heading[0])
    drive(b, ctx, 1.0, 0.0, 20)
    s1 = b.snapshot_part()
    d = s1.position[0, :2] - s0.position[0, :2]
    assert np.hypot(*s1.velocity[0, :2]) == pytest.approx(2.0)
    assert np.hypot(*d) == pytest.approx(0.5 * 2.0**2 * (1 - 1 / 40), rel=1e-9)
    assert math.atan2(d[1], d[0]) == pytest.approx(h)


def test_kinematics_is_a_rear_edge_bicycle() -> None:
    """At constant speed and steering the rear edge of the box (the lot's no-slip point) moves on a
    circle of radius wheelbase / tan(steer), wheelbase = the box length (highway-env's lf = lr = L/2)."""
    b, ctx = make(3, vehicles_count=0)
    lot = b.lot
    b.env.vehicle.speed = 1.0
    steer = 0.4
    rears = []
    for _ in range(40):
        drive(b, ctx, 0.0, steer, 1)
        s = b.snapshot_part()
        h = s.heading[0]
        rears.append(s.position[0, :2] - lot.rear_offset_m * np.array([math.cos(h), math.sin(h)]))
    p = np.array(rears)
    # circle through the points (algebraic fit)
    A = np.column_stack([2 * p, np.ones(len(p))])
    cx, cy, c = np.linalg.lstsq(A, (p**2).sum(axis=1), rcond=None)[0]
    radius = math.sqrt(c + cx**2 + cy**2)
    assert radius == pytest.approx(lot.wheelbase_m / math.tan(steer), rel=0.02)


def test_success_criterion_and_crash_report() -> None:
    b, ctx = make(5, vehicles_count=0)
    lot = b.lot
    v = b.env.vehicle
    v.position = np.array(lot.goal_centre, dtype=float) + [0.3, 0.0]
    v.heading = lot.goal_heading
    drive(b, ctx, 0.0, 0.0, 1)
    assert b.finish(ctx)["he_success"] == 1
    v.heading = lot.goal_heading + math.pi  # reversed in: highway-env's heading term fails it
    drive(b, ctx, 0.0, 0.0, 1)
    assert b.finish(ctx)["he_success"] == 0 and b.finish(ctx)["he_success_any"] == 1
    v.heading = lot.goal_heading
    v.position = np.array([0.0, -20.0])  # into the wall (moving: a standstill is not integrated)
    v.speed = 0.1
    drive(b, ctx, 0.0, 0.0, 1)
    ev = b.snapshot_part().road.events
    assert b.finish(ctx)["he_crashed"] == 1 and ev.collisions and ev.collisions[0][1] == EGO_ID
    assert ev.collisions[0][2].startswith("wall")


def test_intruder_appears_in_front_of_the_goal_bay() -> None:
    b, ctx = make(5, vehicles_count=4, intruder_t_s=0.5)
    drive(b, ctx, 0.0, 0.0, 8)
    s = b.snapshot_part()
    k = list(s.ids).index("intruder")
    lot = b.lot
    assert s.kind[k] == Kind.OBSTACLE and s.size[k, 0] == pytest.approx(0.6)
    into = np.array([math.cos(lot.goal_heading), math.sin(lot.goal_heading)])
    rel = s.position[k, :2] - lot.goal_centre
    assert rel @ into == pytest.approx(-(0.5 * lot.bay_length_m + 3.0))
    assert 2.0 <= abs(rel @ np.array([-into[1], into[0]])) <= 5.0
    assert [e.kind for e in ctx.events.events] == ["scene"]


def test_bad_frequencies_are_refused() -> None:
    with pytest.raises(ValueError, match="whole multiple"):
        HighwayEnvParking.Params(policy_frequency_hz=10, simulation_frequency_hz=15)


def test_success_without_pandas_equals_highway_envs_observation() -> None:
    b, ctx = make(9, vehicles_count=3)
    ot = b.env.observation_type_parking
    for steps in (0, 5, 10):
        drive(b, ctx, 0.8, -0.3, steps)
        obs = ot.observe()
        v = b.env.vehicle
        ego, goal = v.to_dict(), v.goal.to_dict()
        assert np.allclose(np.array([ego[f] for f in ot.features]) / ot.scales, obs["achieved_goal"], rtol=0, atol=0)
        assert np.allclose(np.array([goal[f] for f in ot.features]) / ot.scales, obs["desired_goal"], rtol=0, atol=0)
        assert b.is_success() == b.env._is_success(obs["achieved_goal"], obs["desired_goal"])
    v.position = np.array(b.lot.goal_centre, dtype=float)
    v.heading = b.lot.goal_heading
    assert b.is_success()


def test_standstill_is_not_integrated_but_motion_is() -> None:
    b, ctx = make(9, vehicles_count=3)
    steps0 = b.env.steps
    drive(b, ctx, 0.0, 0.3, 3)  # standing, wheels turned: nothing moves
    assert b.env.steps == steps0
    drive(b, ctx, 0.5, 0.0, 1)
    assert b.env.steps == steps0 + 2 and b.env.vehicle.speed == pytest.approx(0.05)
