"""Control-tube avoidance: tube geometry of the plan, worst-case intruder manoeuvre, conflict geometries.

NMAC threshold: 100 ft horizontal / 15 ft vertical (Weinert et al. 2018, sUAS); the controller's
safety radius (35 m) plus the intruder size (0.5 m) is the separation the tube guarantees.
"""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.uav.control_tube import ControlTubeAvoidance, ControlTubeParams
from corridor.controllers.uav.models import (
    NMAC_HORIZONTAL_M,
    AvoidanceObservation,
    PointMassParams,
    encounter,
    fly,
    min_separation_m,
    nmac_count,
    step_states,
    straight_to_goal,
    time_to_goal_s,
)
from corridor.vehicles.tracks.agent import TrackedAgent

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


def _swap_times(deflect_max_deg: float) -> tuple[np.ndarray, int, int]:
    params = ControlTubeParams(uav_accel_mps2=0.5, period_s=0.2, deflect_max_deg=deflect_max_deg)
    x0, goals = encounter("swap")
    ctrls = [ControlTubeAvoidance(params) for _ in x0]
    traj = fly(ctrls, x0, goals, MODEL, 120.0, dt_s=0.1, control_period_s=0.2)
    return time_to_goal_s(traj, goals), nmac_count(traj.pos), sum(c.infeasible_steps for c in ctrls)


def test_ct_right_hand_nominal_unjams_the_swap() -> None:
    """The nominal's right-hand deflection (the swap's deadlock remedy) measured on the 8-UAV swap:
    every UAV arrives before 100 s (88 s measured; 60 s straight) with no infeasible QP, while the
    straight-to-goal nominal jams at the centre (114-118 s, infeasible steps). NMAC-free both ways."""
    t_with, nmac_with, infeasible_with = _swap_times(70.0)
    t_without, nmac_without, infeasible_without = _swap_times(0.0)
    assert np.all(t_with < 100.0) and infeasible_with == 0 and nmac_with == 0
    assert nmac_without == 0
    assert np.nanmean(t_without) > np.mean(t_with) + 15.0 or not np.all(np.isfinite(t_without))
    assert infeasible_without > 0


def test_ct_zero_copy_solver_call_equals_the_plain_casadi_call() -> None:
    """The QP goes to qpOASES through CasADi's zero-copy Function.buffer (numpy -> DM conversion cost
    several times the solve); a fresh solver called the ordinary way must return the same optimum."""
    rng = np.random.default_rng(3)
    ctrl = ControlTubeAvoidance(PARAMS)
    others = tuple(TrackedAgent(str(i), np.array([60.0, 0.0, 50.0]) + rng.normal(0.0, 20.0, 3),
                                rng.normal(0.0, 4.0, 3)) for i in range(3))
    obs = AvoidanceObservation(0.0, np.array([0.0, 0.0, 50.0]), np.array([6.0, 0.0, 0.0]),
                               np.array([400.0, 0.0, 50.0]), others)
    x0 = np.concatenate([obs.own_pos, obs.own_vel])
    intruders = ctrl._relevant(obs, ctrl._ego_speed_bound(x0[3:]))
    k = len(intruders)
    assert k == 3
    qp = ctrl._qp(k)
    nominal = ctrl._nominal(x0, obs.goal, ctrl._deflection(obs, intruders))
    c_rows, c_lo = ctrl._collision_rows(obs, x0, intruders, nominal)
    a_lo, a_hi = ctrl._accel_bounds(x0)
    amat = np.vstack([c_rows, qp.fixed])
    lba = np.concatenate([c_lo, a_lo, ctrl._speed_lo])
    uba = np.concatenate([np.full(len(c_lo), 1e20), a_hi, ctrl._speed_hi])
    g = ctrl._gradient(nominal, obs.own_vel, k)
    z, ok = qp.solve(g, amat, lba, uba)
    plain = ctrl._build_solver(len(g), len(lba))
    ref = np.asarray(plain(h=qp.h, g=g, a=amat, lba=lba, uba=uba, lbx=qp.lbx, ubx=qp.ubx)["x"]).ravel()
    assert ok and plain.stats()["success"]
    np.testing.assert_allclose(z, ref, atol=1e-9)
    assert np.min(c_rows @ z - c_lo) > -1e-6  # the optimum respects every tube half-space


def test_ct_fleet_step_equals_uav_by_uav_steps() -> None:
    """step_many (the tube rows of every UAV's intruders built in one pass) returns exactly the commands
    of each UAV's own step, over a converging swarm where the number of intruders varies."""
    from corridor.controllers.uav.control_tube import step_many

    n, params = 6, ControlTubeParams(period_s=0.2, uav_accel_mps2=1.0)
    ang = 2.0 * np.pi * np.arange(n) / n
    pos = np.column_stack([80.0 * np.cos(ang), 80.0 * np.sin(ang), np.full(n, 50.0)])
    vel = -0.08 * pos * np.array([1.0, 1.0, 0.0])
    goal = -pos + np.array([0.0, 0.0, 100.0])
    solo, fleet = [ControlTubeAvoidance(params) for _ in range(n)], [ControlTubeAvoidance(params) for _ in range(n)]
    counts = set()
    for k in range(25):
        t = 0.2 * k
        obs = [AvoidanceObservation(t, pos[i], vel[i], goal[i], tuple(
            TrackedAgent(str(j), pos[j].copy(), vel[j].copy(), 1.0) for j in range(n) if j != i)) for i in range(n)]
        a = [m.step(o) for m, o in zip(solo, obs, strict=True)]
        b = step_many(fleet, obs)
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x.vel_mps, y.vel_mps) and x.avoiding == y.avoiding and x.info == y.info
        counts |= {int(c.info["n_intruders"]) for c in a}
        cmd = np.array([c.vel_mps for c in a])
        pos, vel = pos + 0.2 * cmd, cmd
    assert len(counts) > 1  # different intruder counts were batched together


def _qpoases_optimum(ctrl: ControlTubeAvoidance, obs: AvoidanceObservation) -> np.ndarray:
    """The step's QP solved by qpOASES (the full problem, no shortcut), as the controller builds it."""
    s = ctrl._prepare(obs)
    k = len(s.intruders)
    c_rows, c_lo = ctrl._collision_rows(obs, s.x0, s.intruders, s.u_ref) if k else (np.zeros((0, ctrl.n_u)), np.zeros(0))
    a_lo, a_hi = ctrl._accel_bounds(s.x0)
    qp = ctrl._qp(k)
    amat = np.vstack([c_rows, qp.fixed])
    lba = np.concatenate([c_lo, a_lo, ctrl._speed_lo])
    uba = np.concatenate([np.full(len(c_lo), 1e20), a_hi, ctrl._speed_hi])
    last = ctrl._last_cmd if ctrl._last_cmd is not None else ctrl._saturate(obs.own_vel)
    z, ok = qp.solve(ctrl._gradient(s.nominal, last, k), amat, lba, uba)
    assert ok
    return z[:3]


@pytest.mark.parametrize("case", ["free", "far_intruder", "binding_intruder"])
def test_ct_unconstrained_steps_equal_the_qp_optimum(case: str) -> None:
    """When the unconstrained minimiser satisfies every constraint it is the QP's optimum: the step
    takes it without calling qpOASES and returns what qpOASES returns; a binding tube still goes to
    the solver."""
    # cruising at the speed limit towards a far goal, 22.5 deg off the axes (inside the speed octagon)
    e = np.array([np.cos(np.pi / 8), np.sin(np.pi / 8), 0.0])
    own_p, goal = np.array([0.0, 0.0, 50.0]), np.array([0.0, 0.0, 50.0]) + 400.0 * e
    own_v = PARAMS.max_speed_h_mps * np.cos(np.pi / 8) * e
    left = np.array([-e[1], e[0], 0.0])
    others = {"free": (),  # a UAV abeam 150 m to the left, slightly behind, flying away: its tube is far
              "far_intruder": (TrackedAgent("i", own_p + 150.0 * left - 5.0 * e, 5.0 * left, 2.0),),
              "binding_intruder": (TrackedAgent("i", own_p + 60.0 * e + 2.0 * left, -6.0 * e, 2.0),)}
    obs = AvoidanceObservation(0.0, own_p, own_v, goal, others[case])
    ref = _qpoases_optimum(ControlTubeAvoidance(PARAMS), obs)
    ctrl = ControlTubeAvoidance(PARAMS)
    cmd = ctrl.step(obs)
    assert ctrl.unconstrained_steps == (0 if case == "binding_intruder" else 1)
    assert len(ctrl.solve_times_s) == (1 if case == "binding_intruder" else 0)
    np.testing.assert_allclose(cmd.vel_mps, ref, atol=1e-9)
    if case == "far_intruder":
        assert cmd.info["n_intruders"] == 1.0 and not cmd.avoiding



def _phugoid_pass(offset_m: float) -> tuple[float, float]:
    """A c172x-like piloted aircraft at 50 m/s crosses the path of a UAV flying west (the geometry of
    uav_encounter's plain run 5076), its altitude oscillating +-11 m with a 32 s period (the phugoid
    of JSBSim's c172x): descending for the first 6 s, climbing through the pass at 13 s, where it is
    ``offset_m`` above the UAV's start. Returns (smallest 3D separation [m], UAV minus aircraft
    altitude at that instant [m])."""
    dt_s, w, v = 0.02, 2.0 * np.pi / 32.0, np.array([-17.3, 47.0])
    ego, goal = np.array([112.0, -100.0, 61.0, -4.0, 0.0, 0.0]), np.array([-128.0, -100.0, 61.0])
    ctrl = ControlTubeAvoidance(PARAMS)
    ctrl.reset(np.random.default_rng(0))
    every, u, best = int(round(PARAMS.period_s / dt_s)), np.zeros(3), (np.inf, 0.0)
    for k in range(int(30.0 / dt_s)):
        t = k * dt_s
        z = 61.0 + offset_m - 8.25 - 11.25 * np.cos(w * (t - 6.0))
        q = np.array([*(np.array([55.0, -92.0]) + v * (t - 13.0)), z])
        qv = np.array([*v, 11.25 * w * np.sin(w * (t - 6.0))])
        if k % every == 0:
            seen = (TrackedAgent("c172x", q.copy(), qv.copy(), 2.0, is_piloted=True),)
            u = ctrl.step(AvoidanceObservation(t, ego[:3].copy(), ego[3:].copy(), goal, seen)).vel_mps
        ego = step_states(ego, u, MODEL, dt_s)
        sep = float(np.linalg.norm(ego[:3] - q))
        if sep < best[0]:
            best = (sep, float(ego[2] - q[2]))
    return best


@pytest.mark.parametrize("offset_m", [18.0, 22.0, 24.0])
def test_ct_passes_below_a_phugoiding_aircraft_that_is_above(offset_m: float) -> None:
    """The aircraft is above the UAV throughout, but early on it descends, so its tube centre
    extrapolated over the 6 s horizon lies below the UAV. Taking the vertical side from that
    centre made the UAV climb, the previous plan kept it climbing, and the aircraft climbed towards
    it through the pass (uav_encounter run 5076: 11.8 m). With the side from the measured altitudes
    the UAV goes down and passes below with more room."""
    sep, dz = _phugoid_pass(offset_m)
    assert dz < 0.0
    assert sep > 65.0


def test_ct_climbs_when_above_a_piloted_aircraft() -> None:
    """The mirror case: a UAV above the aircraft's measured altitude is pushed up, not down."""
    ctrl = ControlTubeAvoidance(PARAMS)
    ctrl.reset(np.random.default_rng(0))
    q, qv = np.array([0.0, -400.0, 50.0]), np.array([0.0, 50.0, -3.0])  # sinking: centre farther below
    seen = (TrackedAgent("c172x", q, qv, 2.0, is_piloted=True),)
    obs = AvoidanceObservation(0.0, np.array([0.0, 0.0, 60.0]), np.zeros(3), np.array([60.0, 0.0, 60.0]), seen)
    assert ctrl.step(obs).vel_mps[2] > 0.0
