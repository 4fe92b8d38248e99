"""Stage 2: minimum time-and-effort trajectory in CasADi/IPOPT, warm-started from the search path.

Kinematic bicycle (rear-axle reference) with states x, y, θ, v, δ and piecewise-constant inputs a and
ω = dδ/dt, multiple shooting (one RK4 step per interval of free length T/N). Limits on v, a, δ, ω are
variable bounds. Collision avoidance is a safe-travel corridor: for every node k an obstacle-free box,
oriented along the warm start's heading at k, grown side by side from the footprints of nodes k and
k+1; the corners of both footprints (grown by a margin) must stay in it. Both ends of every interval
lie in one convex obstacle-free box, so the swept footprint between nodes is covered up to the arc's
sagitta (millimetres), which the margin absorbs. The start and goal poses are equality constraints.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from corridor.controllers.parking.geometry import Obstacles, VehicleGeometry, footprint


@dataclass(frozen=True)
class OptimiseParams:
    margin_m: float = 0.03  # footprint growth inside the corridor boxes
    grow_step_m: float = 0.1
    grow_max_m: float = 2.0  # per side
    effort_weight: float = 0.5  # on ∫ a² + 2 ω² dt, beside the manoeuvre time
    jerk_weight: float = 0.05  # on ∫ (da/dt)² dt: no chattering of the speed about zero
    max_iter: int = 150  # IPOPT iterations (deterministic, unlike its wall-time cap)


class OptimiseFailed(Exception):
    pass


@dataclass(frozen=True)
class Solution:
    h_s: float  # interval length
    states: np.ndarray  # (N+1, 5): x, y, θ, v, δ
    inputs: np.ndarray  # (N, 2): a, ω
    iterations: int = 0  # IPOPT's


def corridors(states: np.ndarray, obstacles: Obstacles, veh: VehicleGeometry,
              p: OptimiseParams) -> tuple[np.ndarray, np.ndarray]:
    """(N+1, 4) box extents (x_min, x_max, y_min, y_max) in the frame of each warm-start pose, and
    whether each box also holds the next node (False where the pair does not fit: own footprint only)."""
    poses = states[:, :3]
    nxt = np.vstack([poses[1:], poses[-1:]])
    corners = np.concatenate([footprint(poses, veh, p.margin_m), footprint(nxt, veh, p.margin_m)], axis=1)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx, dy = corners[..., 0] - poses[:, 0:1], corners[..., 1] - poses[:, 1:2]
    lx, ly = c * dx + s * dy, -s * dx + c * dy
    ext = np.column_stack([lx.min(axis=1), lx.max(axis=1), ly.min(axis=1), ly.max(axis=1)])
    own = np.tile(np.asarray(veh.box(p.margin_m)), (len(poses), 1))
    bad = obstacles.collides_boxes(poses, ext)
    ext[bad] = own[bad]  # the pair does not fit: keep the node's own footprint
    if obstacles.collides_boxes(poses, ext).any():
        raise OptimiseFailed("the warm start touches an obstacle within the optimisation margin")
    active = np.ones((len(poses), 4), dtype=bool)
    sign = np.array([-1.0, 1.0, -1.0, 1.0])
    for _ in range(int(round(p.grow_max_m / p.grow_step_m))):
        for j in range(4):
            rows = np.flatnonzero(active[:, j])
            if len(rows) == 0:
                continue
            trial = ext[rows].copy()
            trial[:, j] += sign[j] * p.grow_step_m
            hit = obstacles.collides_boxes(poses[rows], trial)
            ext[rows[~hit]] = trial[~hit]
            active[rows[hit], j] = False
    return ext, ~bad


def solve(ws: np.ndarray, T0: float, obstacles: Obstacles, veh: VehicleGeometry,
          p: OptimiseParams | None = None) -> Solution:
    """Optimal trajectory from the warm start's first state to its last pose (local frame); ``ws`` is
    (N+1, 5) states at uniform times over T0 [s]."""
    p = p or OptimiseParams()
    boxes, pair = corridors(ws, obstacles, veh, p)
    n = len(ws) - 1
    nlp = _nlp(n, veh, p.margin_m, p.effort_weight, p.jerk_weight, p.max_iter)
    par = np.concatenate([ws[:, 0], ws[:, 1], ws[:, 2]])
    lo, hi = np.tile(boxes[:, [0, 2]], (1, 8)), np.tile(boxes[:, [1, 3]], (1, 8))
    lo[~pair, 8:], hi[~pair, 8:] = -np.inf, np.inf  # the next node is not held in this box
    lbg = np.concatenate([np.zeros(5 * n), lo.ravel()])
    ubg = np.concatenate([np.zeros(5 * n), hi.ravel()])
    lbx, ubx = _bounds(ws, n, veh, T0)
    x0 = np.concatenate([ws.T.ravel(), np.diff(ws[:, 3]) / (T0 / n), np.diff(ws[:, 4]) / (T0 / n), [T0]])
    res = nlp(x0=x0, p=par, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    stats = nlp.stats()
    status = stats["return_status"]
    if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level"):
        raise OptimiseFailed(f"IPOPT: {status}")
    zs = np.asarray(res["x"]).ravel()
    states = zs[:5 * (n + 1)].reshape(5, n + 1).T
    inputs = zs[5 * (n + 1):5 * (n + 1) + 2 * n].reshape(2, n).T
    return Solution(h_s=float(zs[-1]) / n, states=states, inputs=inputs, iterations=int(stats["iter_count"]))


LINEAR_SOLVER = "mumps"  # of the two shipped with CasADi's IPOPT (mumps, spral)
IPOPT_TOL = 1e-6


@lru_cache(maxsize=16)
def _nlp(n: int, veh: VehicleGeometry, margin_m: float, effort_weight: float, jerk_weight: float,
         max_iter: int) -> ca.Function:
    """The NLP for n intervals, parametrised by the warm start's poses (the corridor frames); the boxes,
    start and goal enter through the bounds. Cached: replanning with the same n reuses it."""
    z = ca.MX.sym("z", 5 * (n + 1) + 2 * n + 1)  # x_0..x_n, y_0.., θ.., v.., δ.., a_0.., ω.., T
    X = ca.reshape(z[:5 * (n + 1)], n + 1, 5).T
    U = ca.reshape(z[5 * (n + 1):-1], n, 2).T
    T = z[-1]
    P = ca.MX.sym("P", 3 * (n + 1))
    W = ca.horzcat(P[:n + 1], P[n + 1:2 * (n + 1)], P[2 * (n + 1):]).T  # (3, n+1) corridor frames
    h = T / n
    nxt = _rk4(veh).map(n)(X[:, :-1], U, h)
    g = [ca.vec(X[:, 1:] - nxt)]
    nodes1 = ca.horzcat(X[:3, 1:], X[:3, n])
    g.append(ca.vec(_corners_in_frame(veh, margin_m).map(n + 1)(X[:3, :], nodes1, W)))  # 16 per node
    effort = ca.sumsqr(U[0, :]) + 2 * ca.sumsqr(U[1, :])
    jerk = ca.sumsqr(U[0, 1:] - U[0, :-1]) / h ** 2
    opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
            "ipopt.tol": IPOPT_TOL, "ipopt.linear_solver": LINEAR_SOLVER,
            "ipopt.mu_strategy": "adaptive",
            "ipopt.acceptable_constr_viol_tol": 1e-6}  # "acceptable" only ever relaxes optimality
    return ca.nlpsol("parking", "ipopt", {"x": z, "p": P, "f": T + (effort_weight * effort + jerk_weight * jerk) * h,
                                          "g": ca.vertcat(*g)}, opts)


def _corners_in_frame(veh: VehicleGeometry, margin_m: float) -> ca.Function:
    """Corners of two footprints (node k and k+1) in the frame of pose w: 16 values, (along, across)
    pairs, node k's four corners first."""
    q0, q1, w = ca.SX.sym("q0", 3), ca.SX.sym("q1", 3), ca.SX.sym("w", 3)
    bx0, bx1, by0, by1 = veh.box(margin_m)
    cw, sw = ca.cos(w[2]), ca.sin(w[2])
    out = []
    for q in (q0, q1):
        c, s = ca.cos(q[2]), ca.sin(q[2])
        for a, b in ((bx0, by0), (bx1, by0), (bx1, by1), (bx0, by1)):
            px, py = q[0] + c * a - s * b - w[0], q[1] + s * a + c * b - w[1]
            out += [cw * px + sw * py, -sw * px + cw * py]
    return ca.Function("corners", [q0, q1, w], [ca.vertcat(*out)])


def _rk4(veh: VehicleGeometry) -> ca.Function:
    x, u, h = ca.SX.sym("x", 5), ca.SX.sym("u", 2), ca.SX.sym("h")

    def f(s: ca.SX) -> ca.SX:
        return ca.vertcat(s[3] * ca.cos(s[2]), s[3] * ca.sin(s[2]), s[3] * ca.tan(s[4]) / veh.wheelbase_m,
                          u[0], u[1])

    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return ca.Function("rk4", [x, u, h], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])


def _bounds(ws: np.ndarray, n: int, veh: VehicleGeometry, T0: float) -> tuple[np.ndarray, np.ndarray]:
    lo_x = np.tile([-np.inf, -np.inf, -np.inf, -veh.max_speed_mps, -veh.max_steer_rad], (n + 1, 1))
    hi_x = np.tile([np.inf, np.inf, np.inf, veh.max_speed_mps, veh.max_steer_rad], (n + 1, 1))
    lo_x[0] = hi_x[0] = [ws[0, 0], ws[0, 1], ws[0, 2], 0.0, 0.0]
    lo_x[-1, :4] = hi_x[-1, :4] = [ws[-1, 0], ws[-1, 1], ws[-1, 2], 0.0]
    lo_u = np.tile([-veh.max_accel_mps2, -veh.max_steer_rate_rps], (n, 1))
    hi_u = -lo_u
    lbx = np.concatenate([lo_x.T.ravel(), lo_u.T.ravel(), [0.2 * T0]])
    ubx = np.concatenate([hi_x.T.ravel(), hi_u.T.ravel(), [5.0 * T0]])
    return lbx, ubx


def sample(sol: Solution, veh: VehicleGeometry, dt_s: float) -> dict[str, np.ndarray]:
    """States every h/m ≤ dt_s: each interval integrated in m RK4 sub-steps of its constant inputs,
    starting from the solver's node (so rows stay on the model and end exactly at the last node)."""
    n = len(sol.inputs)
    m = max(1, int(np.ceil(sol.h_s / dt_s - 1e-9)))
    F = _rk4(veh)
    rows = [sol.states[0]]
    for k in range(n):
        s = sol.states[k]
        for j in range(m):
            s = sol.states[k + 1] if j == m - 1 else np.asarray(F(s, sol.inputs[k], sol.h_s / m)).ravel()
            rows.append(s)
    st = np.asarray(rows)
    a = np.concatenate([np.repeat(sol.inputs[:, 0], m), [0.0]])
    t = np.arange(len(st)) * sol.h_s / m
    return {"t": t, "x": st[:, 0], "y": st[:, 1], "theta": st[:, 2], "v": st[:, 3], "a": a, "steer": st[:, 4]}
