"""Potential-field collision avoidance for UAVs: saturated gradient flow of an artificial potential.

The ego's velocity command is the saturated negative gradient of::

    J(x) = sum_i b / f_c(x; x_i, v_i) + w_m / f_c(x; x_m, v_m) + J_goal(x)

    f(x; x_i, v_i) = |x - x_i| - tau * max(0, closing speed) - (r_safe + sigma_i)
    f_c            = f if f >= eps else eps * exp(f / eps - 1)        (C1 soft floor, stays > 0)
    J_goal(x)      = k |x - g|^2 inside d_q, continued linearly (cone) outside  (C1)

``f`` grows with distance and shrinks with the closing speed, so the repulsion starts earlier in fast
encounters; the piloted aircraft term uses its own, larger weight, radius and look-ahead (UAVs give
way). The goal term is the usual quadratic well near the goal, continued as a cone beyond ``d_q`` so
that its gradient never exceeds the vehicle's speed limit and cannot drown the repulsion far from the
goal (Choset et al., "Principles of Robot Motion", 2005, sec. 4.1). Gradients are analytic; the
command is clipped to the horizontal speed limit (norm) and to the climb-rate limit.

Local minima. In a symmetric head-on encounter the repulsion is collinear with the goal attraction,
so the gradient flow stops at a saddle where both cancel: the two UAVs face each other forever. The
remedy is a vortex (tangential) term: for each agent that lies ahead on the way to the goal
((x_i - x) . (g - x) > 0) the horizontal repulsion, rotated 90 degrees counter-clockwise, is added
with gain ``vortex_gain``. Seen from the ego this pushes it to its right, so two UAVs meeting head-on
both turn right and pass left side to left side, as the rules of the air prescribe (ICAO Annex 2,
3.2.2.2). The field stays deterministic (no random perturbation) and is unchanged once the other is
behind. Its effect is measured in tests/controllers/test_ctrl_potential_field.py.

Crowds. With a 1/f tail every UAV feels all the others, and in the 20-UAV swap of uav_swarm.yaml the
summed far-field pressure of the crowd keeps pushing UAVs off their goals (10-50 % arrive in 120 s).
The UAV term therefore has bounded support (``uav_cutoff_m`` = f0, default 15 m): it is
``b (1/f + f/f0^2 - 2/f0)`` for f < f0 and zero beyond, which keeps J and its gradient continuous
(C1) at f0 and leaves the near field (f << f0) as before. Measured on the 20-UAV swap in the
point-mass harness: vortex + cutoff 100 % at their goals in 120 s, no vortex 0 %, no cutoff 50 %;
in JSBSim (uav_swarm.yaml) 100 % with 0 NMAC.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.uav.models import AvoidanceObservation, VelocityCommand
from corridor.vehicles.tracks.agent import TrackedAgent


class PotentialFieldParams(BaseModel):
    """Weights, radii and limits of the potential field (scenario YAML may override any of them)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    period_s: float = Field(0.1, gt=0.0)  # [s] decision period
    max_speed_h_mps: float = Field(10.0, gt=0.0)  # [m/s] horizontal speed limit (norm)
    max_climb_mps: float = Field(3.0, gt=0.0)  # [m/s] climb/descent rate limit
    goal_gain_per_s: float = Field(0.25, gt=0.0)  # [1/s] k of the quadratic goal well
    goal_quadratic_radius_m: float = Field(20.0, gt=0.0)  # [m] d_q, cone beyond it
    uav_weight: float = Field(6000.0, ge=0.0)  # [m^3/s] b: repulsion b/f^2 [m/s] from UAVs
    uav_safety_radius_m: float = Field(45.0, ge=0.0)  # [m] r_safe around other UAVs
    uav_lookahead_s: float = Field(2.5, ge=0.0)  # [s] tau: closing-speed shrinkage of f
    piloted_weight: float = Field(30000.0, ge=0.0)  # [m^3/s] w_m for the piloted aircraft
    piloted_safety_radius_m: float = Field(150.0, ge=0.0)  # [m]
    piloted_lookahead_s: float = Field(6.0, ge=0.0)  # [s]
    eps_m: float = Field(1.0, gt=0.0)  # [m] soft floor of f
    vortex_gain: float = Field(1.0, ge=0.0)  # tangential / radial ratio; 0 disables the remedy
    influence_m: float = Field(400.0, gt=0.0)  # [m] agents farther than this are ignored
    uav_cutoff_m: float | None = Field(15.0, gt=0.0)  # [m] f0: UAV repulsion is zero for f >= f0 (None: 1/f tail)
    piloted_cutoff_m: float | None = Field(None, gt=0.0)  # [m] same for the piloted aircraft


# lowest exponent of the soft floor: deeper inside, exp() would underflow, 1/fc^2 overflow and the
# repulsion turn to inf * 0 = NaN (a 50 m/s aircraft closing head-on within a few lookaheads); the
# floor's value stays about 1e-131 * eps there, so the repulsion stays finite and saturates the command
_FLOOR_EXP_MIN = -300.0


def _soft_floor(f: float, eps: float) -> tuple[float, float]:
    """C1 positive floor of f and its derivative d f_c / d f."""
    if f >= eps:
        return f, 1.0
    e = float(np.exp(max(f / eps - 1.0, _FLOOR_EXP_MIN)))
    return eps * e, e


def _agent_terms(
    x: np.ndarray, v: np.ndarray, other: TrackedAgent, p: PotentialFieldParams
) -> tuple[float, np.ndarray]:
    """Repulsive potential w / f_c and its gradient w.r.t. the ego position x."""
    weight, radius, tau = (
        (p.piloted_weight, p.piloted_safety_radius_m, p.piloted_lookahead_s)
        if other.is_piloted
        else (p.uav_weight, p.uav_safety_radius_m, p.uav_lookahead_s)
    )
    rel = x - other.pos
    d = max(float(np.linalg.norm(rel)), 1e-9)
    unit = rel / d
    v_rel = v - other.vel
    closing = -float(unit @ v_rel)  # [m/s] > 0 when approaching
    grad_f = unit.copy()
    f = d - radius - other.sigma_m
    if closing > 0.0:
        f -= tau * closing
        grad_f += (tau / d) * (v_rel - unit * float(unit @ v_rel))
    fc, dfc = _soft_floor(f, p.eps_m)
    f0 = p.piloted_cutoff_m if other.is_piloted else p.uav_cutoff_m
    if f0 is None:
        return weight / fc, -(weight / fc**2) * dfc * grad_f
    if fc >= f0:
        return 0.0, np.zeros(3)
    # bounded support: w/f + w f/f0^2 - 2 w/f0 is zero with zero slope at f = f0 (C1)
    return weight / fc + weight * fc / f0**2 - 2.0 * weight / f0, -(weight / fc**2 - weight / f0**2) * dfc * grad_f


def _goal_terms(x: np.ndarray, goal: np.ndarray, p: PotentialFieldParams) -> tuple[float, np.ndarray]:
    """Quadratic-near, conic-far goal potential and its gradient."""
    e = x - goal
    r = float(np.linalg.norm(e))
    k, dq = p.goal_gain_per_s, p.goal_quadratic_radius_m
    if r <= dq:
        return k * r**2, 2.0 * k * e
    return 2.0 * k * dq * r - k * dq**2, 2.0 * k * dq * e / r


def potential(obs: AvoidanceObservation, x: np.ndarray, p: PotentialFieldParams) -> float:
    """J at position x (ego velocity taken from the observation); for diagnostics and tests."""
    total = _goal_terms(x, obs.goal, p)[0]
    for other in _relevant(obs, p):
        total += _agent_terms(x, obs.own_vel, other, p)[0]
    return total


def _relevant(obs: AvoidanceObservation, p: PotentialFieldParams) -> list[TrackedAgent]:
    return [o for o in obs.others if np.linalg.norm(o.pos - obs.own_pos) < p.influence_m]


def pair_repulsion(x: np.ndarray, v: np.ndarray, o_pos: np.ndarray, o_vel: np.ndarray, sigma: np.ndarray,
                   piloted: np.ndarray, p: PotentialFieldParams) -> np.ndarray:
    """-grad of each pair's repulsive term at its ego (K, 3) [m/s]: the ego at ``x``, ``v`` (K, 3) and the
    other agent of the pair; agents beyond ``influence_m`` give zero rows.  Shared by the per-UAV
    method (:func:`_agent_gradients`) and the fleet (``potential_field_fleet``)."""
    rel = x - o_pos
    d_raw = np.sqrt(np.einsum("kd,kd->k", rel, rel))
    d = np.maximum(d_raw, 1e-9)
    unit = rel / d[:, None]
    v_rel = v - o_vel
    u_dot_v = np.einsum("kd,kd->k", unit, v_rel)
    closing = -u_dot_v  # [m/s] > 0 when approaching
    weight = np.where(piloted, p.piloted_weight, p.uav_weight)
    radius = np.where(piloted, p.piloted_safety_radius_m, p.uav_safety_radius_m)
    tau = np.where(piloted, p.piloted_lookahead_s, p.uav_lookahead_s)
    approaching = closing > 0.0
    f = d - radius - sigma - np.where(approaching, tau * closing, 0.0)
    grad_f = unit + np.where(approaching, tau / d, 0.0)[:, None] * (v_rel - unit * u_dot_v[:, None])
    soft = f < p.eps_m  # C1 positive floor (see _soft_floor)
    e = np.exp(np.maximum(np.minimum(f, p.eps_m) / p.eps_m - 1.0, _FLOOR_EXP_MIN))
    fc, dfc = np.where(soft, p.eps_m * e, f), np.where(soft, e, 1.0)
    f0 = np.array([np.inf if c is None else c for c in (p.uav_cutoff_m, p.piloted_cutoff_m)])[piloted.astype(int)]
    # bounded support: -(w/fc^2 - w/f0^2) inside f0, zero beyond; 1/f tail when f0 is None (w/inf = 0)
    scale = np.where(fc < f0, -(weight / fc**2 - weight / f0**2) * dfc, 0.0)
    scale = np.where(d_raw < p.influence_m, scale, 0.0)
    return -scale[:, None] * grad_f


def _agent_gradients(obs: AvoidanceObservation, p: PotentialFieldParams) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (K, 3) of every agent's repulsive term at the ego position, all agents at once, and
    each agent's position relative to the ego (K, 3); the same arithmetic as :func:`_agent_terms`
    (agents beyond ``influence_m`` get zero rows)."""
    others = obs.others
    pos = np.array([o.pos for o in others], dtype=float).reshape(-1, 3)
    vel = np.array([o.vel for o in others], dtype=float).reshape(-1, 3)
    sig = np.array([o.sigma_m for o in others], dtype=float)
    piloted = np.array([o.is_piloted for o in others], dtype=bool)
    return -pair_repulsion(obs.own_pos, obs.own_vel, pos, vel, sig, piloted, p), -(obs.own_pos - pos)


def _rotate_ccw(g: np.ndarray) -> np.ndarray:
    """Horizontal part of g rotated +90 degrees about Up; the vertical part dropped."""
    return np.array([-g[1], g[0], 0.0])


def saturate(cmd: np.ndarray, max_speed_h_mps: float, max_climb_mps: float) -> np.ndarray:
    """Clip the horizontal norm and the vertical rate of a velocity command."""
    out = np.array(cmd, dtype=float)
    h = float(np.linalg.norm(out[:2]))
    if h > max_speed_h_mps:
        out[:2] *= max_speed_h_mps / h
    out[2] = np.clip(out[2], -max_climb_mps, max_climb_mps)
    return out


class PotentialFieldAvoidance:
    """Velocity command = saturated -grad J plus the vortex remedy (see the module docstring)."""

    def __init__(self, params: PotentialFieldParams | None = None) -> None:
        self.params = params or PotentialFieldParams()

    @property
    def period(self) -> float:
        return self.params.period_s

    def reset(self, rng: np.random.Generator) -> None:
        """The field is deterministic; rng is accepted for the common controller interface."""
        del rng

    def field(self, obs: AvoidanceObservation) -> tuple[np.ndarray, np.ndarray]:
        """(-grad J, vortex term) at the ego position, both unsaturated [m/s]."""
        p, x = self.params, obs.own_pos
        flow = -_goal_terms(x, obs.goal, p)[1]
        if not obs.others:
            return flow, np.zeros(3)
        grad, ahead_vec = _agent_gradients(obs, p)
        rep = -grad  # (K, 3)
        flow = flow + rep.sum(axis=0)
        ahead = ahead_vec @ (obs.goal - x) > 0.0
        r = rep[ahead].sum(axis=0)
        vortex = p.vortex_gain * _rotate_ccw(r)
        return flow, vortex

    def step(self, obs: AvoidanceObservation) -> VelocityCommand:
        flow, vortex = self.field(obs)
        goal_only = -_goal_terms(obs.own_pos, obs.goal, self.params)[1]
        raw = flow + vortex
        repulsion = float(np.linalg.norm(raw - goal_only))
        cmd = saturate(raw, self.params.max_speed_h_mps, self.params.max_climb_mps)
        avoiding = repulsion > 0.1 * self.params.max_speed_h_mps
        return VelocityCommand(obs.t, cmd, avoiding, {"repulsion_mps": repulsion})
