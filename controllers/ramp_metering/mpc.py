"""Coordinated ramp-metering + route-guidance MPC on METANET (CasADi + IPOPT), with ALINEA fallback.

The optimal control problem (built once, re-solved with parameters):

    min  T sum_k (sum_i rho_i L_i lanes_i + sum_o w_o)                   total time spent [veh h]
         + xi_r sum ||r_j - r_{j-1}||^2 + xi_s sum ||s_j - s_{j-1}||^2   smooth controls
         + xi_w sum sigma                                                soft queue limits
    s.t. x_{k+1} = f(x_k, u_{floor(k/M)}, d_k)   (METANET, multiple shooting, k = 0..N-1)
         w_{o,k} <= storage_o + sigma_{o,k},  sigma >= 0
         r_min <= r <= r_max,  split_lo <= s <= split_hi

with control step M model steps (60 s = 6 x 10 s) and N = horizon x M. Parameters are the initial
state, the disturbance forecast and the previously applied input. Each solve is warm-started from
the previous solution shifted by one control step. If IPOPT fails, or stops at its limit without a
usable iterate, the controller returns ALINEA rates (one ALINEA per meter, fed from the state's
density and queue) with the default split, and sets ``fallback`` so the caller can log the event.

The solve budget is deterministic: IPOPT's iteration limit ``max_iter`` (and its acceptable-level
stop) decides where a solve ends, so the same inputs give the same rates on an idle and on a loaded
machine.  ``max_cpu_time_s`` is only a safety net against a pathological solve; a solve it ends is
counted in ``n_cpu_capped`` (its status names the CPU limit) so the caller can log it, since from
then on the run depends on the machine.  IPOPT's wall-time limit is not used (it depends on load).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from corridor.controllers.ramp_metering.alinea import Alinea, AlineaConfig, occupancy_from_density
from corridor.controllers.ramp_metering.casadi_blas import set_casadi_blas_threads
from corridor.traffic.macro.metanet import MetanetNetwork, SimResult, total_time_spent_step

_OK_STATUS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
_LIMIT_STATUS = ("Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded", "Maximum_WallTime_Exceeded")
CPU_CAP_STATUS = "Maximum_CpuTime_Exceeded"  # the safety net ended the solve: machine-dependent


@dataclass(frozen=True)
class MPCConfig:
    """Settings of the ramp-metering MPC."""

    horizon_ctrl_steps: int = 5  # prediction horizon in control steps
    control_step_s: float = 60.0  # control step [s]; a multiple of the model step
    weight_rate_change: float = 0.4  # xi_r on squared change of meter rate fractions
    weight_split_change: float = 0.4  # xi_s on squared change of route splits
    weight_queue_slack: float = 10.0  # xi_w per vehicle above storage per model step
    rate_min: float = 0.0  # lowest meter rate [fraction of ramp capacity]
    rate_max: float = 1.0  # highest meter rate [fraction of ramp capacity]
    max_cpu_time_s: float = 60.0  # IPOPT CPU-time safety net per solve [s] (counted in n_cpu_capped)
    max_iter: int = 500  # the deterministic budget: IPOPT iterations per solve
    tol: float = 1e-5  # IPOPT convergence tolerance (TTS is ~1e2 veh h: 1e-5 is far below what matters)
    acceptable_tol: float = 1e-3  # IPOPT stops after ``acceptable_iter`` iterations at this tolerance
    acceptable_iter: int = 5
    accept_improving_iterate: bool = True  # at an iteration or time limit, apply the last iterate if
    #   it satisfies the dynamics and storage rows (within ``feasibility_tol``) and costs less than
    #   holding the current inputs: suboptimal MPC (Scokaert, Mayne & Rawlings 1999)
    feasibility_tol: float = 1e-2  # [veh/km/lane, km/h, veh] largest constraint violation accepted
    smooth_vph: float = 20.0  # width of the smooth min in the prediction model's origin flows [veh/h]
    smooth_rho: float = 1.0  # width of the smooth min/max at destinations [veh/km/lane]
    # width of the smooth positive part of the density in the equilibrium speed [veh/km/lane]: the
    # states are free in the NLP, and an iterate with a negative density made the Jacobian NaN
    # (IPOPT stopped, the step fell back to ALINEA); it moves V by < 1e-3 km/h at any rho >= 0.1
    smooth_pos_rho: float = 0.1
    occupancy_eff_length_m: float = 7.0  # vehicle + loop length, converts density to occupancy [m]
    alinea_gain_vph_per_pct: float = 70.0
    alinea_override_frac: float = 0.8
    # IPOPT's linear solver (95 % of the solve time) and MUMPS's fill-reducing ordering (its ICNTL(7):
    # 0 AMD, 2 AMF, 4 PORD, 5 METIS, 6 QAMD, 7 MUMPS chooses; None: by problem size, see
    # ``pivot_order_for``).  METIS halves the beltway MPC's solve time at 8 and 16 interchanges against
    # 7 and costs time at 4 (benchmarks/mpc_solve.py prints both side by side)
    linear_solver: str = "mumps"
    mumps_pivot_order: int | None = None
    ipopt_extra: tuple[tuple[str, Any], ...] = ()  # further IPOPT options, (name, value) pairs
    # threads of CasADi's OpenBLAS (MUMPS's dense kernels), set before each solve for the whole
    # process; None: leave it (OpenBLAS's default: one per core).  1: no CPU spent by a spinning
    # second thread, the same sums on every machine (see casadi_blas)
    blas_threads: int | None = 1
    # Opt-in: warm solves (after a successful one) also start from the shifted multipliers, with
    # IPOPT's warm-start point and a small initial barrier parameter.  On the beltway (4-16
    # interchanges) about half the iterations and CPU time, TTS equal to 1e-3 veh h; on the Hegyi
    # benchmark it falls back to ALINEA 3 times (mu_init 1e-2, 1e-1) or never meters (1e-4), so it
    # is off by default.  Cold solves (the first, after a fallback) use the plain solver either way.
    warm_start_duals: bool = False
    warm_mu_init: float = 1e-4
    warm_bound_push: float = 1e-6  # warm_start_bound_push and warm_start_mult_bound_push


@dataclass(frozen=True)
class MPCResult:
    """Outcome of one MPC solve (or of its ALINEA fallback)."""

    rates: np.ndarray  # meter rates [fraction of capacity], one per metered origin
    rates_vph: np.ndarray  # same in [veh/h]
    split: np.ndarray  # route-guidance cw shares, one per split group
    status: str  # IPOPT return status, or the failure reason
    solve_s: float  # wall time of the solve [s]
    fallback: bool  # True when the rates come from ALINEA
    predicted_tts: float  # TTS over the horizon predicted by the solution [veh h] (nan on fallback)

    @property
    def u(self) -> np.ndarray:
        """The input vector [rates, split] in the model's order."""
        return np.concatenate([self.rates, self.split])


@dataclass
class _Warm:
    """Previous solution kept for warm starting (already shifted when stored)."""

    z: np.ndarray
    valid: bool = False
    lam_x: np.ndarray | None = None  # multipliers of the bounds, shifted like z
    lam_g: np.ndarray | None = None  # multipliers of the constraints, shifted by one control step


@dataclass
class _Layout:
    """Index ranges of the decision vector z = [X(:,1..N), R, S, sigma] (column-major blocks)."""

    nx: int
    n: int
    nr: int
    ns: int
    nc: int
    nq: int
    sizes: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.sizes = [self.nx * self.n, self.nr * self.nc, self.ns * self.nc, self.nq * self.n]

    @property
    def offsets(self) -> list[int]:
        return list(np.cumsum([0] + self.sizes))

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(X (nx,N), R (nr,Nc), S (ns,Nc), sigma (nq,N)) from a flat z (column-major like CasADi)."""
        o = self.offsets
        shapes = [(self.nx, self.n), (self.nr, self.nc), (self.ns, self.nc), (self.nq, self.n)]
        return tuple(z[o[i]:o[i + 1]].reshape(shapes[i], order="F") for i in range(4))  # type: ignore[return-value]

    def join(self, x: np.ndarray, r: np.ndarray, s: np.ndarray, sig: np.ndarray) -> np.ndarray:
        return np.concatenate([a.ravel(order="F") for a in (x, r, s, sig)])


METIS_FROM_VARIABLES = 3000  # NLP size from which METIS orders faster than MUMPS's own choice


def pivot_order_for(n_variables: int, configured: int | None) -> int:
    """MUMPS ordering: the configured one, else METIS (5) for NLPs of ``METIS_FROM_VARIABLES`` decision
    variables or more (the beltway MPC at 8 interchanges: 3960) and MUMPS's own choice (7) below."""
    if configured is not None:
        return configured
    return 5 if n_variables >= METIS_FROM_VARIABLES else 7


def alinea_config_for(net: MetanetNetwork, j: int, cfg: MPCConfig) -> AlineaConfig:
    """ALINEA for origin j: set point at the critical occupancy of the segment it feeds."""
    i = int(net.orig_seg[j])
    cap = float(net.orig_cap_vph[j])
    return AlineaConfig(
        gain_vph_per_pct=cfg.alinea_gain_vph_per_pct,
        setpoint_pct=float(occupancy_from_density(net.rho_crit[i], cfg.occupancy_eff_length_m)),
        rate_min_vph=cfg.rate_min * cap, rate_max_vph=cfg.rate_max * cap,
        storage_veh=float(net.orig_storage_veh[j]), override_frac=cfg.alinea_override_frac,
        period_s=cfg.control_step_s)


class RampMeteringMPC:
    """Coordinated ramp metering + route guidance MPC: ``solve(x0, demand_forecast, u_prev)``."""

    def __init__(self, net: MetanetNetwork, cfg: MPCConfig | None = None) -> None:
        self.net, self.cfg = net, cfg or MPCConfig()
        steps = self.cfg.control_step_s / (net.params.step_h * 3600.0)
        if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
            raise ValueError("MPCConfig.control_step_s must be a multiple of the model step")
        self.m = int(round(steps))  # model steps per control step
        self.n = self.cfg.horizon_ctrl_steps * self.m  # model steps in the horizon
        self.queue_idx = np.flatnonzero(np.isfinite(net.orig_storage_veh))
        self.lay = _Layout(net.nx, self.n, net.n_metered, net.n_split, self.cfg.horizon_ctrl_steps,
                           len(self.queue_idx))
        self.pivot_order = pivot_order_for(int(self.lay.offsets[-1]), self.cfg.mumps_pivot_order)
        set_casadi_blas_threads(self.cfg.blas_threads)  # before nlpsol loads OpenBLAS (casadi_blas)
        self._solver, self._lbz, self._ubz, self._lbg, self._ubg = self._build()
        self._warm = _Warm(z=np.zeros(sum(self.lay.sizes)))
        self.alineas = [Alinea(alinea_config_for(net, int(j), self.cfg)) for j in net.metered_idx]
        self.solve_times_s: list[float] = []
        self.solve_cpu_s: list[float] = []  # CPU time of each solve (this process) [s]
        self.iter_counts: list[int] = []
        self.n_solves = 0
        self.n_fallbacks = 0
        self.n_suboptimal = 0  # limit hit, improving feasible iterate applied
        self.n_cpu_capped = 0  # solves ended by the CPU-time safety net (not by the iteration budget)

    # ---- construction -------------------------------------------------------------------
    def _build(self) -> tuple[ca.Function, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Build the multiple-shooting NLP once (SX, expanded) and return solver and bounds."""
        net, c, lay = self.net, self.cfg, self.lay
        X = ca.SX.sym("X", lay.nx, lay.n)
        R = ca.SX.sym("R", lay.nr, lay.nc)
        S = ca.SX.sym("S", lay.ns, lay.nc)
        SIG = ca.SX.sym("SIG", lay.nq, lay.n)
        x0 = ca.SX.sym("x0", lay.nx)
        D = ca.SX.sym("D", net.nd, lay.n)
        u_prev = ca.SX.sym("u_prev", net.nu)
        pred = dataclasses.replace(net, params=dataclasses.replace(
            net.params, smooth_vph=c.smooth_vph, smooth_rho=c.smooth_rho, smooth_pos_rho=c.smooth_pos_rho))
        f = self._pred_f = pred.function  # the same METANET with smoothed kinks (metanet.smooth_min)
        g, cost, x = [], 0, x0
        lane_km = ca.DM(net.lane_km())
        for k in range(lay.n):
            j = k // self.m
            x_next = f(x, ca.vertcat(R[:, j], S[:, j]), D[:, k])[0]
            g.append(X[:, k] - x_next)
            x = X[:, k]
            w = x[2 * net.n_seg:]
            cost += net.params.step_h * (ca.dot(lane_km, x[:net.n_seg]) + ca.sum1(w))
            if lay.nq:
                g.append(w[self.queue_idx.tolist()] - SIG[:, k])
        cost += self._change_cost(R, S, u_prev) + c.weight_queue_slack * ca.sum1(ca.vec(SIG))
        z = ca.vertcat(ca.vec(X), ca.vec(R), ca.vec(S), ca.vec(SIG))
        p = ca.vertcat(x0, ca.vec(D), u_prev)
        self._tts_fun = ca.Function("tts", [z, p], [cost])
        opts = {"expand": True, "print_time": False,
                "ipopt": {"print_level": 0, "sb": "yes", "max_iter": c.max_iter, "tol": c.tol,
                          "acceptable_tol": c.acceptable_tol, "acceptable_iter": c.acceptable_iter,
                          "max_cpu_time": c.max_cpu_time_s,
                          "linear_solver": c.linear_solver,
                          **({"mumps_pivot_order": self.pivot_order} if c.linear_solver == "mumps" else {}),
                          **dict(c.ipopt_extra)}}
        self._nlp, self._opts, self._warm_solver = {"x": z, "p": p, "f": cost, "g": ca.vertcat(*g)}, opts, None
        solver = ca.nlpsol("ramp_mpc", "ipopt", self._nlp, opts)
        lbz, ubz = self._bounds()
        lbg, ubg = self._constraint_bounds()
        return solver, lbz, ubz, lbg, ubg

    @property
    def nlp(self) -> dict[str, ca.SX]:
        """The NLP as given to ``nlpsol``: x (decision vector z), p (parameters), f (cost), g (rows)."""
        return dict(self._nlp)

    def _warm_start_solver(self) -> ca.Function:
        """The same NLP with IPOPT's warm-start options (built at the first warm solve)."""
        if self._warm_solver is None:
            c = self.cfg
            ipopt = {**self._opts["ipopt"], "warm_start_init_point": "yes", "mu_init": c.warm_mu_init,
                     "warm_start_bound_push": c.warm_bound_push, "warm_start_mult_bound_push": c.warm_bound_push,
                     **dict(c.ipopt_extra)}
            self._warm_solver = ca.nlpsol("ramp_mpc_warm", "ipopt", self._nlp, {**self._opts, "ipopt": ipopt})
        return self._warm_solver

    def _change_cost(self, R: ca.SX, S: ca.SX, u_prev: ca.SX) -> ca.SX:
        """Quadratic penalty on control changes, the first against the applied input u_prev."""
        c, nr = self.cfg, self.lay.nr
        dr = ca.diff(ca.horzcat(u_prev[:nr], R), 1, 1)
        ds = ca.diff(ca.horzcat(u_prev[nr:], S), 1, 1)
        return c.weight_rate_change * ca.sumsqr(dr) + c.weight_split_change * ca.sumsqr(ds)

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on z: rates and splits in their ranges, slacks >= 0, states free.

        States get no bounds on purpose: the dynamics already keep rho, v, w >= 0 (the smoothed
        origin flow never exceeds d + w/T), and bounds that sit on empty queues (w = 0) make the
        interior-point iterations crawl along the barrier.
        """
        net, c, lay = self.net, self.cfg, self.lay
        free = np.full((lay.nx, lay.n), np.inf)
        lo = lay.join(-free, np.full((lay.nr, lay.nc), c.rate_min),
                      np.tile(net.split_lo[:, None], lay.nc), np.zeros((lay.nq, lay.n)))
        hi = lay.join(free, np.full((lay.nr, lay.nc), c.rate_max),
                      np.tile(net.split_hi[:, None], lay.nc), np.full((lay.nq, lay.n), np.inf))
        return lo, hi

    def _constraint_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Dynamics are equalities; queue rows are w - sigma <= storage."""
        lay, store = self.lay, self.net.orig_storage_veh[self.queue_idx]
        lo, hi = [], []
        for _ in range(lay.n):
            lo.append(np.zeros(lay.nx))
            hi.append(np.zeros(lay.nx))
            lo.append(np.full(lay.nq, -np.inf))
            hi.append(store)
        return np.concatenate(lo), np.concatenate(hi)

    # ---- solving ------------------------------------------------------------------------
    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Forget the warm start, statistics and ALINEA states (deterministic; rng unused)."""
        del rng
        self._warm = _Warm(z=np.zeros(sum(self.lay.sizes)))
        for a in self.alineas:
            a.reset()
        self.solve_times_s, self.solve_cpu_s, self.iter_counts, self.n_solves, self.n_fallbacks = [], [], [], 0, 0
        self.n_suboptimal = 0  # limit hit, improving feasible iterate applied
        self.n_cpu_capped = 0

    def forecast_matrix(self, demand_forecast: np.ndarray) -> np.ndarray:
        """Disturbances (nd, N): a (nd,) vector is held constant, shorter (K, nd) forecasts are padded."""
        d = np.atleast_2d(np.asarray(demand_forecast, dtype=float))
        if d.shape[1] != self.net.nd:
            raise ValueError(f"demand_forecast needs {self.net.nd} columns, got {d.shape[1]}")
        if d.shape[0] < self.n:
            d = np.vstack([d, np.repeat(d[-1:], self.n - d.shape[0], axis=0)])
        return d[: self.n].T

    def _initial_guess(self, x0: np.ndarray, dmat: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """Shifted previous solution, or a forward simulation of the prediction model holding u_prev.

        (A start re-simulated from x0 under the shifted inputs was tried: it is dynamically consistent
        but sits in the local optimum "meters open" of this nonconvex problem, and the Hegyi benchmark
        MPC then never meters; the shifted previous trajectory does not have that problem.)
        """
        if self._warm.valid:
            return self._warm.z
        return self._hold_plan(x0, dmat, u_prev)

    def _hold_plan(self, x0: np.ndarray, dmat: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """The feasible plan that holds u_prev over the horizon (forward simulation of the model)."""
        f, lay = self._pred_f, self.lay
        xs, x = np.zeros((lay.nx, lay.n)), x0
        for k in range(lay.n):
            x = f(x, u_prev, dmat[:, k])[0].full().ravel()
            xs[:, k] = x
        r = np.tile(u_prev[:lay.nr, None], lay.nc)
        s = np.tile(u_prev[lay.nr:, None], lay.nc)
        sig = np.maximum(xs[2 * self.net.n_seg + self.queue_idx, :]
                         - self.net.orig_storage_veh[self.queue_idx, None], 0.0)
        return np.clip(lay.join(xs, r, s, sig), self._lbz, self._ubz)

    def _shift_z(self, z: np.ndarray) -> np.ndarray:
        """A z-shaped vector shifted by one control step (last columns repeated)."""
        xs, r, s, sig = self.lay.split(z)
        xs, sig = _shift_cols(xs, self.m), _shift_cols(sig, self.m)
        return self.lay.join(xs, _shift_cols(r, 1), _shift_cols(s, 1), sig)

    def _store_shifted(self, z: np.ndarray, lam_x: np.ndarray, lam_g: np.ndarray) -> None:
        """Keep the solution and its multipliers shifted by one control step for the next solve."""
        g_cols = lam_g.reshape((-1, self.lay.n), order="F")  # one column of rows per model step
        self._warm = _Warm(z=self._shift_z(z), valid=True, lam_x=self._shift_z(lam_x),
                           lam_g=_shift_cols(g_cols, self.m).ravel(order="F"))

    def solve(self, x0: np.ndarray, demand_forecast: np.ndarray, u_prev: np.ndarray | None = None,
              occupancy_pct: np.ndarray | None = None) -> MPCResult:
        """Optimal rates and splits for the next control step; ALINEA if IPOPT fails or times out.

        ``occupancy_pct`` (one per meter, measured downstream of the merge) feeds the fallback; when
        omitted it is derived from the density of the segment each ramp feeds.
        """
        x0 = np.asarray(x0, dtype=float)
        u_prev = self.net.default_u() if u_prev is None else np.asarray(u_prev, dtype=float)
        dmat = self.forecast_matrix(demand_forecast)
        p = np.concatenate([x0, dmat.ravel(order="F"), u_prev])
        z0 = self._initial_guess(x0, dmat, u_prev)
        args = {"x0": z0, "p": p, "lbx": self._lbz, "ubx": self._ubz, "lbg": self._lbg, "ubg": self._ubg}
        solver, warm = self._solver, self._warm
        if self.cfg.warm_start_duals and warm.valid and warm.lam_x is not None:
            solver, args["lam_x0"], args["lam_g0"] = self._warm_start_solver(), warm.lam_x, warm.lam_g
        set_casadi_blas_threads(self.cfg.blas_threads)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            sol = solver(**args)
            stats = solver.stats()
            status = str(stats["return_status"])
            self.iter_counts.append(int(stats.get("iter_count", -1)))
        except RuntimeError as exc:  # IPOPT may raise on evaluation errors
            sol, status = None, f"error: {exc}"
        solve_s = time.perf_counter() - t0
        self.solve_cpu_s.append(time.process_time() - c0)
        self.n_solves += 1
        self.solve_times_s.append(solve_s)
        if status == CPU_CAP_STATUS:
            self.n_cpu_capped += 1
        if sol is not None and status in _LIMIT_STATUS and self._usable_iterate(sol, x0, dmat, u_prev, p):
            status = f"Suboptimal_Feasible ({status})"
            self.n_suboptimal += 1
        elif sol is None or status not in _OK_STATUS:
            return self._fallback(x0, dmat[:, 0], occupancy_pct, status, solve_s)
        z = sol["x"].full().ravel()
        self._store_shifted(z, sol["lam_x"].full().ravel(), sol["lam_g"].full().ravel())
        _, r, s, _ = self.lay.split(z)
        rates = np.clip(r[:, 0], self.cfg.rate_min, self.cfg.rate_max)
        rates_vph = rates * self.net.orig_cap_vph[self.net.metered_idx]
        for a, rv in zip(self.alineas, rates_vph):
            a.rate_vph = float(rv)  # bumpless transfer to the fallback
        return MPCResult(rates=rates, rates_vph=rates_vph, split=s[:, 0].copy(), status=status,
                         solve_s=solve_s, fallback=False, predicted_tts=float(sol["f"]))

    def _usable_iterate(self, sol: dict[str, Any], x0: np.ndarray, dmat: np.ndarray, u_prev: np.ndarray,
                        p: np.ndarray) -> bool:
        """The last iterate is feasible (dynamics, storage rows, bounds) and costs less than holding
        the current inputs over the horizon (a feasible plan the controller could apply anyway)."""
        if not self.cfg.accept_improving_iterate:
            return False
        z, g = sol["x"].full().ravel(), sol["g"].full().ravel()
        viol = max(float(np.max(np.maximum(self._lbg - g, 0.0), initial=0.0)),
                   float(np.max(np.maximum(g - self._ubg, 0.0), initial=0.0)),
                   float(np.max(np.maximum(self._lbz - z, 0.0), initial=0.0)),
                   float(np.max(np.maximum(z - self._ubz, 0.0), initial=0.0)))
        f0 = float(self._tts_fun(self._hold_plan(x0, dmat, u_prev), p))
        return viol <= self.cfg.feasibility_tol and float(sol["f"]) < f0 - 1e-9 * max(1.0, abs(f0))

    def _fallback(self, x0: np.ndarray, d_now: np.ndarray, occupancy_pct: np.ndarray | None,
                  status: str, solve_s: float) -> MPCResult:
        """ALINEA rates for every meter and the default split; counts the event."""
        net = self.net
        self.n_fallbacks += 1
        self._warm.valid = False
        rho, _, w = net.split_x(x0)
        split = net.split_default.copy()
        d_orig = _origin_demand_now(net, d_now, split)
        rates_vph = np.zeros(net.n_metered)
        for k, j in enumerate(net.metered_idx):
            occ = (occupancy_pct[k] if occupancy_pct is not None
                   else occupancy_from_density(rho[int(net.orig_seg[j])], self.cfg.occupancy_eff_length_m))
            rates_vph[k] = self.alineas[k].step(float(occ), float(w[j]), float(d_orig[j]))
        rates = rates_vph / net.orig_cap_vph[net.metered_idx]
        return MPCResult(rates=rates, rates_vph=rates_vph, split=split, status=status, solve_s=solve_s,
                         fallback=True, predicted_tts=math.nan)

    def solve_time_stats(self) -> dict[str, float]:
        """p50/p95/max of the solve wall times so far [s] and the fallback count."""
        t = np.asarray(self.solve_times_s) if self.solve_times_s else np.array([math.nan])
        return {"p50_s": float(np.percentile(t, 50)), "p95_s": float(np.percentile(t, 95)),
                "max_s": float(np.max(t)), "solves": float(self.n_solves), "fallbacks": float(self.n_fallbacks)}


def _shift_cols(a: np.ndarray, k: int) -> np.ndarray:
    """Columns k.. of ``a`` followed by its last column k times."""
    return np.hstack([a[:, k:], np.repeat(a[:, -1:], k, axis=1)])


def _origin_demand_now(net: MetanetNetwork, d_now: np.ndarray, split: np.ndarray) -> np.ndarray:
    """Demand of each origin [veh/h] for the current disturbance and split."""
    dem = d_now[net.orig_source].astype(float)
    for j in range(net.n_orig):
        g = int(net.orig_split[j])
        if g >= 0:
            dem[j] *= split[g] if net.orig_split_a[j] else 1.0 - split[g]
    return dem


Policy = Callable[[int, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def closed_loop(net: MetanetNetwork, policy: Policy | None, x0: np.ndarray, d_seq: np.ndarray,
                steps_per_ctrl: int) -> SimResult:
    """Run the pure model with a controller deciding every ``steps_per_ctrl`` model steps.

    ``policy(k, x, d_future, u_prev) -> u`` gets the current state, the disturbances from step k on
    (a perfect forecast, as in Hegyi et al. 2005) and the last input; None means no control.
    """
    f = net.function
    K = d_seq.shape[0]
    xs, us = np.zeros((K + 1, net.nx)), np.zeros((K, net.nu))
    qs, qo = np.zeros((K, net.n_seg)), np.zeros((K, net.n_orig))
    xs[0], u = x0, net.default_u()
    for k in range(K):
        if policy is not None and k % steps_per_ctrl == 0:
            u = np.asarray(policy(k, xs[k], d_seq[k:], u), dtype=float)
        xn, q, q_o = f(xs[k], u, d_seq[k])
        xs[k + 1], qs[k], qo[k], us[k] = xn.full().ravel(), q.full().ravel(), q_o.full().ravel(), u
    tts = float(sum(total_time_spent_step(xs[k + 1], net) for k in range(K)))
    return SimResult(x=xs, q_seg_vph=qs, q_orig_vph=qo, u=us, tts_veh_h=tts)


def mpc_policy(mpc: RampMeteringMPC, log: list[MPCResult] | None = None) -> Policy:
    """Wrap an MPC as a ``closed_loop`` policy; results are appended to ``log`` if given."""

    def policy(k: int, x: np.ndarray, d_future: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        del k
        res = mpc.solve(x, d_future, u_prev)
        if log is not None:
            log.append(res)
        return res.u

    return policy


def alinea_policy(net: MetanetNetwork, cfg: MPCConfig | None = None) -> Policy:
    """ALINEA on every meter (model density as occupancy, model queue), default route split."""
    c = cfg or MPCConfig()
    meters = [Alinea(alinea_config_for(net, int(j), c)) for j in net.metered_idx]

    def policy(k: int, x: np.ndarray, d_future: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        del k, u_prev
        rho, _, w = net.split_x(x)
        dem = _origin_demand_now(net, d_future[0], net.split_default)
        occ = occupancy_from_density(rho[net.orig_seg[net.metered_idx]], c.occupancy_eff_length_m)
        rates = [m.step(float(o), float(w[j]), float(dem[j])) / float(net.orig_cap_vph[j])
                 for m, o, j in zip(meters, occ, net.metered_idx)]
        return np.concatenate([rates, net.split_default])

    return policy
