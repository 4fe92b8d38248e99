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

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from corridor.controllers.parking.geometry import Obstacles, VehicleGeometry, footprint
from corridor.controllers.parking.search import Segment


@dataclass(frozen=True)
class OptimiseParams:
    margin_m: float = 0.03  # footprint growth inside the corridor boxes
    grow_step_m: float = 0.1
    grow_max_m: float = 2.0  # per side
    spacing_m: float = 0.25  # about one node per this much path
    min_nodes: int = 40
    max_nodes: int = 300
    effort_weight: float = 0.5  # on ∫ a² + 2 ω² dt, beside the manoeuvre time
    warm_speed_mps: float = 1.5


class OptimiseFailed(Exception):
    pass


@dataclass(frozen=True)
class Solution:
    h_s: float  # interval length
    states: np.ndarray  # (N+1, 5): x, y, θ, v, δ
    inputs: np.ndarray  # (N, 2): a, ω


def warm_start(segments: list[Segment], veh: VehicleGeometry, p: OptimiseParams) -> tuple[np.ndarray, float]:
    """(N+1, 5) states at uniform times along the path and the total time T [s]: trapezoidal speed in
    each run between direction changes, steering from the path's curvature."""
    runs: list[list[Segment]] = []
    for seg in segments:
        if runs and np.sign(runs[-1][-1].length_m) == np.sign(seg.length_m):
            runs[-1].append(seg)
        else:
            runs.append([seg])
    total = sum(abs(s.length_m) for s in segments)
    n = int(np.clip(np.ceil(total / p.spacing_m) + 8 * len(runs), p.min_nodes, p.max_nodes))
    acc = 0.5 * veh.max_accel_mps2
    durations = []
    for run in runs:
        L = sum(abs(s.length_m) for s in run)
        vp = min(p.warm_speed_mps, np.sqrt(L * acc))
        durations.append(2 * vp / acc + max(0.0, L - vp ** 2 / acc) / vp)
    T = float(sum(durations))
    t = np.linspace(0.0, T, n + 1)
    out = np.zeros((n + 1, 5))
    t0 = 0.0
    for run, dur in zip(runs, durations, strict=True):
        m = (t >= t0 - 1e-12) & (t <= t0 + dur + 1e-12)
        L = sum(abs(s.length_m) for s in run)
        vp = min(p.warm_speed_mps, np.sqrt(L * acc))
        tau = np.clip(t[m] - t0, 0.0, dur)
        r = vp / acc
        s = np.where(tau < r, 0.5 * acc * tau ** 2, np.where(tau > dur - r, L - 0.5 * acc * (dur - tau) ** 2,
                                                              0.5 * acc * r ** 2 + vp * (tau - r)))
        v = np.where(tau < r, acc * tau, np.where(tau > dur - r, acc * (dur - tau), vp))
        out[m] = _along(run, s, np.sign(run[0].length_m) * v, veh)
        t0 += dur
    out[0, 3:] = 0.0
    out[-1, 3] = 0.0
    return out, T


def _along(run: list[Segment], s: np.ndarray, v: np.ndarray, veh: VehicleGeometry) -> np.ndarray:
    """States at distances s along one run of same-direction segments."""
    from corridor.controllers.parking import reeds_shepp as rs

    ends = np.cumsum([abs(seg.length_m) for seg in run])
    idx = np.clip(np.searchsorted(ends, s, side="left"), 0, len(run) - 1)
    out = np.zeros((len(s), 5))
    for i, seg in enumerate(run):
        m = idx == i
        if m.any():
            local = s[m] - (ends[i] - abs(seg.length_m))
            out[m, :3] = rs.arc(*seg.start, np.sign(seg.length_m) * local, seg.kappa)
            out[m, 4] = np.arctan(seg.kappa * veh.wheelbase_m)
    out[:, 3] = v
    return out


def corridors(states: np.ndarray, obstacles: Obstacles, veh: VehicleGeometry, p: OptimiseParams) -> np.ndarray:
    """(N+1, 4) box extents (x_min, x_max, y_min, y_max) in the frame of each warm-start pose."""
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
    return ext


def solve(segments: list[Segment], obstacles: Obstacles, veh: VehicleGeometry, deadline: float,
          p: OptimiseParams | None = None) -> Solution:
    """Optimal trajectory from the first segment's start to the last segment's end (local frame)."""
    p = p or OptimiseParams()
    ws, T0 = warm_start(segments, veh, p)
    boxes = corridors(ws, obstacles, veh, p)
    n = len(ws) - 1
    X, U, T = ca.SX.sym("X", 5, n + 1), ca.SX.sym("U", 2, n), ca.SX.sym("T")
    h = T / n
    F = _rk4(veh)
    g, lbg, ubg = [], [], []
    nxt = ca.horzcat(*[F(X[:, k], U[:, k], h) for k in range(n)])
    g.append(ca.vec(X[:, 1:] - nxt))
    lbg += [0.0] * (5 * n)
    ubg += [0.0] * (5 * n)
    bx0, bx1, by0, by1 = veh.box(p.margin_m)
    local = [(bx0, by0), (bx1, by0), (bx1, by1), (bx0, by1)]
    for k in range(n + 1):
        ck, sk = np.cos(ws[k, 2]), np.sin(ws[k, 2])
        for j in (k, min(k + 1, n)):
            for a, b in local:
                px = X[0, j] + ca.cos(X[2, j]) * a - ca.sin(X[2, j]) * b - ws[k, 0]
                py = X[1, j] + ca.sin(X[2, j]) * a + ca.cos(X[2, j]) * b - ws[k, 1]
                g += [ck * px + sk * py, -sk * px + ck * py]
                lbg += [boxes[k, 0], boxes[k, 2]]
                ubg += [boxes[k, 1], boxes[k, 3]]
    effort = ca.sumsqr(U[0, :]) + 2 * ca.sumsqr(U[1, :])
    cost = T + p.effort_weight * effort * h
    z = ca.vertcat(ca.vec(X), ca.vec(U), T)
    lbx, ubx = _bounds(ws, n, veh, T0)
    x0 = np.concatenate([ws.ravel(), np.zeros(2 * n), [T0]])
    remaining = deadline - time.perf_counter()
    if remaining <= 0.05:
        raise OptimiseFailed("no time left for the optimisation")
    opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": 1000,
            "ipopt.tol": 1e-6, "ipopt.max_wall_time": remaining, "ipopt.linear_solver": "mumps",
            "ipopt.mu_strategy": "adaptive"}
    nlp = ca.nlpsol("parking", "ipopt", {"x": z, "f": cost, "g": ca.vertcat(*g)}, opts)
    res = nlp(x0=x0, lbx=lbx, ubx=ubx, lbg=np.asarray(lbg), ubg=np.asarray(ubg))
    status = nlp.stats()["return_status"]
    if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level"):
        raise OptimiseFailed(f"IPOPT: {status}")
    zs = np.asarray(res["x"]).ravel()
    states = zs[:5 * (n + 1)].reshape(n + 1, 5)
    inputs = zs[5 * (n + 1):5 * (n + 1) + 2 * n].reshape(n, 2)
    return Solution(h_s=float(zs[-1]) / n, states=states, inputs=inputs)


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
    lbx = np.concatenate([lo_x.ravel(), lo_u.ravel(), [0.2 * T0]])
    ubx = np.concatenate([hi_x.ravel(), hi_u.ravel(), [5.0 * T0]])
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
