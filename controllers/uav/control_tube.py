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
Against a piloted aircraft the normal's vertical component takes the side the ego is on now (at or
above the aircraft's tracked altitude: up, else down), not the side of the extrapolated tube centre: a
light aircraft's phugoid (c172x: +-10 m over ~30 s) extrapolated over the horizon put the centre
below a UAV the aircraft was 15 m above, the UAV started to climb, the previous plan then kept the
normals pointing up, and the climbing aircraft passed 11 m under it (uav_encounter, crossing
geometry, aircraft 20-23.5 m above the conflict point; at 24 m and more the UAV descended and
passed 44-46 m away). Any unit normal gives a half-space that excludes the ball, so the guarantee
below does not depend on this choice.
m_j = dt_j * (v_ego_max + |v| + a_max t_j) covers the time between samples: if the constraint holds
at t_j, the true separation over [t_{j-1}, t_j] is at least r0 + r_safe. Hence, when a step's QP is
feasible with zero slack, collision avoidance holds at every time instant of the applied control
period against any intruder manoeuvre with |a| <= a_max (velocity estimate exact, position within
sigma). Recursive feasibility is not guaranteed (a faster intruder can corner the ego): each intruder
gets one slack variable with a large L1 + small L2 penalty, so an infeasible step returns the
least-violating command, and such steps are counted in ``infeasible_steps``.

Nominal. ``u_nom`` flies to the goal (``sat(k (goal - x))`` along its own rollout), turned right by up
to ``deflect_max_deg`` when an intruder sits ahead in the corridor to the goal (``_deflection``). This
right-hand rule is the remedy for the swap through a common centre: with a straight nominal every
QP stays as close as it can to "through the centre" and the swarm jams there (8-UAV swap: 114-118 s
and infeasible steps, vs 88 s and none with it; 20-UAV uav_swarm.yaml in JSBSim: 85 % -> 95 % of the
UAVs at their goals within 120 s). Safety does not depend on it: the tube constraints are unchanged.

QP. minimise  w_track sum_k |u_k - u_nom,k|^2 + w_rate |u_0 - u_last|^2 + w_smooth sum_k |u_k+1 - u_k|^2
+ sum_i (M s_i + s_i^2)  subject to the tube half-spaces, horizontal speed (inscribed octagon), climb
rate, and acceleration bounds. Solved each step with CasADi ``conic`` and qpOASES (an active-set
method: exact vertex solutions, so no constraint is violated by solver tolerance as it could be
with a first-order method such as OSQP; ``solver="osqp"`` is available).

Unconstrained steps. The objective is strictly convex, so when its unconstrained minimiser
``U* = -H^-1 g`` (slacks 0) satisfies every constraint exactly (tube rows with zero slack, speed,
climb and acceleration bounds), it is the QP's unique optimum: the KKT conditions hold with every
multiplier zero except the slacks' bounds (multiplier M > 0). Such steps (free flight, intruders
whose tubes are far from the plan) take U* without calling the solver; ``unconstrained_steps``
counts them. The check has no tolerance, so the tube property above holds for them as for any
zero-slack step.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import io
import math
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stdout
from dataclasses import dataclass

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.controllers.uav.models import (
    AvoidanceObservation,
    PointMassParams,
    VelocityCommand,
    discrete_matrices,
)
from corridor.vehicles.tracks.agent import TrackedAgent

_OCT = float(np.cos(np.pi / 8.0))  # inscribed-octagon factor for the horizontal speed disc
_INF = 1e20
_LIBC = ctypes.CDLL(ctypes.util.find_library("c"))


class ControlTubeParams(BaseModel):
    """Horizon, limits, tube bounds and weights of the control-tube QP."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    period_s: float = Field(0.1, gt=0.0)  # [s] decision period (must be <= step_s)
    step_s: float = Field(0.5, gt=0.0)  # [s] command step of the plan
    n_steps: int = Field(12, ge=1, le=100)  # [steps] horizon = n_steps * step_s (QP size grows with it)
    substeps: int = Field(2, ge=1, le=20)  # constraint instants per command step
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
    deflect_max_deg: float = Field(70.0, ge=0.0, le=90.0)  # [deg] right-hand deflection of the nominal
    deflect_range_m: float = Field(120.0, gt=0.0)  # [m] intruders in the corridor closer than this deflect
    w_track: float = Field(1.0, gt=0.0)
    w_rate: float = Field(2.0, ge=0.0)
    w_smooth: float = Field(0.5, ge=0.0)
    slack_l1: float = Field(1e5, gt=0.0)
    slack_l2: float = Field(10.0, gt=0.0)
    max_intruders: int = Field(8, ge=1, le=64)  # [aircraft] nearest intruders whose tube can reach the ego
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


def _norm(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis, kept as a length-1 axis."""
    return np.sqrt(np.einsum("...d,...d->...", v, v))[..., None]


class _QpStructure:
    """What does not change between steps for one intruder count: Hessian, constant rows and box
    bounds, and the CasADi solver (which keeps qpOASES' working set between calls, i.e. hot starts).

    The solver is called through CasADi's zero-copy ``Function.buffer`` on preallocated numpy arrays:
    converting a dense numpy matrix to a ``DM`` per call cost ~1.5 ms, several times the solve itself.
    """

    def __init__(self, h: np.ndarray, fixed: np.ndarray, lbx: np.ndarray, ubx: np.ndarray, solver: ca.Function):
        self.h, self.fixed, self.lbx, self.ubx, self.solver = h, fixed, lbx, ubx, solver
        with _quiet_stdout():  # a new solver memory prints qpOASES' banner again
            self._buf, self._eval = solver.buffer()
        self._in = {name: np.zeros(solver.nnz_in(i)) for i, name in enumerate(solver.name_in())}
        self._in["h"][:] = h.ravel(order="F")
        self._in["lbx"][:], self._in["ubx"][:] = lbx, ubx
        n_rows, nz = solver.size_in("a")
        self._a_cols = self._in["a"].reshape(nz, n_rows).T  # view: row-major writes, column-major memory
        self.x = np.zeros(solver.nnz_out("x"))
        self._out = [self.x] + [np.zeros(solver.nnz_out(i)) for i in range(1, solver.n_out())]
        for i, name in enumerate(solver.name_in()):
            self._buf.set_arg(i, memoryview(self._in[name]))
        for i, arr in enumerate(self._out):
            self._buf.set_res(i, memoryview(arr))
        self._n_var_rows = n_rows - len(fixed)  # the rows that change per step come first
        self._a_cols[self._n_var_rows :] = fixed  # constant: written once

    def solve(self, g: np.ndarray, a: np.ndarray, lba: np.ndarray, uba: np.ndarray) -> tuple[np.ndarray, bool]:
        """Solve with gradient ``g`` and rows ``a`` (dense, row-major numpy) in [lba, uba]; (z, success)."""
        self._a_cols[...] = a  # CasADi stores dense matrices column by column
        return self.solve_rows(g, None, lba, uba)

    def solve_rows(
        self, g: np.ndarray, rows: np.ndarray | None, lba: np.ndarray, uba: np.ndarray
    ) -> tuple[np.ndarray, bool]:
        """:meth:`solve` when only the leading rows change: ``rows`` replaces them, the constant
        ``fixed`` rows stay where the constructor wrote them (None: no row is replaced)."""
        self._in["g"][:] = g
        if rows is not None and len(rows):
            self._a_cols[: self._n_var_rows] = rows
        self._in["lba"][:], self._in["uba"][:] = lba, uba
        self._eval()
        return self.x.copy(), bool(self._buf.stats()["success"])


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
        a, b = discrete_matrices(p.model, p.step_s)  # nominal rollout on the command grid
        self._ab_axis = (float(a[0, 3]), float(a[3, 3]), float(b[0, 0]), float(b[3, 0]))
        self.n_u, self.n_s = 3 * p.n_steps, p.max_intruders
        self._h_u = self._hessian()
        self._h_u_inv = np.linalg.inv(self._h_u)  # unconstrained minimiser U* = -H^-1 g (see the docstring)
        self._ub_u = np.tile([p.max_speed_h_mps * _OCT, p.max_speed_h_mps * _OCT, p.max_climb_mps], p.n_steps)
        self._fixed = self._fixed_rows()
        self._gam_pos = np.ascontiguousarray(self.pred.gam[:, :3, :])  # (M, 3, n_u)
        self._t_sq = self.pred.t**2  # [s^2]
        m = p.model  # tau a_max per axis: the plan's velocity change per command step [m/s]
        self._accel_bound = np.array([m.max_accel_h_mps2 / np.sqrt(2.0)] * 2 + [m.max_accel_v_mps2]) * m.tau_s
        # what the tube rows depend on besides the per-UAV data: UAVs sharing it are batched
        self._batch_key = (p.step_s, p.n_steps, p.substeps, p.model, p.right_tilt)
        self._qps: dict[int, _QpStructure] = {}  # per number of intruders, built on first use
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
        self.unconstrained_steps = 0
        self.solve_times_s: list[float] = []

    def planned_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_j [s] relative to the last step, predicted ego positions (M, 3) [m]) of the last plan."""
        if self._plan is None:
            raise RuntimeError("no plan yet: call step() first")
        return self.pred.t.copy(), self.pred.states(self._plan_x0, self._plan.ravel())[:, :3]

    # ---- QP structure (built once) -------------------------------------------------------------
    def _hessian(self) -> np.ndarray:
        """Hessian of the command part (tracking, rate and smoothness terms), (n_u, n_u)."""
        p, n = self.params, self.params.n_steps
        eye3 = np.eye(3)
        diff = np.zeros((3 * (n - 1), 3 * n))
        for k in range(n - 1):
            diff[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = -eye3
            diff[3 * k : 3 * k + 3, 3 * k + 3 : 3 * k + 6] = eye3
        first = np.zeros((3, 3 * n))
        first[:, :3] = eye3
        return 2.0 * (p.w_track * np.eye(3 * n) + p.w_rate * first.T @ first + p.w_smooth * diff.T @ diff)

    def _qp(self, k: int) -> _QpStructure:
        """The QP for ``k`` intruders: one slack and M tube rows each. A solver per k keeps each QP as
        small as the situation (the dense active-set cost grows with the rows) and warm-starts it."""
        qp = self._qps.get(k)
        if qp is None:
            p, nz = self.params, self.n_u + k
            h = np.zeros((nz, nz))
            h[: self.n_u, : self.n_u] = self._h_u
            h[self.n_u :, self.n_u :] = 2.0 * p.slack_l2 * np.eye(k)
            fixed = np.zeros((len(self._fixed), nz))
            fixed[:, : self.n_u] = self._fixed
            vh = p.max_speed_h_mps * _OCT
            ub_u = np.tile([vh, vh, p.max_climb_mps], p.n_steps)
            lbx = np.concatenate([-ub_u, np.zeros(k)])
            ubx = np.concatenate([ub_u, np.full(k, _INF)])
            n_rows = k * len(self.pred.t) + len(fixed)
            qp = self._qps[k] = _QpStructure(h, fixed, lbx, ubx, self._build_solver(nz, n_rows))
        return qp

    def _build_solver(self, nz: int, n_rows: int) -> ca.Function:
        h_sp = ca.Sparsity.dense(nz, nz)
        a_sp = ca.Sparsity.dense(n_rows, nz)
        if self.params.solver == "qpoases":
            opts = {"printLevel": "none", "error_on_fail": False, "sparse": False}
        else:
            opts = {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "polish": True},
                    "error_on_fail": False}
        with _quiet_stdout():
            return ca.conic("control_tube", self.params.solver, {"h": h_sp, "a": a_sp}, opts)

    def _fixed_rows(self) -> np.ndarray:
        """Acceleration rows (3n) then speed-octagon rows (2n) on the command part: constant matrices
        (only their bounds move with the state), so they are built once."""
        pr, n = self.pred, self.params.n_steps
        acc = np.zeros((3 * n, self.n_u))
        self._v_free = np.zeros((n, 3, 6))  # x0 -> free velocity at the start of each command step
        for k in range(n):
            j = pr.step_index[k]
            if j >= 0:
                acc[3 * k : 3 * k + 3] = -pr.gam[j, 3:, :]
                self._v_free[k] = pr.phi[j, 3:, :]
            else:
                self._v_free[k, :, 3:] = np.eye(3)
            acc[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] += np.eye(3)
        speed = np.zeros((2 * n, self.n_u))
        for k in range(n):
            speed[2 * k, 3 * k : 3 * k + 2] = [1.0, 1.0]
            speed[2 * k + 1, 3 * k : 3 * k + 2] = [1.0, -1.0]
        lim = np.sqrt(2.0) * self.params.max_speed_h_mps * _OCT
        self._speed_lo, self._speed_hi = np.full(2 * n, -lim), np.full(2 * n, lim)
        return np.vstack([acc, speed])

    # ---- per-step data --------------------------------------------------------------------------
    def _nominal(self, x0: np.ndarray, goal: np.ndarray, deflect_rad: float = 0.0) -> np.ndarray:
        """Goal-seeking command sequence (n_steps, 3) along its own predicted rollout, its horizontal
        part turned right by ``deflect_rad`` (see :meth:`_deflection`)."""
        p = self.params
        a12, a22, b1, b2 = self._ab_axis  # the model is the same decoupled 2-state chain per axis
        k, lim, climb = p.goal_gain_per_s, p.max_speed_h_mps * _OCT, p.max_climb_mps
        c, s = math.cos(deflect_rad), math.sin(deflect_rad)
        gx, gy, gz = goal.tolist()
        px, py, pz, vx, vy, vz = x0.tolist()
        out = []
        for _ in range(p.n_steps):  # plain floats: 12 tiny steps, where numpy's call overhead dominated
            ux, uy, uz = k * (gx - px), k * (gy - py), k * (gz - pz)
            h = math.sqrt(ux * ux + uy * uy)
            if h > lim:
                ux, uy = ux * (lim / h), uy * (lim / h)
            uz = min(max(uz, -climb), climb)
            if deflect_rad:
                ux, uy = c * ux + s * uy, -s * ux + c * uy
            out.append((ux, uy, uz))
            px, py, pz = px + a12 * vx + b1 * ux, py + a12 * vy + b1 * uy, pz + a12 * vz + b1 * uz
            vx, vy, vz = a22 * vx + b2 * ux, a22 * vy + b2 * uy, a22 * vz + b2 * uz
        return np.array(out)

    def _deflection(
        self, obs: AvoidanceObservation, intruders: list[TrackedAgent], agents: _Agents | None = None
    ) -> float:
        """Right-hand rule on the nominal [rad]: the closer an intruder sits in the corridor to the goal
        (ahead, nearer than the goal, laterally within its tube radius), the more the nominal turns
        right, up to ``deflect_max_deg``. Without it the nominal of every UAV of a swap points at the
        common centre and the QP, which stays as close to the nominal as the tubes allow, jams there;
        with it the UAVs circulate counter-clockwise around the conflict (a roundabout) and leave it
        towards their goals, and head-on pairs pass left side to left side (ICAO Annex 2, 3.2.2.2)."""
        p = self.params
        to_goal = (obs.goal - obs.own_pos)[:2]
        d_goal = float(np.hypot(*to_goal))
        if p.deflect_max_deg <= 0.0 or d_goal < 1e-6 or not intruders:
            return 0.0
        e = to_goal / d_goal
        agents = agents if agents is not None else self._agents(intruders)
        r = agents.pos[:, :2] - obs.own_pos[:2]  # (K, 2)
        ahead = r[:, 0] * e[0] + r[:, 1] * e[1]
        lateral = np.abs(e[0] * r[:, 1] - e[1] * r[:, 0])
        dist = np.hypot(r[:, 0], r[:, 1])
        half_width = agents.radius + agents.sigma
        near = (ahead > 0.0) & (dist < min(d_goal, p.deflect_range_m)) & (lateral < half_width)
        w = max(0.0, float(np.max(1.0 - dist[near] / p.deflect_range_m, initial=0.0)))
        return math.radians(p.deflect_max_deg) * min(1.0, 2.0 * w)

    def _saturate(self, u: np.ndarray) -> np.ndarray:
        p, out = self.params, np.array(u, dtype=float)
        lim = p.max_speed_h_mps * _OCT
        ux, uy, uz = out.tolist()
        h = math.sqrt(ux * ux + uy * uy)
        if h > lim:
            out[:2] *= lim / h
        out[2] = min(max(uz, -p.max_climb_mps), p.max_climb_mps)
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
        vx, vy, vz = (float(x) for x in v0)
        vh = max(math.sqrt(vx * vx + vy * vy), p.max_speed_h_mps)
        return float(np.hypot(vh, max(abs(vz), p.max_climb_mps)))

    def _agents(self, others: tuple[TrackedAgent, ...] | list[TrackedAgent]) -> _Agents:
        """Struct of arrays of tracked agents with their tube class (a_max and radius, see ``_tube``)."""
        p = self.params
        piloted = np.array([o.is_piloted for o in others], dtype=bool)
        return _Agents(
            pos=np.array([o.pos for o in others], dtype=float).reshape(-1, 3),
            vel=np.array([o.vel for o in others], dtype=float).reshape(-1, 3),
            sigma=np.array([o.sigma_m for o in others], dtype=float),
            acc=np.where(piloted, p.piloted_accel_mps2, p.uav_accel_mps2),
            radius=np.where(piloted, p.piloted_size_m + p.piloted_safety_radius_m, p.uav_size_m + p.uav_safety_radius_m),
            piloted=piloted,
        )

    def _relevant(self, obs: AvoidanceObservation, v_ego: float) -> list[TrackedAgent]:
        """Nearest intruders whose tube can reach the ego within the horizon (exact reachability)."""
        if not obs.others:
            return []
        return [obs.others[i] for i in self._relevant_index(obs, self._agents(obs.others), v_ego)]

    def _relevant_index(self, obs: AvoidanceObservation, agents: _Agents, v_ego: float) -> np.ndarray:
        """Indices (nearest first) of :meth:`_relevant` into ``obs.others``."""
        horizon = self.params.n_steps * self.params.step_s
        speed = np.sqrt(np.einsum("kd,kd->k", agents.vel, agents.vel))
        rel = agents.pos - obs.own_pos
        dist = np.sqrt(np.einsum("kd,kd->k", rel, rel))
        reach = agents.radius + agents.sigma + 0.5 * agents.acc * horizon**2 + (v_ego + speed) * horizon
        keep = np.flatnonzero(dist < reach + 10.0)
        return keep[np.argsort(dist[keep], kind="stable")][: self.params.max_intruders]

    def _normals(
        self, d: np.ndarray, radius: np.ndarray, v_rel: np.ndarray, fallback: np.ndarray
    ) -> np.ndarray:
        """Unit separating normals (..., M, 3); tilted to the ego's right where the reference is inside."""
        right = np.stack([v_rel[..., 1], -v_rel[..., 0], np.zeros(v_rel.shape[:-1])], axis=-1)
        rn = _norm(right)
        right = np.where(rn > 0.5, right / np.maximum(rn, 1e-12), fallback)
        dist = _norm(d)
        inside = np.maximum(radius[..., None] - dist, 0.0)
        closing = np.einsum("...d,...d->...", d, v_rel)[..., None] < 0.0
        n = d + (2.0 * inside + self.params.right_tilt * dist * closing) * right
        nn = _norm(n)
        return np.where(nn > 1e-9, n / np.maximum(nn, 1e-12), np.array([1.0, 0.0, 0.0]))

    def _collision_rows(
        self, obs: AvoidanceObservation, x0: np.ndarray, intruders: list[TrackedAgent], u_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Half-space rows (K*M, n_u + K) and their lower bounds, all intruders at once."""
        return _collision_rows_many([_Pending(self, obs, x0, intruders, u_ref)])[0]

    def _accel_bounds(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """|u_k - v(t_k)| <= tau a_max per axis, widened only if the current velocity is off-limits."""
        bound = np.maximum(self._accel_bound, np.abs(x0[3:] - self._saturate(x0[3:] * 0.99)) + 1e-6)
        offset = self._v_free @ x0  # (n_steps, 3)
        return (offset - bound).ravel(), (offset + bound).ravel()

    def _gradient(self, nominal: np.ndarray, u_last: np.ndarray, k: int) -> np.ndarray:
        p = self.params
        g = np.zeros(self.n_u + k)
        g[: self.n_u] = -2.0 * p.w_track * nominal.ravel()
        g[:3] -= 2.0 * p.w_rate * u_last
        g[self.n_u :] = p.slack_l1
        return g

    # ---- the step -------------------------------------------------------------------------------
    def step(self, obs: AvoidanceObservation) -> VelocityCommand:
        return step_many([self], [obs])[0]

    def _prepare(self, obs: AvoidanceObservation) -> _Pending:
        """Everything of a step before the tube rows: intruders, nominal, linearisation reference."""
        x0 = np.concatenate([obs.own_pos, obs.own_vel]).astype(float)
        intruders: list[TrackedAgent] = []
        agents = None
        if obs.others:
            everyone = self._agents(obs.others)
            keep = self._relevant_index(obs, everyone, self._ego_speed_bound(x0[3:]))
            intruders = [obs.others[i] for i in keep]
            agents = everyone.take(keep)
        nominal = self._nominal(x0, obs.goal, self._deflection(obs, intruders, agents))
        u_ref = self._reference(obs, nominal) if intruders else nominal
        return _Pending(self, obs, x0, intruders, u_ref, nominal, agents)

    def _solve(self, s: _Pending, c_rows: np.ndarray, c_lo: np.ndarray) -> VelocityCommand:
        """The QP of a prepared step with its tube rows, then the plan bookkeeping."""
        obs, x0, nominal, k = s.obs, s.x0, s.nominal, len(s.intruders)
        u_last = self._last_cmd if self._last_cmd is not None else self._saturate(obs.own_vel)
        a_lo, a_hi = self._accel_bounds(x0)
        g = self._gradient(nominal, u_last, k)
        z = self._unconstrained(g, c_rows, c_lo, a_lo, a_hi)
        if z is not None:
            self.unconstrained_steps += 1
            ok = True
        else:
            qp = self._qp(k)
            lba = np.concatenate([c_lo, a_lo, self._speed_lo])
            uba = np.concatenate([np.full(len(c_lo), _INF), a_hi, self._speed_hi])
            t0 = time.perf_counter()
            z, ok = qp.solve_rows(g, c_rows if k else None, lba, uba)
            self.solve_times_s.append(time.perf_counter() - t0)
        active = k > 0 and float(np.min(c_rows @ z - c_lo)) < 1e-3
        return self._finish(obs, z, ok, nominal, k, active)

    def _unconstrained(
        self, g: np.ndarray, c_rows: np.ndarray, c_lo: np.ndarray, a_lo: np.ndarray, a_hi: np.ndarray
    ) -> np.ndarray | None:
        """The QP's optimum when its unconstrained minimiser (slacks 0) satisfies every constraint
        exactly, else None (see the module docstring)."""
        u = -(self._h_u_inv @ g[: self.n_u])
        k = len(g) - self.n_u
        if k and np.any(c_rows[:, : self.n_u] @ u < c_lo):  # first: near intruders mostly bind
            return None
        if np.any(np.abs(u) > self._ub_u):
            return None
        n_acc = len(a_lo)
        r = self._fixed @ u
        if (np.any(r[:n_acc] < a_lo) or np.any(r[:n_acc] > a_hi)
                or np.any(r[n_acc:] < self._speed_lo) or np.any(r[n_acc:] > self._speed_hi)):
            return None
        return np.concatenate([u, np.zeros(k)])

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


@dataclass(frozen=True)
class _Agents:
    """Tracked agents as arrays: positions, velocities, uncertainty radii and tube class."""

    pos: np.ndarray  # (K, 3) [m]
    vel: np.ndarray  # (K, 3) [m/s]
    sigma: np.ndarray  # (K,) [m]
    acc: np.ndarray  # (K,) [m/s^2] a_max of the agent's class
    radius: np.ndarray  # (K,) [m] size + safety radius of the agent's class
    piloted: np.ndarray  # (K,) bool: piloted aircraft (vertical side from the current altitudes)

    def take(self, idx: np.ndarray) -> _Agents:
        return _Agents(self.pos[idx], self.vel[idx], self.sigma[idx], self.acc[idx], self.radius[idx],
                       self.piloted[idx])


@dataclass
class _Pending:
    """One UAV's step between preparation and solve (see :func:`step_many`)."""

    method: ControlTubeAvoidance
    obs: AvoidanceObservation
    x0: np.ndarray  # [m, m/s] ego state
    intruders: list[TrackedAgent]
    u_ref: np.ndarray  # (n_steps, 3) [m/s] linearisation reference of the tube normals
    nominal: np.ndarray | None = None  # (n_steps, 3) [m/s]
    agents: _Agents | None = None  # the intruders as arrays (built on demand)

    def intruder_arrays(self) -> _Agents:
        if self.agents is None:
            self.agents = self.method._agents(self.intruders)
        return self.agents


def step_many(methods: list[ControlTubeAvoidance], observations: list[AvoidanceObservation]) -> list[VelocityCommand]:
    """``methods[i].step(observations[i])`` for a fleet, each UAV with its own plan and QP; the tube
    rows of every UAV's intruders are built in one vectorised pass (:func:`_collision_rows_many`),
    which cost more than the QP solve itself when built UAV by UAV (numpy's per-call overhead)."""
    pending = [m._prepare(o) for m, o in zip(methods, observations, strict=True)]
    with_rows = [s for s in pending if s.intruders]
    rows = dict(zip(map(id, with_rows), _collision_rows_many(with_rows), strict=True))
    empty = (np.zeros((0, 0)), np.zeros(0))
    return [s.method._solve(s, *rows.get(id(s), empty)) for s in pending]


def _collision_rows_many(items: list[_Pending]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Tube half-space rows and lower bounds of several UAVs' steps (every intruder of every item at
    once); per item the same element-wise arithmetic as one UAV alone. Items whose prediction or
    normal parameters differ from the first item's are built in their own pass."""
    if not items:
        return []
    first = items[0].method
    same = [s for s in items if s.method._batch_key == first._batch_key]
    if len(same) < len(items):
        rest = [s for s in items if s.method._batch_key != first._batch_key]
        done = dict(zip(map(id, same), _collision_rows_many(same), strict=True))
        done.update(zip(map(id, rest), _collision_rows_many(rest), strict=True))
        return [done[id(s)] for s in items]
    pr, n_u = first.pred, first.n_u
    m = len(pr.t)
    counts = [len(s.intruders) for s in items]
    owner = np.repeat(np.arange(len(items)), counts)
    # per item: reference rollout, ego speed bound, right-hand fallback, free (command-less) positions
    ref = np.array([pr.states(s.x0, s.u_ref.ravel()) for s in items])[owner]  # (KT, M, 6)
    v_ego = np.array([s.method._ego_speed_bound(s.x0[3:]) for s in items])[owner][:, None]
    fallback = np.array([_fallback(s.obs) for s in items])[owner][:, None, :]
    free = np.array([pr.phi[:, :3, :] @ s.x0 for s in items])[owner]  # (KT, M, 3)
    # per intruder (KT = all intruders of all items)
    agents = [s.intruder_arrays() for s in items]
    acc = np.concatenate([a.acc for a in agents])[:, None]
    r = np.concatenate([a.radius for a in agents])[:, None]
    sigma = np.concatenate([a.sigma for a in agents])[:, None]
    pos = np.concatenate([a.pos for a in agents])
    vel = np.concatenate([a.vel for a in agents])
    centre = pos[:, None, :] + pr.t[None, :, None] * vel[:, None, :]  # (KT, M, 3)
    radius = r + sigma + 0.5 * acc * first._t_sq  # (KT, M)
    margin = pr.dt * (v_ego + np.sqrt(np.einsum("kd,kd->k", vel, vel))[:, None] + acc * pr.t)
    bound = radius + margin
    d = ref[:, :, :3] - centre
    piloted = np.concatenate([a.piloted for a in agents])
    if piloted.any():  # vertical side of a piloted intruder: from the current altitudes (docstring)
        above = np.array([s.x0[2] for s in items])[owner] >= pos[:, 2]
        side = np.where(above, 1.0, -1.0)[:, None]
        d[:, :, 2] = np.where(piloted[:, None], side * np.abs(d[:, :, 2]), d[:, :, 2])
    n = first._normals(d, bound, ref[:, :, 3:] - vel[:, None, :], fallback)
    coef = np.einsum("kmd,mdc->kmc", n, first._gam_pos)  # (KT, M, n_u)
    lower = bound + np.einsum("kmd,kmd->km", n, centre - free)
    out, start = [], 0
    for k in counts:
        rows = np.zeros((k, m, n_u + k))
        rows[:, :, :n_u] = coef[start : start + k]
        rows[np.arange(k), :, n_u + np.arange(k)] = 1.0
        out.append((rows.reshape(-1, n_u + k), lower[start : start + k].ravel()))
        start += k
    return out


def _fallback(obs: AvoidanceObservation) -> np.ndarray:
    """Unit vector to the right of the goal direction (normal tilt when the relative velocity is 0)."""
    to_goal = obs.goal - obs.own_pos
    return np.array([to_goal[1], -to_goal[0], 0.0]) / max(np.linalg.norm(to_goal[:2]), 1e-9)
