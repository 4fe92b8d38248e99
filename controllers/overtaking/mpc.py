"""The overtaking MPC: a kinematic-bicycle NLP whose constraints are the overtaking STL specification,
encoded by smooth robustness and solved by IPOPT (CasADi ``nlpsol``, built once, warm-started).

Road frame (the lead maps SUMO coordinates onto it): a straight two-lane, two-way road along +x; the
ego's own lane has its centre at y = 0, the oncoming lane at y = +lane_width.  All other vehicles are
given by the x of their body centre; the ego's body centre is its rear axle plus half the wheelbase
along the heading.

The specification, per horizon step k (each conjunct is a constraint ``rho >= 0``):

* lead:   behind with a time gap  OR  laterally clear of the lead  OR  ahead of it by ``front_gap_m``
* each oncoming vehicle j:  laterally clear (in the own lane)  OR  still ahead of us by a closing-speed
  gap  OR  already behind us
* completion (only for steps at or after the deadline, selected by a 0/1 mask parameter): ahead of the
  lead AND back in the own lane
* lane/road boundaries, speed limit, actuator limits: simple bounds

Smooth semantics: OR is a log-sum-exp soft max minus ``log(n)/beta`` and AND a soft min; both are
*under*-approximations of the exact max/min, so ``rho_smooth >= 0`` implies the exact (min/max) space
robustness is >= 0: the smoothing never admits an unsafe plan, it only costs a little conservatism
(at most ``log(3)/beta`` metres).  Gaps use the axis-aligned hull of the ego's rotated box and are
tightened by the predicted position uncertainty of the other vehicles (``lead_sigma_m``, ...).

``OvertakingMilp`` encodes the same specification with big-M binaries (HiGHS via CasADi ``conic``) on
the linearised bicycle, for the comparison in ``benchmarks/overtaking_solve.py``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.vehicles.ground.bicycle import N_INPUT, N_STATE, BicycleParams, rk4_step

FAR_M = 1.0e4  # [m] position used for absent vehicles (numerically inert in the soft max)


class RoadGeometry(BaseModel):
    """Lane layout and the sizes of the other vehicles (the ego's size is in ``BicycleParams``)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    lane_width_m: float = Field(3.5, gt=0.0)  # [m]
    other_length_m: float = Field(4.5, gt=0.0)  # [m]
    other_width_m: float = Field(1.8, gt=0.0)  # [m]


class OvertakingMpcParams(BaseModel):
    """Horizon, specification margins, cost weights and solver options of the overtaking MPC."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    dt_s: float = Field(0.2, gt=0.0)  # [s] MPC step (= controller period)
    horizon_steps: int = Field(40, ge=5, le=200)  # [steps] of dt_s: 8 s at 0.2 s, at most 40 s
    max_oncoming: int = Field(3, ge=1, le=10)  # oncoming vehicles considered (nearest first)
    speed_limit_mps: float = Field(27.8, gt=0.0)  # [m/s] 100 km/h
    lead_standstill_gap_m: float = Field(3.0, ge=0.0)  # [m] bumper gap behind the lead at v = 0
    lead_time_gap_s: float = Field(0.9, ge=0.0)  # [s] plus this times the ego's speed
    front_gap_m: float = Field(6.0, ge=0.0)  # [m] bumper gap ahead of the lead before/while cutting in
    oncoming_gap_m: float = Field(8.0, ge=0.0)  # [m] bumper gap to an oncoming vehicle
    oncoming_time_gap_s: float = Field(0.5, ge=0.0)  # [s] plus this times the closing speed
    lateral_margin_m: float = Field(0.4, ge=0.0)  # [m] lateral clearance counted as "clear"
    back_in_lane_m: float = Field(0.5, gt=0.0)  # [m] |y| below this is "back in the own lane"
    beta: float = Field(3.0, gt=0.0)  # [1/m] sharpness of the soft max/min
    heading_max_rad: float = Field(0.2, gt=0.0)  # [rad] bound on |psi| (road-aligned driving)
    w_lane: float = 0.5  # cost on (y - y_ref)^2 per step
    w_speed: float = 0.2  # cost on (v - v_ref)^2
    w_accel: float = 0.05
    w_steer: float = 20.0
    w_heading: float = 5.0
    w_daccel: float = 0.2  # on input rate (comfort)
    w_dsteer: float = 200.0
    max_iter: int = Field(200, ge=1, le=10_000)  # IPOPT iterations
    decision_max_iter: int = Field(40, ge=1, le=10_000)  # a pass not found within this many iterations is refused
    tol: float = Field(1e-4, gt=0.0)


@dataclass(frozen=True)
class MpcProblem:
    """Numeric data of one solve; arrays cover the horizon's N + 1 knots."""

    x0: np.ndarray  # [4] ego state
    u_prev: np.ndarray  # [2] last applied input (for the rate cost)
    lead_x: np.ndarray  # [N+1] predicted lead centre [m] (FAR_M when there is none)
    oncoming_x: np.ndarray  # [M, N+1] predicted oncoming centres [m] (FAR_M for empty slots)
    oncoming_v: np.ndarray  # [M] oncoming speeds [m/s] (signed, < 0)
    v_ref: float  # [m/s] speed the cost pulls towards
    y_ref: float  # [m] lateral position the cost pulls towards
    done_mask: np.ndarray  # [N+1] 1 where the completion constraint applies, else 0
    y_max_m: float = np.inf  # [m] extra bound on the rear-axle y (e.g. keep the own lane in follow)
    lead_sigma_m: np.ndarray | None = None  # [N+1] position uncertainty of the lead (tightens its gaps)
    oncoming_sigma_m: np.ndarray | None = None  # [M, N+1] same for the oncoming vehicles

    def sigmas(self) -> tuple[np.ndarray, np.ndarray]:
        """The uncertainty arrays, zeros when not given."""
        lead = np.zeros_like(self.lead_x) if self.lead_sigma_m is None else self.lead_sigma_m
        onc = np.zeros_like(self.oncoming_x) if self.oncoming_sigma_m is None else self.oncoming_sigma_m
        return lead, onc


@dataclass(frozen=True)
class MpcSolution:
    """A solved (or failed) plan."""

    ok: bool  # IPOPT converged and the exact robustness of the plan is >= 0
    status: str
    states: np.ndarray  # [N+1, 4]
    inputs: np.ndarray  # [N, 2]
    solve_time_s: float
    robustness_m: float  # exact (min/max) space robustness of the plan's spec constraints [m]


@lru_cache(maxsize=8)
def cached_mpc(params: OvertakingMpcParams, ego: BicycleParams, road: RoadGeometry) -> OvertakingMpc:
    """One built solver per parameter set (building the NLP takes ~1 s; solving never mutates it)."""
    return OvertakingMpc(params, ego, road)


def _smax(args: list[ca.SX], beta: float) -> ca.SX:
    """Soft max that under-approximates max (LSE minus log n / beta)."""
    return ca.logsumexp(beta * ca.vertcat(*args)) / beta - np.log(len(args)) / beta


def _smin(args: list[ca.SX], beta: float) -> ca.SX:
    """Soft min that under-approximates min (-LSE(-x))."""
    return -ca.logsumexp(-beta * ca.vertcat(*args)) / beta


def body_centre(states: np.ndarray | ca.SX, wheelbase_m: float) -> tuple:
    """Body-centre (x, y) of ego state(s): rear axle plus half the wheelbase along the heading."""
    if isinstance(states, ca.SX):
        return (states[0] + 0.5 * wheelbase_m * ca.cos(states[2]),
                states[1] + 0.5 * wheelbase_m * ca.sin(states[2]))
    s = np.atleast_2d(states)
    return (s[:, 0] + 0.5 * wheelbase_m * np.cos(s[:, 2]), s[:, 1] + 0.5 * wheelbase_m * np.sin(s[:, 2]))


def hull_half_extents(psi: np.ndarray | ca.SX, ego: BicycleParams) -> tuple:
    """Half length and half width [m] of the axis-aligned hull of the ego's box at heading ``psi``.

    Gaps measured with the hull are conservative for the oriented box; the CasADi version smooths
    ``|sin psi|`` as ``sqrt(sin^2 + 1e-4)`` (an over-estimate, so still conservative).
    """
    if isinstance(psi, ca.SX):
        c, s = ca.cos(psi), ca.sqrt(ca.sin(psi) ** 2 + 1e-4)
    else:
        c, s = np.abs(np.cos(psi)), np.abs(np.sin(psi))
    hl, hw = 0.5 * ego.length_m, 0.5 * ego.width_m
    return hl * c + hw * s, hl * s + hw * c

class OvertakingMpc:
    """Builds the NLP once; ``solve(problem, guess)`` fills parameters and warm-starts IPOPT."""

    def __init__(self, params: OvertakingMpcParams | None = None, ego: BicycleParams | None = None,
                 road: RoadGeometry | None = None) -> None:
        self.p = params or OvertakingMpcParams()
        self.ego = ego or BicycleParams()
        self.road = road or RoadGeometry()
        self.n = self.p.horizon_steps
        self._build()

    # ---- construction -------------------------------------------------------------------------------
    def _constraint_terms(self, xk: ca.SX, lead_x: ca.SX, onc_x: ca.SX, onc_v: ca.SX, mask: ca.SX,
                          lead_sig: ca.SX, onc_sig: ca.SX) -> list[ca.SX]:
        """Smooth robustness of the lead, oncoming and completion conjuncts at one knot."""
        p, road, ego = self.p, self.road, self.ego
        xc, yc = body_centre(xk, ego.wheelbase_m)
        hx, hy = hull_half_extents(xk[2], ego)
        half_len, half_wid = hx + 0.5 * road.other_length_m, hy + 0.5 * road.other_width_m
        cap = 50.0  # [m] keep far-away vehicles from dominating the soft max's gradients
        behind = ca.fmin(lead_x - lead_sig - xc - half_len - p.lead_standstill_gap_m
                         - p.lead_time_gap_s * xk[3], cap)
        ahead = ca.fmin(xc - lead_x - lead_sig - half_len - p.front_gap_m, cap)
        lat_lead = yc - half_wid - p.lateral_margin_m
        terms = [_smax([behind, lat_lead, ahead], p.beta)]
        lat_onc = road.lane_width_m - yc - half_wid - p.lateral_margin_m
        for j in range(self.p.max_oncoming):
            closing = ca.fmax(xk[3] - onc_v[j], 0.0)
            before = ca.fmin(onc_x[j] - onc_sig[j] - xc - half_len - p.oncoming_gap_m
                             - p.oncoming_time_gap_s * closing, cap)
            after = ca.fmin(xc - onc_x[j] - onc_sig[j] - half_len - 1.0, cap)
            terms.append(_smax([lat_onc, before, after], p.beta))
        done = _smin([ahead, p.back_in_lane_m - yc], p.beta)
        terms.append(mask * done)
        return terms

    def _build(self) -> None:
        n, m, p, ego = self.n, self.p.max_oncoming, self.p, self.ego
        X = ca.SX.sym("X", N_STATE, n + 1)
        U = ca.SX.sym("U", N_INPUT, n)
        x0, u_prev = ca.SX.sym("x0", N_STATE), ca.SX.sym("u_prev", N_INPUT)
        lead = ca.SX.sym("lead", n + 1)
        onc = ca.SX.sym("onc", m, n + 1)
        onc_v = ca.SX.sym("onc_v", m)
        v_ref, y_ref = ca.SX.sym("v_ref"), ca.SX.sym("y_ref")
        mask = ca.SX.sym("mask", n + 1)
        lead_sig, onc_sig = ca.SX.sym("lead_sig", n + 1), ca.SX.sym("onc_sig", m, n + 1)
        g = [X[:, 0] - x0]
        ineq: list[ca.SX] = []
        cost = 0
        for k in range(n):
            g.append(X[:, k + 1] - rk4_step(X[:, k], U[:, k], p.dt_s, ego))
            du = U[:, k] - (u_prev if k == 0 else U[:, k - 1])
            cost += (p.w_accel * U[0, k] ** 2 + p.w_steer * U[1, k] ** 2
                     + p.w_daccel * du[0] ** 2 + p.w_dsteer * du[1] ** 2)
        for k in range(1, n + 1):
            ineq += self._constraint_terms(X[:, k], lead[k], onc[:, k], onc_v, mask[k], lead_sig[k], onc_sig[:, k])
            cost += (p.w_lane * (X[1, k] - y_ref) ** 2 + p.w_speed * (X[3, k] - v_ref) ** 2
                     + p.w_heading * X[2, k] ** 2)
        self._n_eq = N_STATE * (n + 1)
        self._n_ineq = len(ineq)
        w = ca.vertcat(ca.vec(X), ca.vec(U))
        par = ca.vertcat(x0, u_prev, lead, ca.vec(onc), onc_v, v_ref, y_ref, mask, lead_sig, ca.vec(onc_sig))
        nlp = {"x": w, "p": par, "f": cost, "g": ca.vertcat(*g, *ineq)}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                "ipopt.max_iter": p.max_iter, "ipopt.tol": p.tol, "ipopt.acceptable_tol": 1e-2,
                "ipopt.acceptable_iter": 5, "ipopt.mu_strategy": "adaptive"}
        self._solver = ca.nlpsol("overtaking_mpc", "ipopt", nlp, opts)
        self._decision_solver = ca.nlpsol("overtaking_decision", "ipopt", nlp,
                                          {**opts, "ipopt.max_iter": p.decision_max_iter})
        self._bounds()

    def _bounds(self) -> None:
        n, p, ego, road = self.n, self.p, self.ego, self.road
        half_w = 0.5 * ego.width_m
        xlo = np.tile([-np.inf, -0.5 * road.lane_width_m + half_w, -p.heading_max_rad, 0.0], n + 1)
        xhi = np.tile([np.inf, 1.5 * road.lane_width_m - half_w, p.heading_max_rad,
                       min(p.speed_limit_mps, ego.speed_max_mps)], n + 1)
        ulo = np.tile([ego.accel_min_mps2, -ego.steer_max_rad], n)
        uhi = np.tile([ego.accel_max_mps2, ego.steer_max_rad], n)
        self._lbx, self._ubx = np.concatenate([xlo, ulo]), np.concatenate([xhi, uhi])
        self._lbg = np.zeros(self._n_eq + self._n_ineq)
        self._ubg = np.concatenate([np.zeros(self._n_eq), np.full(self._n_ineq, np.inf)])

    # ---- solving ------------------------------------------------------------------------------------
    def solve(self, prob: MpcProblem, guess_states: np.ndarray, guess_inputs: np.ndarray,
              decision: bool = False) -> MpcSolution:
        """Solve from the warm start (``guess_states`` [N+1, 4], ``guess_inputs`` [N, 2]).

        ``decision=True`` uses the iteration-capped solver (a go/no-go decision must be quick; not
        finding a plan in time means no).
        """
        n = self.n
        par = np.concatenate([prob.x0, prob.u_prev, prob.lead_x, prob.oncoming_x.T.ravel(),
                              prob.oncoming_v, [prob.v_ref, prob.y_ref], prob.done_mask,
                              prob.sigmas()[0], prob.sigmas()[1].T.ravel()])
        w0 = np.concatenate([guess_states.ravel(), guess_inputs.ravel()])
        ubx = self._ubx.copy()
        ubx[1: N_STATE * (n + 1): N_STATE] = np.minimum(ubx[1: N_STATE * (n + 1): N_STATE], prob.y_max_m)
        ubx[1] = max(ubx[1], prob.x0[1])  # the current state is never out of bounds
        w0 = np.clip(w0, self._lbx, ubx)
        t0 = time.perf_counter()
        solver = self._decision_solver if decision else self._solver
        res = solver(x0=w0, p=par, lbx=self._lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg)
        dt = time.perf_counter() - t0
        self.last_stats = solver.stats()
        status = str(self.last_stats["return_status"])
        w = np.asarray(res["x"]).ravel()
        states = w[: N_STATE * (n + 1)].reshape(n + 1, N_STATE)
        inputs = w[N_STATE * (n + 1):].reshape(n, N_INPUT)
        rho = self.exact_robustness(states, prob)
        converged = status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        dyn_err = float(np.max(np.abs(np.asarray(res["g"]).ravel()[: self._n_eq])))
        ok = converged and rho >= -1e-3 and dyn_err < 1e-3
        return MpcSolution(ok, status, states, inputs, dt, rho)

    def exact_robustness(self, states: np.ndarray, prob: MpcProblem) -> float:
        """Exact min/max robustness [m] of the MPC's constraint set on a plan (knots 1..N)."""
        lead_sig, onc_sig = prob.sigmas()
        sig = spec_margins(states[1:], prob.lead_x[1:], prob.oncoming_x[:, 1:], prob.oncoming_v,
                           self.p, self.ego, self.road, lead_sig[1:], onc_sig[:, 1:])
        rho = np.minimum(sig["lead"], sig["oncoming"])
        done = np.where(prob.done_mask[1:] > 0, sig["done"], np.inf)
        return float(np.min(np.minimum(rho, done)))


def spec_margins(states: np.ndarray, lead_x: np.ndarray, onc_x: np.ndarray, onc_v: np.ndarray,
                 p: OvertakingMpcParams, ego: BicycleParams, road: RoadGeometry,
                 lead_sigma: np.ndarray | float = 0.0, onc_sigma: np.ndarray | float = 0.0) -> dict[str, np.ndarray]:
    """Exact (min/max) robustness [m] per knot of the MPC's lead, oncoming and completion conjuncts."""
    xc, yc = body_centre(states, ego.wheelbase_m)
    v = states[:, 3]
    hx, hy = hull_half_extents(states[:, 2], ego)
    half_len, half_wid = hx + 0.5 * road.other_length_m, hy + 0.5 * road.other_width_m
    behind = lead_x - lead_sigma - xc - half_len - p.lead_standstill_gap_m - p.lead_time_gap_s * v
    ahead = xc - lead_x - lead_sigma - half_len - p.front_gap_m
    lead = np.maximum.reduce([behind, yc - half_wid - p.lateral_margin_m, ahead])
    lat_onc = road.lane_width_m - yc - half_wid - p.lateral_margin_m
    onc = np.full_like(xc, np.inf)
    onc_x2 = np.atleast_2d(onc_x)
    onc_s2 = np.broadcast_to(onc_sigma, onc_x2.shape)
    for xj, vj, sj in zip(onc_x2, np.atleast_1d(onc_v), onc_s2):
        closing = np.maximum(v - vj, 0.0)
        before = xj - sj - xc - half_len - p.oncoming_gap_m - p.oncoming_time_gap_s * closing
        after = xc - xj - sj - half_len - 1.0
        onc = np.minimum(onc, np.maximum.reduce([lat_onc, before, after]))
    done = np.minimum(ahead, p.back_in_lane_m - yc)
    return {"lead": lead, "oncoming": onc, "done": done}

def rollout_guess(x0: np.ndarray, lateral_target: Callable[[int, np.ndarray], float],
                  speed_target: Callable[[int, np.ndarray], float], p: OvertakingMpcParams,
                  ego: BicycleParams) -> tuple[np.ndarray, np.ndarray]:
    """A dynamically consistent warm start: P-controllers tracking a lateral/speed target per step.

    ``lateral_target(k, x)`` and ``speed_target(k, x)`` see the rolled-out state, so a guess can say
    "stay in the oncoming lane until 10 m ahead of the lead, then cut in".  It seeds IPOPT in a chosen
    homotopy class (stay behind, pass on the left, fall back), which the local solver then keeps.
    Returns (states [N+1, 4], inputs [N, 2]).
    """
    n = p.horizon_steps
    xs = np.empty((n + 1, N_STATE))
    us = np.empty((n, N_INPUT))
    xs[0] = x0
    for k in range(n):
        x = xs[k]
        v = max(x[3], 1.0)
        psi_des = float(np.clip(0.4 * (lateral_target(k, x) - x[1]) / v, -0.12, 0.12))
        yaw_rate = 1.5 * (psi_des - x[2])
        steer = float(np.clip(np.arctan(yaw_rate * ego.wheelbase_m / v), -ego.steer_max_rad, ego.steer_max_rad))
        accel = float(np.clip(speed_target(k, x) - x[3], ego.accel_min_mps2, ego.accel_max_mps2))
        us[k] = (accel, steer)
        xs[k + 1] = rk4_step(x, us[k], p.dt_s, ego)
    return xs, us


def pass_guess(prob: MpcProblem, mpc: OvertakingMpc) -> tuple[np.ndarray, np.ndarray]:
    """Warm start of a pass: move out, drive at the speed limit, cut in once clear ahead of the lead."""
    p, ego = mpc.p, mpc.ego
    clear = 0.5 * (ego.length_m + mpc.road.other_length_m) + p.front_gap_m + 3.0

    def lateral(k: int, x: np.ndarray) -> float:
        ahead = x[0] + 0.5 * ego.wheelbase_m - prob.lead_x[k] > clear
        return 0.0 if ahead else mpc.road.lane_width_m

    return rollout_guess(prob.x0, lateral, lambda k, x: p.speed_limit_mps, p, ego)


class OvertakingMilp:
    """The same specification by a big-M mixed-integer encoding (CasADi ``conic`` with HiGHS).

    For comparison with the smooth NLP in the benchmark.  Exact disjunctions need a linear model, so the
    dynamics are the shared bicycle ``f`` linearised by CasADi at psi = 0 along a speed ramp (linear
    time-varying) and discretised exactly (zero-order hold); the cost is the L1 analogue of the NLP's.  One binary per
    disjunct per knot selects which reason makes the lead/oncoming conjunct true (sum >= 1), with
    ``r(z) >= -M (1 - b)``.  Plans are returned in the nonlinear model (the inputs re-simulated by RK4),
    so their robustness is checked honestly.  The heading enters the body centre linearly; a lateral
    margin of ``hull_pad_m`` covers the box rotation (|psi| <= heading_max_rad).
    """

    def __init__(self, mpc: OvertakingMpc, big_m: float = 1.0e3, time_limit_s: float = 5.0) -> None:
        self.mpc, self.big_m, self.time_limit_s = mpc, big_m, time_limit_s
        p, ego = mpc.p, mpc.ego
        self.hull_pad_m = 0.5 * ego.length_m * float(np.sin(p.heading_max_rad))
        x, u = ca.SX.sym("x", N_STATE), ca.SX.sym("u", N_INPUT)
        from corridor.vehicles.ground.bicycle import f as bicycle_f

        fx = bicycle_f(x, u, ego)
        self._jac = ca.Function("bicycle_linearisation", [x, u], [ca.jacobian(fx, x), ca.jacobian(fx, u), fx])

    def _speed_profile(self, prob: MpcProblem) -> np.ndarray:
        """Speeds [m/s] to linearise at, per step: the current speed ramped towards ``v_ref`` at the
        acceleration limit (a linear time-varying model; the bilinear ``v sin(psi)`` needs a guess)."""
        ts = np.arange(self.mpc.n) * self.mpc.p.dt_s
        v0, v_ref = float(prob.x0[3]), prob.v_ref
        rate = self.mpc.ego.accel_max_mps2 if v_ref >= v0 else -self.mpc.ego.accel_max_mps2
        return v0 + np.clip(rate * ts, -abs(v_ref - v0), abs(v_ref - v0))

    def _discrete(self, v0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact ZOH discretisation of the linearisation at (0, 0, 0, v0), (0, 0)."""
        from scipy.linalg import expm

        xs, us = np.array([0.0, 0.0, 0.0, v0]), np.zeros(N_INPUT)
        A, B, f0 = (np.asarray(z, dtype=float) for z in self._jac(xs, us))
        c = f0.ravel() - A @ xs
        aug = np.zeros((N_STATE + N_INPUT + 1,) * 2)
        aug[:N_STATE, :N_STATE], aug[:N_STATE, N_STATE:-1], aug[:N_STATE, -1] = A, B, c
        E = expm(aug * self.mpc.p.dt_s)
        return E[:N_STATE, :N_STATE], E[:N_STATE, N_STATE:-1], E[:N_STATE, -1]

    def solve(self, prob: MpcProblem) -> MpcSolution:
        """Build and solve the MILP for ``prob``; the returned states are the nonlinear replay."""
        t0 = time.perf_counter()
        rows, lo, hi, cost, disc, lbx, ubx = self._assemble(prob)
        A = ca.DM(np.asarray(rows))
        solver = ca.conic("overtaking_milp", "highs", {"h": ca.Sparsity(A.size2(), A.size2()), "a": A.sparsity()},
                          {"discrete": disc, "error_on_fail": False,
                           "highs": {"output_flag": False, "time_limit": self.time_limit_s}})
        res = solver(h=ca.DM(A.size2(), A.size2()), g=cost, a=A, lba=lo, uba=hi, lbx=lbx, ubx=ubx)
        stats = solver.stats()
        dt = time.perf_counter() - t0
        n = self.mpc.n
        z = np.asarray(res["x"]).ravel()
        inputs = z[N_STATE * (n + 1): N_STATE * (n + 1) + N_INPUT * n].reshape(n, N_INPUT)
        states = np.empty((n + 1, N_STATE))
        states[0] = prob.x0
        for k in range(n):
            states[k + 1] = rk4_step(states[k], inputs[k], self.mpc.p.dt_s, self.mpc.ego)
        rho = self.mpc.exact_robustness(states, prob)
        ok = bool(stats["success"]) and rho >= -1e-3
        return MpcSolution(ok, str(stats["return_status"]), states, inputs, dt, rho)

    def _assemble(self, prob: MpcProblem) -> tuple:
        """Constraint rows, bounds, linear cost and the discrete flags of the MILP (x shifted to x0)."""
        p, ego, road, n, big = self.mpc.p, self.mpc.ego, self.mpc.road, self.mpc.n, self.big_m
        x_shift = float(prob.x0[0])
        present = [j for j in range(len(prob.oncoming_v)) if prob.oncoming_x[j, 0] < 0.5 * FAR_M]
        o_u = N_STATE * (n + 1)
        o_aux = o_u + N_INPUT * n  # e_y, e_v, e_a, e_d: 4 blocks of n
        o_bin = o_aux + 4 * n
        n_var = o_bin + 3 * n * (1 + len(present))
        ix = lambda k, i: N_STATE * k + i  # noqa: E731
        rows: list[dict[int, float]] = []
        lo: list[float] = []
        hi: list[float] = []

        def add(coefs: dict[int, float], lower: float, upper: float = np.inf) -> None:
            rows.append(coefs)
            lo.append(lower)
            hi.append(upper)

        x0 = np.array([0.0, *prob.x0[1:]])
        for i in range(N_STATE):
            add({ix(0, i): 1.0}, x0[i], x0[i])
        v_lin = self._speed_profile(prob)
        for k in range(n):
            Ad, Bd, cd = self._discrete(float(v_lin[k]))
            for i in range(N_STATE):
                coefs = {ix(k + 1, i): 1.0}
                for j in range(N_STATE):
                    coefs[ix(k, j)] = coefs.get(ix(k, j), 0.0) - Ad[i, j]
                for j in range(N_INPUT):
                    coefs[o_u + N_INPUT * k + j] = -Bd[i, j]
                add(coefs, cd[i], cd[i])
        for k in range(n):  # |y - y_ref|, |v - v_ref|, |a|, |delta| as epigraphs
            for blk, (col, ref) in enumerate([(ix(k + 1, 1), prob.y_ref), (ix(k + 1, 3), prob.v_ref),
                                              (o_u + N_INPUT * k, 0.0), (o_u + N_INPUT * k + 1, 0.0)]):
                e = o_aux + blk * n + k
                add({e: 1.0, col: -1.0}, -ref)
                add({e: 1.0, col: 1.0}, ref)
        lead_sig, onc_sig = prob.sigmas()
        half_len = 0.5 * (ego.length_m + road.other_length_m)
        half_wid = 0.5 * (ego.width_m + road.other_width_m) + self.hull_pad_m
        c_x, c_y = 0.5 * ego.wheelbase_m, 0.5 * ego.wheelbase_m  # xc = x + c_x, yc = y + c_y psi

        def disjunction(k: int, b0: int, terms: list[tuple[dict[int, float], float]]) -> None:
            """sum_i b_i >= 1 and a_i . z + c_i >= -M (1 - b_i)."""
            add({b0 + i: 1.0 for i in range(len(terms))}, 1.0)
            for i, (coefs, const) in enumerate(terms):
                add({**coefs, b0 + i: -big}, -const - big)

        for k in range(1, n + 1):
            xk, yk, pk, vk = (ix(k, i) for i in range(N_STATE))
            lx, ls = prob.lead_x[k] - x_shift, lead_sig[k]
            b_lead = o_bin + 3 * (k - 1)
            if prob.lead_x[k] < 0.5 * FAR_M:
                disjunction(k, b_lead, [
                    ({xk: -1.0, vk: -p.lead_time_gap_s}, lx - ls - c_x - half_len - p.lead_standstill_gap_m),
                    ({yk: 1.0, pk: c_y}, -half_wid - p.lateral_margin_m),
                    ({xk: 1.0}, c_x - lx - ls - half_len - p.front_gap_m)])
                if prob.done_mask[k] > 0:
                    add({xk: 1.0}, -(c_x - lx - ls - half_len - p.front_gap_m))
            if prob.done_mask[k] > 0:
                add({yk: -1.0, pk: -c_y}, -p.back_in_lane_m)
            for q, j in enumerate(present):
                ox, os_, ov = prob.oncoming_x[j, k] - x_shift, onc_sig[j, k], prob.oncoming_v[j]
                disjunction(k, o_bin + 3 * n * (1 + q) + 3 * (k - 1), [
                    ({yk: -1.0, pk: -c_y}, road.lane_width_m - half_wid - p.lateral_margin_m),
                    ({xk: -1.0, vk: -p.oncoming_time_gap_s},
                     ox - os_ - c_x - half_len - p.oncoming_gap_m + p.oncoming_time_gap_s * ov),
                    ({xk: 1.0}, c_x - ox - os_ - half_len - 1.0)])
        A = np.zeros((len(rows), n_var))
        for r, coefs in enumerate(rows):
            for col, val in coefs.items():
                A[r, col] += val
        cost = np.zeros(n_var)
        for blk, w in enumerate((1.0, 0.5, 0.1, 5.0)):  # lane, speed, accel, steer (L1 weights)
            cost[o_aux + blk * n: o_aux + (blk + 1) * n] = w
        lbx, ubx = np.full(n_var, -np.inf), np.full(n_var, np.inf)
        lbx[:o_aux], ubx[:o_aux] = self.mpc._lbx, self.mpc._ubx
        ubx[1:o_u:N_STATE] = np.minimum(ubx[1:o_u:N_STATE], max(prob.y_max_m, float(prob.x0[1])))
        lbx[0:o_u:N_STATE], ubx[0:o_u:N_STATE] = -np.inf, np.inf
        lbx[o_aux:o_bin] = 0.0
        lbx[o_bin:], ubx[o_bin:] = 0.0, 1.0
        disc = [False] * o_bin + [True] * (n_var - o_bin)
        return A, np.array(lo), np.array(hi), cost, disc, lbx, ubx
