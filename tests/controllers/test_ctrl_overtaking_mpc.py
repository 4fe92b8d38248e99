"""The overtaking MPC on its own: smooth operators are sound, plans satisfy the spec, infeasible gaps
are refused, and a follow plan settles at the closed-form time gap."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from corridor.controllers.overtaking.controller import OvertakingParams
from corridor.controllers.overtaking.mpc import (
    FAR_M,
    MpcProblem,
    OvertakingMilp,
    _smax,
    _smin,
    body_centre,
    cached_mpc,
    rollout_guess,
    spec_margins,
)
from corridor.vehicles.ground.bicycle import rk4_step

P = OvertakingParams()
MPC = cached_mpc(P.mpc, P.ego, P.road)
N = P.mpc.horizon_steps
TS = np.arange(N + 1) * P.mpc.dt_s


def _problem(lead_gap_m: float, v_lead: float, onc_at_m: float | None, v_onc: float, mode: str) -> MpcProblem:
    x0 = np.array([0.0, 0.0, 0.0, v_lead])
    lead = 0.5 * P.ego.wheelbase_m + 4.5 + lead_gap_m + v_lead * TS
    onc = np.full((P.mpc.max_oncoming, N + 1), FAR_M)
    onc_v = np.zeros(P.mpc.max_oncoming)
    if onc_at_m is not None:
        onc[0], onc_v[0] = onc_at_m - v_onc * TS, -v_onc
    mask = (TS >= TS[-1] - 1e-9).astype(float) if mode == "pass" else np.zeros(N + 1)
    v_ref = P.mpc.speed_limit_mps if mode == "pass" else 26.0
    return MpcProblem(x0, np.zeros(2), lead, onc, onc_v, v_ref, 0.0, mask)


def _pass_guess(prob: MpcProblem) -> tuple[np.ndarray, np.ndarray]:
    def lateral(k: int, x: np.ndarray) -> float:
        return 0.0 if x[0] - prob.lead_x[k] > 16.0 else P.road.lane_width_m
    return rollout_guess(prob.x0, lateral, lambda k, x: P.mpc.speed_limit_mps, P.mpc, P.ego)


def test_smooth_max_and_min_under_approximate() -> None:
    x = ca.SX.sym("x", 3)
    fmax = ca.Function("smax", [x], [_smax([x[0], x[1], x[2]], 3.0)])
    fmin = ca.Function("smin", [x], [_smin([x[0], x[1], x[2]], 3.0)])
    rng = np.random.default_rng(0)
    for v in rng.normal(0.0, 5.0, size=(500, 3)):
        smax, smin = float(fmax(v)), float(fmin(v))
        assert smax <= v.max() + 1e-12 and smax >= v.max() - np.log(3) / 3.0 - 1e-12
        assert smin <= v.min() + 1e-12 and smin >= v.min() - np.log(3) / 3.0 - 1e-12


def test_follow_plan_settles_at_time_gap() -> None:
    prob = _problem(lead_gap_m=40.0, v_lead=18.0, onc_at_m=None, v_onc=0.0, mode="follow")
    sol = MPC.solve(prob, *rollout_guess(prob.x0, lambda k, x: 0.0, lambda k, x: 18.0, P.mpc, P.ego))
    assert sol.ok, sol.status
    xc = body_centre(sol.states, P.ego.wheelbase_m)[0]
    gap = prob.lead_x - xc - 4.5  # bumper gap
    want = P.mpc.lead_standstill_gap_m + P.mpc.lead_time_gap_s * sol.states[:, 3]
    assert np.all(gap >= want - 1e-3)  # never closer than the spec allows
    assert gap[-1] - want[-1] < 1.0  # and it closes up to it (cost wants 26 m/s > lead speed)
    assert np.max(np.abs(sol.states[:, 1])) < 0.05  # stays in lane


def test_pass_plan_completes_and_satisfies_spec() -> None:
    prob = _problem(lead_gap_m=20.0, v_lead=16.0, onc_at_m=600.0, v_onc=22.0, mode="pass")
    sol = MPC.solve(prob, *_pass_guess(prob))
    assert sol.ok, sol.status
    m = spec_margins(sol.states, prob.lead_x, prob.oncoming_x, prob.oncoming_v, P.mpc, P.ego, P.road)
    assert m["lead"][1:].min() >= -1e-3 and m["oncoming"][1:].min() >= -1e-3
    assert m["done"][-1] >= -1e-3  # ahead of the lead and back in lane at the deadline
    assert sol.states[:, 1].max() > 2.0  # it really used the oncoming lane
    # the inputs reproduce the states through the shared RK4 step (multiple shooting is consistent)
    for k in range(N):
        assert rk4_step(sol.states[k], sol.inputs[k], P.mpc.dt_s, P.ego) == pytest.approx(sol.states[k + 1], abs=1e-4)
    assert np.all(sol.states[:, 3] <= P.mpc.speed_limit_mps + 1e-6)


def test_pass_refused_when_oncoming_too_close() -> None:
    prob = _problem(lead_gap_m=20.0, v_lead=16.0, onc_at_m=200.0, v_onc=25.0, mode="pass")
    sol = MPC.solve(prob, *_pass_guess(prob))
    assert not sol.ok


def test_warm_start_is_not_slower_than_cold() -> None:
    """Shifting the previous plan as the initial guess must need no more IPOPT iterations than a cold
    start (iterations, not wall time: the machine is shared)."""
    prob = _problem(lead_gap_m=20.0, v_lead=16.0, onc_at_m=700.0, v_onc=22.0, mode="pass")
    cold = MPC.solve(prob, *_pass_guess(prob))
    iters_cold = MPC._solver.stats()["iter_count"]
    warm = MPC.solve(prob, cold.states, cold.inputs)
    iters_warm = MPC._solver.stats()["iter_count"]
    assert cold.ok and warm.ok
    assert iters_warm < iters_cold


def test_big_m_milp_agrees_on_clear_cases() -> None:
    """The mixed-integer encoding finds a pass when the road is clear (and its plan, replayed in the
    nonlinear bicycle, satisfies the spec) and refuses one into a close oncoming car."""
    milp = OvertakingMilp(MPC)
    clear = milp.solve(_problem(lead_gap_m=20.0, v_lead=16.0, onc_at_m=700.0, v_onc=22.0, mode="pass"))
    assert clear.ok and clear.robustness_m >= 0.0 and clear.states[:, 1].max() > 2.0
    blocked = milp.solve(_problem(lead_gap_m=20.0, v_lead=16.0, onc_at_m=200.0, v_onc=25.0, mode="pass"))
    assert not blocked.ok
