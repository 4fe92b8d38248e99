"""Control-tube avoidance: tube geometry of the plan, worst-case intruder manoeuvre, conflict geometries.

NMAC threshold: 100 ft horizontal / 15 ft vertical (Weinert et al. 2018, sUAS); the controller's
safety radius (35 m) plus the intruder size (0.5 m) is the separation the tube guarantees.
"""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.control_tube import ControlTubeAvoidance, ControlTubeParams
from corridor.controllers.uav_models import (
    NMAC_HORIZONTAL_M,
    AvoidanceObservation,
    PointMassParams,
    TrackedAgent,
    encounter,
    fly,
    min_separation_m,
    nmac_count,
    step_states,
    straight_to_goal,
    time_to_goal_s,
)

MODEL = PointMassParams()
PARAMS = ControlTubeParams()
GUARANTEED_M = PARAMS.uav_safety_radius_m + PARAMS.uav_size_m  # [m]


def _intercept_direction(ego: np.ndarray, q: np.ndarray, qv: np.ndarray) -> np.ndarray:
    """Unit vector to steer the intruder's velocity onto a collision course with the ego."""
    rel = ego[:3] - q
    dist = max(float(np.linalg.norm(rel)), 1e-6)
    t_go = dist / max(float(-(rel @ (ego[3:] - qv))) / dist, 1.0)
    aim = rel + (ego[3:] - qv) * min(t_go, 30.0)
    return aim / max(float(np.linalg.norm(aim)), 1e-6)


def _pursuit(geometry: str, avoid: bool, seed: int = 0, sigma_m: float = 3.0) -> tuple[np.ndarray, int]:
    """Worst case: the intruder accelerates at a_max straight at the ego (speed capped at 10 m/s).

    The ego sees the intruder's position with an error inside its sigma ball. Returns the true 3D
    separation at every 10 ms simulation step and the number of infeasible QP steps.
    """
    rng, dt_s, a_max = np.random.default_rng(seed), 0.01, PARAMS.uav_accel_mps2
    ego, goal = np.array([-250.0, 0.0, 50.0, 10.0, 0.0, 0.0]), np.array([400.0, 0.0, 50.0])
    if geometry == "head_on":
        q, qv = np.array([250.0, 0.0, 50.0]), np.array([-10.0, 0.0, 0.0])
    else:
        q, qv = np.array([0.0, -250.0, 50.0]), np.array([0.0, 10.0, 0.0])
    ctrl = ControlTubeAvoidance(PARAMS)
    ctrl.reset(rng)
    every, u, seps = int(round(PARAMS.period_s / dt_s)), ego[3:].copy(), []
    for k in range(int(40.0 / dt_s)):
        if k % every == 0:
            noise = rng.normal(size=3)
            noise *= sigma_m * rng.uniform() / np.linalg.norm(noise)
            seen = (TrackedAgent("intruder", q + noise, qv.copy(), sigma_m),)
            obs = AvoidanceObservation(k * dt_s, ego[:3].copy(), ego[3:].copy(), goal, seen)
            u = ctrl.step(obs).vel_mps if avoid else straight_to_goal(ego, goal, 10.0)
        ego = step_states(ego, u, MODEL, dt_s)
        acc = a_max * _intercept_direction(ego, q, qv)
        q = q + qv * dt_s + 0.5 * acc * dt_s**2
        qv = qv + acc * dt_s
        qv *= min(1.0, 10.0 / np.linalg.norm(qv))  # projection onto the speed ball: |dv| <= a_max dt
        seps.append(float(np.linalg.norm(ego[:3] - q)))
    return np.array(seps), ctrl.infeasible_steps


@pytest.mark.parametrize("geometry", ["head_on", "crossing"])
def test_ct_worst_case_pursuer_never_breaches_the_safety_radius(geometry: str) -> None:
    """The property: separation >= r_safe + r0 at every 10 ms step under an a_max pursuit."""
    unprotected, _ = _pursuit(geometry, avoid=False)
    assert unprotected.min() < 5.0  # the manoeuvre is a real threat: it hits a non-avoiding UAV
    seps, _ = _pursuit(geometry, avoid=True)
    assert seps.min() >= GUARANTEED_M, f"{geometry}: {seps.min():.2f} m"


def test_ct_plan_stays_outside_every_tube_ball() -> None:
    """Every predicted ego position of a feasible plan is outside the intruder ball at that time."""
    intruder = TrackedAgent("i", np.array([200.0, 5.0, 50.0]), np.array([-10.0, 0.0, 0.0]), 2.0)
    obs = AvoidanceObservation(
        0.0, np.array([0.0, 0.0, 50.0]), np.array([10.0, 0.0, 0.0]), np.array([500.0, 0.0, 50.0]), (intruder,)
    )
    ctrl = ControlTubeAvoidance(PARAMS)
    cmd = ctrl.step(obs)
    t, pos = ctrl.planned_positions()
    radius = GUARANTEED_M + intruder.sigma_m + 0.5 * PARAMS.uav_accel_mps2 * t**2  # closed form
    dist = np.linalg.norm(pos - (intruder.pos + np.outer(t, intruder.vel)), axis=1)
    assert cmd.info["slack_m"] < 1e-6 and ctrl.infeasible_steps == 0
    assert np.all(dist >= radius - 1e-6)
    assert np.any(dist < radius + 20.0)  # the constraint is active, not trivially far
    assert cmd.avoiding and cmd.vel_mps[1] < 0.0  # both-turn-right convention: heading east -> south
    assert pos[-1, 1] < -1.0


def test_ct_free_flight_follows_nominal_within_limits() -> None:
    """With nobody around the plan is the goal-seeking command, inside the speed limits."""
    obs = AvoidanceObservation(0.0, np.zeros(3), np.zeros(3), np.array([300.0, 400.0, 60.0]), ())
    ctrl = ControlTubeAvoidance(PARAMS)
    cmd = ctrl.step(obs)
    _, pos = ctrl.planned_positions()
    late = pos[-1, :2] - pos[-3, :2]  # heading over the last command step of the plan
    np.testing.assert_allclose(late / np.linalg.norm(late), [0.6, 0.8], atol=0.02)
    assert np.linalg.norm(late) / PARAMS.step_s > 0.9 * PARAMS.max_speed_h_mps * np.cos(np.pi / 8)
    assert np.hypot(*cmd.vel_mps[:2]) <= PARAMS.max_speed_h_mps + 1e-6
    assert abs(cmd.vel_mps[2]) <= PARAMS.max_climb_mps + 1e-6
    assert cmd.info["slack_m"] == 0.0 and not cmd.avoiding


def test_ct_solve_is_deterministic() -> None:
    intruder = TrackedAgent("i", np.array([100.0, 0.0, 50.0]), np.array([-10.0, 0.0, 0.0]))
    obs = AvoidanceObservation(
        0.0, np.array([0.0, 0.0, 50.0]), np.array([10.0, 0.0, 0.0]), np.array([500.0, 0.0, 50.0]), (intruder,)
    )
    a, b = ControlTubeAvoidance(PARAMS), ControlTubeAvoidance(PARAMS)
    np.testing.assert_array_equal(a.step(obs).vel_mps, b.step(obs).vel_mps)


@pytest.mark.parametrize("name", ["head_on", "crossing", "overtaking"])
def test_ct_pairwise_encounters_keep_separation_and_reach_goals(name: str) -> None:
    x0, goals = encounter(name)
    params = ControlTubeParams(period_s=0.2)  # any period <= step_s keeps the guarantee
    ctrls = [ControlTubeAvoidance(params) for _ in x0]
    traj = fly(ctrls, x0, goals, MODEL, 90.0, dt_s=0.05, control_period_s=params.period_s)
    assert nmac_count(traj.pos) == 0
    assert min_separation_m(traj.pos) >= GUARANTEED_M
    assert sum(c.infeasible_steps for c in ctrls) == 0
    assert np.all(np.isfinite(time_to_goal_s(traj, goals)))


@pytest.mark.slow
def test_ct_eight_uav_swap_through_centre() -> None:
    """Swarm swap; other UAVs are cooperative, so their assumed manoeuvre bound is 0.5 m/s^2."""
    params = ControlTubeParams(uav_accel_mps2=0.5, period_s=0.2)
    x0, goals = encounter("swap")
    ctrls = [ControlTubeAvoidance(params) for _ in x0]
    traj = fly(ctrls, x0, goals, MODEL, 180.0, dt_s=0.05, control_period_s=0.2)
    assert nmac_count(traj.pos) == 0
    assert min_separation_m(traj.pos) > NMAC_HORIZONTAL_M
    assert np.all(np.isfinite(time_to_goal_s(traj, goals)))
