"""Control-tube collision avoidance for UAVs: a receding-horizon QP outside the intruders' reachable tubes.

Intruder tube. From an intruder's tracked position p, velocity v, position uncertainty sigma and an
acceleration bound a_max, every position it can reach at time t lies in the ball
``B(p + v t, sigma + 1/2 a_max t^2)``; adding the intruder's size r0 and the ego's safety radius
r_safe gives the ball the ego must stay out of.

Ego plan. The ego's velocity command is piecewise constant over N steps of ``step_s`` (default
12 x 0.5 s = 6 s). Its positions at the finer instants t_j = j * step_s / substeps are affine in the
command sequence U through the exact discretisation of the first-order velocity model in
``uav_models`` (the plan also bounds |u_k - v(t_k)| <= tau * a_max per axis, so the model's
acceleration saturation never becomes active and the prediction is exact).

Constraints. "Outside a ball" is non-convex; each one is replaced by a half-space
``n . (p_j(U) - c_j) >= R_j + m_j``, n the unit direction from the tube centre to a reference ego
position (the previous plan, shifted; on the first step the nominal plan). A half-space that
excludes the ball is a subset of the ball's complement, so every feasible plan is outside every tube.
If the reference is itself inside the ball (a head-on nominal) the normal is tilted to the ego's
right (relative to the relative velocity), so two UAVs running this controller both turn right.
m_j = dt_j * (v_ego_max + |v| + a_max t_j) covers the time between samples: if the constraint holds
at t_j, the true separation over [t_{j-1}, t_j] is at least r0 + r_safe. Hence, when a step's QP is
feasible with zero slack, collision avoidance holds at every time instant of the applied control
period against any intruder manoeuvre with |a| <= a_max (velocity estimate exact, position within
sigma). Recursive feasibility is not guaranteed (a faster intruder can corner the ego): each intruder
gets one slack variable with a large L1 + small L2 penalty, so an infeasible step returns the
least-violating command, and such steps are counted in ``infeasible_steps``.

QP. minimise  w_track sum_k |u_k - u_nom,k|^2 + w_rate |u_0 - u_last|^2 + w_smooth sum_k |u_k+1 - u_k|^2
+ sum_i (M s_i + s_i^2)  subject to the tube half-spaces, horizontal speed (inscribed octagon), climb
rate, and acceleration bounds. Solved each step with CasADi ``conic`` and qpOASES (an active-set
method: exact vertex solutions, so no constraint is violated by solver tolerance as it could be
with a first-order method such as OSQP; ``solver="osqp"`` is available).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import io
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stdout

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.controllers.uav_models import (
    AvoidanceObservation,
    PointMassParams,
    TrackedAgent,
    VelocityCommand,
    discrete_matrices,
)

_OCT = float(np.cos(np.pi / 8.0))  # inscribed-octagon factor for the horizontal speed disc
_INF = 1e20
_LIBC = ctypes.CDLL(ctypes.util.find_library("c"))


class ControlTubeParams(BaseModel):
    """Horizon, limits, tube bounds and weights of the control-tube QP."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    period_s: float = Field(0.1, gt=0.0)  # [s] decision period (must be <= step_s)
    step_s: float = Field(0.5, gt=0.0)  # [s] command step of the plan
    n_steps: int = Field(12, ge=1)  # horizon = n_steps * step_s
    substeps: int = Field(2, ge=1)  # constraint instants per command step
    max_speed_h_mps: float = Field(10.0, gt=0.0)  # [m/s]
    max_climb_mps: float = Field(3.0, gt=0.0)  # [m/s]
    model: PointMassParams = PointMassParams()  # ego velocity-loop model
    goal_gain_per_s: float = Field(0.5, gt=0.0)  # [1/s] nominal command sat(k (goal - x))
    uav_accel_mps2: float = Field(2.0, ge=0.0)  # [m/s^2] a_max assumed for other UAVs
    uav_size_m: float = Field(0.5, ge=0.0)  # [m] r0 of other UAVs
    uav_safety_radius_m: float = Field(35.0, ge=0.0)  # [m] > NMAC 30.5 m (100 ft)
    piloted_accel_mps2: float = Field(3.0, ge=0.0)  # [m/s^2] ~0.3 g manoeuvre of a light aircraft
    piloted_size_m: float = Field(6.0, ge=0.0)  # [m] half span of a c172
    piloted_safety_radius_m: float = Field(150.0, ge=0.0)  # [m] UAVs give way with a wide berth
    right_tilt: float = Field(0.5, ge=0.0)  # tan of the right tilt of normals of closing intruders
    w_track: float = Field(1.0, gt=0.0)
    w_rate: float = Field(2.0, ge=0.0)
    w_smooth: float = Field(0.5, ge=0.0)
    slack_l1: float = Field(1e5, gt=0.0)
    slack_l2: float = Field(10.0, gt=0.0)
    max_intruders: int = Field(8, ge=1)  # nearest intruders whose tube can reach the ego
    infeasible_tol_m: float = Field(1e-3, gt=0.0)  # slack above this counts as infeasible
    solver: str = Field("qpoases", pattern="^(qpoases|osqp)$")

    @model_validator(mode="after")
    def _period_within_first_step(self) -> ControlTubeParams:
        """The applied command is the plan's first one only while it is held at most step_s."""
        if self.period_s > self.step_s + 1e-12:
            raise ValueError(f"period_s ({self.period_s}) must be <= step_s ({self.step_s})")
        return self


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence stdout (qpOASES prints its licence banner whenever a solver is built)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null, redirect_stdout(io.StringIO()):
            os.dup2(null.fileno(), 1)  # printf from C
            yield  # CasADi forwards its own messages to Python's sys.stdout: redirected above
            _LIBC.fflush(None)  # C stdio is block-buffered when stdout is not a terminal
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class _Prediction:
    """Affine maps x(t_j) = Phi_j x0 + Gam_j U at the constraint instants t_j, j = 1..M."""

    def __init__(self, p: ControlTubeParams) -> None:
        dt = p.step_s / p.substeps
        a, b = discrete_matrices(p.model, dt)
        m, n3 = p.n_steps * p.substeps, 3 * p.n_steps
        self.t = dt * np.arange(1, m + 1)  # [s]
        self.dt = dt
        self.phi = np.zeros((m, 6, 6))
        self.gam = np.zeros((m, 6, n3))
        phi, gam = np.eye(6), np.zeros((6, n3))
        for j in range(m):
            k = j // p.substeps
            phi, gam = a @ phi, a @ gam
            gam[:, 3 * k : 3 * k + 3] += b
            self.phi[j], self.gam[j] = phi, gam
        self.step_index = np.arange(0, m, p.substeps) - 1  # sample ending just before step k (-1: x0)

    def states(self, x0: np.ndarray, u_flat: np.ndarray) -> np.ndarray:
        """Predicted states (M, 6) for a flat command sequence."""
        return self.phi @ x0 + self.gam @ u_flat


class ControlTubeAvoidance:
    """Receding-horizon QP keeping the ego's predicted positions outside every intruder tube."""

    def __init__(self, params: ControlTubeParams | None = None) -> None:
        self.params = p = params or ControlTubeParams()
        self.pred = _Prediction(p)
        self._ab = discrete_matrices(p.model, p.step_s)  # nominal rollout on the command grid
        self.n_u, self.n_s = 3 * p.n_steps, p.max_intruders
        self.n_rows = p.max_intruders * len(self.pred.t) + 3 * p.n_steps + 2 * p.n_steps
        self._h = self._hessian()
        self._solver = self._build_solver()
        self.reset(np.random.default_rng(0))

    @property
    def period(self) -> float:
        return self.params.period_s

    def reset(self, rng: np.random.Generator) -> None:
        """Forget the previous plan and the counters; the QP is deterministic, rng is unused."""
        del rng
        self._plan: np.ndarray | None = None  # (n_steps, 3) [m/s]
        self._plan_t = 0.0
        self._plan_x0 = np.zeros(6)
        self._last_cmd: np.ndarray | None = None
        self.steps = 0
        self.infeasible_steps = 0
        self.solver_failures = 0
        self.solve_times_s: list[float] = []

    def planned_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_j [s] relative to the last step, predicted ego positions (M, 3) [m]) of the last plan."""
        if self._plan is None:
            raise RuntimeError("no plan yet: call step() first")
        return self.pred.t.copy(), self.pred.states(self._plan_x0, self._plan.ravel())[:, :3]

    # ---- QP structure (built once) -------------------------------------------------------------
    def _hessian(self) -> np.ndarray:
        p, n = self.params, self.params.n_steps
        eye3 = np.eye(3)
        diff = np.zeros((3 * (n - 1), 3 * n))
        for k in range(n - 1):
            diff[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = -eye3
            diff[3 * k : 3 * k + 3, 3 * k + 3 : 3 * k + 6] = eye3
        first = np.zeros((3, 3 * n))
        first[:, :3] = eye3
        h_u = 2.0 * (p.w_track * np.eye(3 * n) + p.w_rate * first.T @ first + p.w_smooth * diff.T @ diff)
        h = np.zeros((self.n_u + self.n_s, self.n_u + self.n_s))
        h[: self.n_u, : self.n_u] = h_u
        h[self.n_u :, self.n_u :] = 2.0 * p.slack_l2 * np.eye(self.n_s)
        return h

    def _build_solver(self) -> ca.Function:
        nz = self.n_u + self.n_s
        h_sp = ca.Sparsity.dense(nz, nz)
        a_sp = ca.Sparsity.dense(self.n_rows, nz)
        if self.params.solver == "qpoases":
            opts = {"printLevel": "none", "error_on_fail": False, "sparse": False}
        else:
            opts = {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "polish": True},
                    "error_on_fail": False}
        with _quiet_stdout():
            return ca.conic("control_tube", self.params.solver, {"h": h_sp, "a": a_sp}, opts)

    # ---- per-step data --------------------------------------------------------------------------
    def _nominal(self, x0: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Goal-seeking command sequence (n_steps, 3) along its own predicted rollout."""
        p = self.params
        a, b = self._ab
        x, out = x0.copy(), np.zeros((p.n_steps, 3))
        for k in range(p.n_steps):
            out[k] = self._saturate(p.goal_gain_per_s * (goal - x[:3]))
            x = a @ x + b @ out[k]
        return out

    def _saturate(self, u: np.ndarray) -> np.ndarray:
        p, out = self.params, np.array(u, dtype=float)
        lim = p.max_speed_h_mps * _OCT
        h = float(np.linalg.norm(out[:2]))
        if h > lim:
            out[:2] *= lim / h
        out[2] = np.clip(out[2], -p.max_climb_mps, p.max_climb_mps)
        return out

    def _reference(self, obs: AvoidanceObservation, nominal: np.ndarray) -> np.ndarray:
        """Command sequence used to linearise: the previous plan shifted by the elapsed time."""
        if self._plan is None:
            return nominal
        p = self.params
        shift = (obs.t - self._plan_t) / p.step_s
        idx = np.minimum(np.floor(shift + np.arange(p.n_steps) + 1e-9).astype(int), p.n_steps - 1)
        return self._plan[idx]

    def _tube(self, other: TrackedAgent) -> tuple[float, float]:
        """(a_max, radius at t=0 without sigma) for this intruder class."""
        p = self.params
        if other.is_piloted:
            return p.piloted_accel_mps2, p.piloted_size_m + p.piloted_safety_radius_m
        return p.uav_accel_mps2, p.uav_size_m + p.uav_safety_radius_m

    def _ego_speed_bound(self, v0: np.ndarray) -> float:
        p = self.params
        vh = max(float(np.linalg.norm(v0[:2])), p.max_speed_h_mps)
        vz = max(abs(float(v0[2])), p.max_climb_mps)
        return float(np.hypot(vh, vz))

    def _relevant(self, obs: AvoidanceObservation, v_ego: float) -> list[TrackedAgent]:
        """Nearest intruders whose tube can reach the ego within the horizon (exact reachability)."""
        horizon = self.params.n_steps * self.params.step_s
        keep = []
        for o in obs.others:
            acc, r = self._tube(o)
            reach = r + o.sigma_m + 0.5 * acc * horizon**2 + (v_ego + np.linalg.norm(o.vel)) * horizon
            dist = float(np.linalg.norm(o.pos - obs.own_pos))
            if dist < reach + 10.0:
                keep.append((dist, o))
        keep.sort(key=lambda e: e[0])
        return [o for _, o in keep[: self.params.max_intruders]]

    def _normals(
        self, d: np.ndarray, radius: np.ndarray, v_rel: np.ndarray, fallback: np.ndarray
    ) -> np.ndarray:
        """Unit separating normals (M, 3); tilted to the ego's right where the reference is inside."""
        right = np.stack([v_rel[:, 1], -v_rel[:, 0], np.zeros(len(v_rel))], axis=1)
        rn = np.linalg.norm(right, axis=1, keepdims=True)
        right = np.where(rn > 0.5, right / np.maximum(rn, 1e-12), fallback)
        dist = np.linalg.norm(d, axis=1, keepdims=True)
        inside = np.maximum(radius[:, None] - dist, 0.0)
        closing = np.einsum("md,md->m", d, v_rel)[:, None] < 0.0
        n = d + (2.0 * inside + self.params.right_tilt * dist * closing) * right
        nn = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(nn > 1e-9, n / np.maximum(nn, 1e-12), np.array([1.0, 0.0, 0.0]))

    def _collision_rows(
        self, obs: AvoidanceObservation, x0: np.ndarray, intruders: list[TrackedAgent], u_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Half-space rows (K*M, n_u + n_s) and their lower bounds."""
        pr = self.pred
        m = len(pr.t)
        rows = np.zeros((self.n_s, m, self.n_u + self.n_s))
        lower = np.full((self.n_s, m), -_INF)
        ref = pr.states(x0, u_ref.ravel())
        v_ego = self._ego_speed_bound(x0[3:])
        to_goal = obs.goal - obs.own_pos
        fallback = np.array([to_goal[1], -to_goal[0], 0.0]) / max(np.linalg.norm(to_goal[:2]), 1e-9)
        for i, o in enumerate(intruders):
            acc, r = self._tube(o)
            centre = o.pos + np.outer(pr.t, o.vel)
            radius = r + o.sigma_m + 0.5 * acc * pr.t**2
            margin = pr.dt * (v_ego + float(np.linalg.norm(o.vel)) + acc * pr.t)
            n = self._normals(ref[:, :3] - centre, radius + margin, ref[:, 3:] - o.vel, fallback)
            rows[i, :, : self.n_u] = np.einsum("md,mdc->mc", n, pr.gam[:, :3, :])
            rows[i, :, self.n_u + i] = 1.0
            lower[i] = radius + margin + np.einsum("md,md->m", n, centre - pr.phi[:, :3, :] @ x0)
        return rows.reshape(-1, self.n_u + self.n_s), lower.ravel()

    def _accel_rows(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """|u_k - v(t_k)| <= tau a_max per axis, widened only if the current velocity is off-limits."""
        p, pr, n = self.params, self.pred, self.params.n_steps
        tau = p.model.tau_s
        bound = np.array([p.model.max_accel_h_mps2 / np.sqrt(2.0)] * 2 + [p.model.max_accel_v_mps2]) * tau
        bound = np.maximum(bound, np.abs(x0[3:] - self._saturate(x0[3:] * 0.99)) + 1e-6)
        rows = np.zeros((3 * n, self.n_u + self.n_s))
        offset = np.zeros(3 * n)
        for k in range(n):
            j = pr.step_index[k]
            gam_v = pr.gam[j, 3:, :] if j >= 0 else np.zeros((3, self.n_u))
            v_free = pr.phi[j, 3:, :] @ x0 if j >= 0 else x0[3:]
            rows[3 * k : 3 * k + 3, : self.n_u] = -gam_v
            rows[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] += np.eye(3)
            offset[3 * k : 3 * k + 3] = v_free
        lo, hi = offset - np.tile(bound, n), offset + np.tile(bound, n)
        return rows, lo, hi

    def _speed_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Diagonal faces |u_x +- u_y| <= sqrt(2) v cos(pi/8) of the inscribed octagon."""
        n = self.params.n_steps
        rows = np.zeros((2 * n, self.n_u + self.n_s))
        for k in range(n):
            rows[2 * k, 3 * k : 3 * k + 2] = [1.0, 1.0]
            rows[2 * k + 1, 3 * k : 3 * k + 2] = [1.0, -1.0]
        lim = np.sqrt(2.0) * self.params.max_speed_h_mps * _OCT
        return rows, np.full(2 * n, -lim), np.full(2 * n, lim)

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        vh = p.max_speed_h_mps * _OCT
        ub_u = np.tile([vh, vh, p.max_climb_mps], p.n_steps)
        lbx = np.concatenate([-ub_u, np.zeros(self.n_s)])
        ubx = np.concatenate([ub_u, np.full(self.n_s, _INF)])
        return lbx, ubx

    def _gradient(self, nominal: np.ndarray, u_last: np.ndarray) -> np.ndarray:
        p = self.params
        g = np.zeros(self.n_u + self.n_s)
        g[: self.n_u] = -2.0 * p.w_track * nominal.ravel()
        g[:3] -= 2.0 * p.w_rate * u_last
        g[self.n_u :] = p.slack_l1
        return g

    # ---- the step -------------------------------------------------------------------------------
    def step(self, obs: AvoidanceObservation) -> VelocityCommand:
        x0 = np.concatenate([obs.own_pos, obs.own_vel]).astype(float)
        nominal = self._nominal(x0, obs.goal)
        u_last = self._last_cmd if self._last_cmd is not None else self._saturate(obs.own_vel)
        intruders = self._relevant(obs, self._ego_speed_bound(x0[3:]))
        c_rows, c_lo = self._collision_rows(obs, x0, intruders, self._reference(obs, nominal))
        a_rows, a_lo, a_hi = self._accel_rows(x0)
        s_rows, s_lo, s_hi = self._speed_rows()
        amat = np.vstack([c_rows, a_rows, s_rows])
        lba = np.concatenate([c_lo, a_lo, s_lo])
        uba = np.concatenate([np.full(len(c_lo), _INF), a_hi, s_hi])
        lbx, ubx = self._bounds()
        t0 = time.perf_counter()
        sol = self._solver(h=self._h, g=self._gradient(nominal, u_last), a=amat, lba=lba, uba=uba,
                           lbx=lbx, ubx=ubx)
        self.solve_times_s.append(time.perf_counter() - t0)
        ok = bool(self._solver.stats()["success"])
        z = np.asarray(sol["x"]).ravel()
        active = len(intruders) > 0 and float(np.min(c_rows @ z - c_lo)) < 1e-3
        return self._finish(obs, z, ok, nominal, len(intruders), active)

    def _finish(
        self,
        obs: AvoidanceObservation,
        z: np.ndarray,
        ok: bool,
        nominal: np.ndarray,
        n_intruders: int,
        active: bool,
    ) -> VelocityCommand:
        """Store the plan, update counters and wrap the first command."""
        p = self.params
        self.steps += 1
        if not ok or not np.all(np.isfinite(z)):
            self.solver_failures += 1
            plan = self._reference(obs, nominal) if self._plan is not None else nominal
            slack = float("nan")
        else:
            plan = z[: self.n_u].reshape(p.n_steps, 3)
            slack = float(z[self.n_u :].max()) if n_intruders else 0.0
            self.infeasible_steps += int(slack > p.infeasible_tol_m)
        self._plan, self._plan_t = plan.copy(), obs.t
        self._plan_x0 = np.concatenate([obs.own_pos, obs.own_vel]).astype(float)
        self._last_cmd = plan[0].copy()
        return VelocityCommand(obs.t, plan[0].copy(), active,
                               {"slack_m": slack, "n_intruders": float(n_intruders)})
