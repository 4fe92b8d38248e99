"""Point-mass UAV model shared by the avoidance controllers, their predictor and their test harness.

The model is written once: ``first_order_velocity(x, u, params)`` is the continuous dynamics of a
multirotor whose attitude/rate loops are abstracted as a first-order response of the velocity to a
velocity command, with the acceleration limited (horizontal norm and vertical separately)::

    x = [p_E, p_N, p_U, v_E, v_N, v_U]  [m, m/s]      u = commanded velocity [m/s, ENU]
    a = sat((u - v) / tau)                               p' = v,  v' = a

The control-tube MPC uses ``discrete_matrices`` (exact zero-order-hold discretisation of the same
model without saturation; it constrains its plan so that the saturation never becomes active, so the
prediction is exact), and the closed-loop simulator ``run_closed_loop`` integrates
``first_order_velocity`` itself, saturation included.

This module also holds the small, frozen interface types of the avoidance controllers
(``AvoidanceObservation``, ``VelocityCommand``; the ``TrackedAgent`` they see is the vehicles' own,
``corridor.vehicles.tracks.agent``) and the separation metrics used by
their tests, so that both controllers and the harness share one definition.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.linalg import expm

from corridor.vehicles.tracks.agent import TrackedAgent

#: Near mid-air collision cylinder for small UAS (Weinert et al. 2018, "Well-Clear Recommendation for
#: Small Unmanned Aircraft Systems Based on Unmitigated Collision Risk", J. Air Transportation 26(3)):
#: 100 ft horizontal and 15 ft vertical.
NMAC_HORIZONTAL_M = 30.48  # [m] 100 ft
NMAC_VERTICAL_M = 4.572  # [m] 15 ft


class PointMassParams(BaseModel):
    """Parameters of the first-order-velocity point mass (defaults: a ~2 kg quadcopter)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    tau_s: float = Field(0.5, gt=0.0)  # [s] velocity response time constant
    max_accel_h_mps2: float = Field(4.0, gt=0.0)  # [m/s^2] horizontal acceleration limit (norm)
    max_accel_v_mps2: float = Field(2.0, gt=0.0)  # [m/s^2] vertical acceleration limit


@dataclass(frozen=True)
class AvoidanceObservation:
    """What an avoidance controller sees at one decision instant."""

    t: float  # [s]
    own_pos: np.ndarray  # [m] ENU, shape (3,)
    own_vel: np.ndarray  # [m/s] ENU, shape (3,)
    goal: np.ndarray  # [m] ENU, shape (3,)
    others: tuple[TrackedAgent, ...] = ()


@dataclass(frozen=True)
class VelocityCommand:
    """Velocity set-point for the ego's velocity loop, plus diagnostics."""

    t: float  # [s]
    vel_mps: np.ndarray  # [m/s] ENU, shape (3,)
    avoiding: bool = False  # an avoidance term/constraint shaped this command
    info: dict[str, float] = field(default_factory=dict)


def accel_of(v: np.ndarray, u: np.ndarray, params: PointMassParams) -> np.ndarray:
    """Saturated acceleration (u - v)/tau of the velocity loop; works on (..., 3) arrays."""
    a = (np.asarray(u, dtype=float) - np.asarray(v, dtype=float)) / params.tau_s
    a_h = np.linalg.norm(a[..., :2], axis=-1, keepdims=True)
    scale = np.minimum(1.0, params.max_accel_h_mps2 / np.maximum(a_h, 1e-12))
    return np.concatenate(
        [a[..., :2] * scale, np.clip(a[..., 2:], -params.max_accel_v_mps2, params.max_accel_v_mps2)],
        axis=-1,
    )


def first_order_velocity(x: np.ndarray, u: np.ndarray, params: PointMassParams) -> np.ndarray:
    """Continuous dynamics x' = f(x, u, params); x is (..., 6), u is (..., 3)."""
    x = np.asarray(x, dtype=float)
    return np.concatenate([x[..., 3:], accel_of(x[..., 3:], u, params)], axis=-1)


def discrete_matrices(params: PointMassParams, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation x+ = A x + B u of the unsaturated model over dt_s."""
    ac = np.zeros((6, 6))
    ac[:3, 3:] = np.eye(3)
    ac[3:, 3:] = -np.eye(3) / params.tau_s
    bc = np.zeros((6, 3))
    bc[3:, :] = np.eye(3) / params.tau_s
    big = np.zeros((9, 9))
    big[:6, :6], big[:6, 6:] = ac * dt_s, bc * dt_s
    phi = expm(big)
    return phi[:6, :6], phi[:6, 6:]


def step_states(x: np.ndarray, u: np.ndarray, params: PointMassParams, dt_s: float) -> np.ndarray:
    """One integration step of f over dt_s (acceleration held over the step; dt_s << tau)."""
    a = accel_of(x[..., 3:], u, params)
    pos = x[..., :3] + x[..., 3:] * dt_s + 0.5 * a * dt_s**2
    return np.concatenate([pos, x[..., 3:] + a * dt_s], axis=-1)


@dataclass(frozen=True)
class FleetTrajectory:
    """Closed-loop history of N point masses sampled every simulation step."""

    t: np.ndarray  # [s] shape (T,)
    pos: np.ndarray  # [m] shape (T, N, 3)
    vel: np.ndarray  # [m/s] shape (T, N, 3)
    cmd: np.ndarray  # [m/s] commanded velocity in force at each sample, shape (T, N, 3)


Policy = Callable[[float, np.ndarray], np.ndarray]  # (t, states (N, 6)) -> commands (N, 3)


def run_closed_loop(
    x0: np.ndarray,
    policy: Policy,
    params: PointMassParams,
    duration_s: float,
    dt_s: float = 0.01,
    control_period_s: float = 0.1,
) -> FleetTrajectory:
    """Simulate N point masses with a zero-order-hold policy evaluated every control period."""
    n_steps = int(round(duration_s / dt_s))
    every = max(1, int(round(control_period_s / dt_s)))
    x = np.array(x0, dtype=float)
    u = np.zeros((x.shape[0], 3))
    ts, ps, vs, us = [], [], [], []
    for k in range(n_steps + 1):
        t = k * dt_s
        if k % every == 0:
            u = np.asarray(policy(t, x.copy()), dtype=float)
        ts.append(t), ps.append(x[:, :3].copy()), vs.append(x[:, 3:].copy()), us.append(u.copy())
        x = step_states(x, u, params, dt_s)
    return FleetTrajectory(np.array(ts), np.array(ps), np.array(vs), np.array(us))


def pairwise_separation(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical separation [m] of every pair, each shape (T, N, N); diagonal = inf."""
    d = pos[:, :, None, :] - pos[:, None, :, :]
    horiz = np.linalg.norm(d[..., :2], axis=-1)
    vert = np.abs(d[..., 2])
    eye = np.eye(pos.shape[1], dtype=bool)
    horiz[:, eye], vert[:, eye] = np.inf, np.inf
    return horiz, vert


def min_separation_m(pos: np.ndarray) -> float:
    """Smallest 3D distance [m] between any two agents at any sample."""
    d = pos[:, :, None, :] - pos[:, None, :, :]
    dist = np.linalg.norm(d, axis=-1)
    dist[:, np.eye(pos.shape[1], dtype=bool)] = np.inf
    return float(dist.min())


def nmac_count(
    pos: np.ndarray, horizontal_m: float = NMAC_HORIZONTAL_M, vertical_m: float = NMAC_VERTICAL_M
) -> int:
    """Number of distinct pairs that ever enter the NMAC cylinder (horizontal AND vertical)."""
    horiz, vert = pairwise_separation(pos)
    inside = np.any((horiz < horizontal_m) & (vert < vertical_m), axis=0)
    return int(np.triu(inside, k=1).sum())


def observation_for(
    i: int,
    t: float,
    states: np.ndarray,
    goals: np.ndarray,
    sigma_m: float = 0.0,
    piloted: frozenset[int] = frozenset(),
) -> AvoidanceObservation:
    """Observation of agent i from true fleet states (perfect tracking plus a stated sigma)."""
    others = tuple(
        TrackedAgent(str(j), states[j, :3].copy(), states[j, 3:].copy(), sigma_m, j in piloted)
        for j in range(states.shape[0])
        if j != i
    )
    return AvoidanceObservation(t, states[i, :3].copy(), states[i, 3:].copy(), goals[i].copy(), others)


def encounter(
    name: str, n_swap: int = 8, radius_m: float = 300.0, alt_m: float = 50.0, speed_mps: float = 10.0
) -> tuple[np.ndarray, np.ndarray]:
    """Initial states (N, 6) and goals (N, 3) of a canonical conflict geometry.

    ``head_on`` and ``crossing`` (90 degrees) meet at the origin at the same time; ``overtaking`` puts
    a fast UAV 100 m behind a slow one (0.4 x speed) on the same track (caught up after ~17 s, both
    goals ahead on that track); ``swap`` places ``n_swap``
    UAVs on a circle, each flying to the antipodal point through the common centre.
    """
    r, z = radius_m, alt_m
    speeds = np.full(2, speed_mps)
    if name == "head_on":
        start, goals = np.array([[-r, 0, z], [r, 0, z]]), np.array([[r, 0, z], [-r, 0, z]])
    elif name == "crossing":
        start, goals = np.array([[-r, 0, z], [0, -r, z]]), np.array([[r, 0, z], [0, r, z]])
    elif name == "overtaking":
        start = np.array([[-r, 0, z], [-r + 100.0, 0, z]])
        goals = np.array([[r, 0, z], [100.0, 0, z]])
        speeds = np.array([speed_mps, 0.4 * speed_mps])
    elif name == "swap":
        ang = 2.0 * np.pi * np.arange(n_swap) / n_swap
        start = np.stack([r * np.cos(ang), r * np.sin(ang), np.full(n_swap, z)], axis=1)
        goals = start * np.array([-1.0, -1.0, 1.0])
        speeds = np.full(n_swap, speed_mps)
    else:
        raise ValueError(f"unknown encounter {name!r}")
    heading = goals - start
    heading /= np.linalg.norm(heading, axis=1, keepdims=True)
    return np.hstack([start, heading * speeds[:, None]]).astype(float), goals.astype(float)


def straight_to_goal(x: np.ndarray, goal: np.ndarray, speed_mps: float, gain_per_s: float = 0.5) -> np.ndarray:
    """Non-avoiding command: toward the goal at speed_mps, slowing linearly near it."""
    e = goal - x[:3]
    dist = float(np.linalg.norm(e))
    return e / max(dist, 1e-9) * min(speed_mps, gain_per_s * dist)


def fly(
    controllers: list,
    x0: np.ndarray,
    goals: np.ndarray,
    params: PointMassParams,
    duration_s: float,
    dt_s: float = 0.02,
    control_period_s: float = 0.1,
    sigma_m: float = 0.0,
) -> FleetTrajectory:
    """Closed loop of a fleet; controllers[i] has ``step(obs) -> VelocityCommand`` or is None.

    A None entry flies ``straight_to_goal`` at its initial speed (no avoidance); every agent sees the
    others' true states, tracked with uncertainty radius ``sigma_m``.
    """
    cruise = np.linalg.norm(x0[:, 3:], axis=1)

    def policy(t: float, states: np.ndarray) -> np.ndarray:
        out = np.zeros((states.shape[0], 3))
        for i, ctrl in enumerate(controllers):
            if ctrl is None:
                out[i] = straight_to_goal(states[i], goals[i], float(cruise[i]))
            else:
                out[i] = ctrl.step(observation_for(i, t, states, goals, sigma_m)).vel_mps
        return out

    return run_closed_loop(x0, policy, params, duration_s, dt_s, control_period_s)


def time_to_goal_s(traj: FleetTrajectory, goals: np.ndarray, tol_m: float = 5.0) -> np.ndarray:
    """First time [s] each agent is within tol_m of its goal (nan if never)."""
    dist = np.linalg.norm(traj.pos - goals[None], axis=2)
    hit = dist < tol_m
    return np.where(hit.any(axis=0), traj.t[np.argmax(hit, axis=0)], np.nan)
