"""Ramp-metering MPC: feasible bounded rates on a small beltway, warm start, ALINEA fallback."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.ramp_metering.alinea import occupancy_from_density
from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
from corridor.traffic.macro.metanet import steady_state
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway

LAYOUT = BeltwayLayout(n_interchanges=3, lanes=2, ramp_storage_veh=40.0)


def congested_case() -> tuple:
    """A 3-interchange beltway near capacity with half-full ramp queues and heavy demand."""
    net = beltway(LAYOUT)
    x0 = steady_state(net, 30.0)
    x0[2 * net.n_seg:] = 20.0
    demand = np.full(net.nd, 2400.0)  # [veh/h] per interchange
    return net, x0, demand


def test_mpc_returns_feasible_rates_within_bounds() -> None:
    net, x0, demand = congested_case()
    cfg = MPCConfig(horizon_ctrl_steps=3, rate_min=0.1)
    mpc = RampMeteringMPC(net, cfg)
    res = mpc.solve(x0, demand, net.default_u())
    assert not res.fallback and res.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert res.rates.shape == (net.n_metered,) and res.split.shape == (net.n_split,)
    assert np.all(res.rates >= cfg.rate_min - 1e-8) and np.all(res.rates <= cfg.rate_max + 1e-8)
    assert np.all(res.split >= net.split_lo - 1e-8) and np.all(res.split <= net.split_hi + 1e-8)
    np.testing.assert_allclose(res.rates_vph, res.rates * net.orig_cap_vph[net.metered_idx])
    # the optimum is no worse than holding the previous input (the solver's feasible initial guess)
    p = np.concatenate([x0, mpc.forecast_matrix(demand).ravel(order="F"), net.default_u()])
    mpc._warm.valid = False
    z_hold = mpc._initial_guess(x0, mpc.forecast_matrix(demand), net.default_u())
    hold_tts = float(mpc._tts_fun(z_hold, p))
    assert res.predicted_tts <= hold_tts * (1.0 + 1e-5)  # up to IPOPT's tolerance (MPCConfig.tol = 1e-5)
    # queues of the plan respect storage up to the soft-constraint slack, which should be ~0 here
    xs, _, _, sig = mpc.lay.split(mpc._warm.z)
    assert np.max(sig) < 1.0


def test_warm_start_is_kept_and_reused() -> None:
    net, x0, demand = congested_case()
    mpc = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3))
    first = mpc.solve(x0, demand, net.default_u())
    assert mpc._warm.valid
    second = mpc.solve(x0, demand, first.u)
    assert not second.fallback
    assert mpc.solve_time_stats()["solves"] == 2.0


@pytest.mark.parametrize("cfg", [MPCConfig(horizon_ctrl_steps=3, max_iter=1),
                                 MPCConfig(horizon_ctrl_steps=3, max_cpu_time_s=1e-6)])
def test_solver_failure_falls_back_to_alinea(cfg: MPCConfig) -> None:
    net, _, demand = congested_case()
    x0 = steady_state(net, 40.0)  # above critical density 33.5 and empty queues: pure ALINEA law
    mpc = RampMeteringMPC(net, cfg)
    res = mpc.solve(x0, demand, net.default_u())
    assert res.fallback and mpc.n_fallbacks == 1 and not mpc._warm.valid
    assert np.isnan(res.predicted_tts)
    np.testing.assert_allclose(res.split, net.split_default)
    # ALINEA starts open (rate_max * capacity) and integrates once: r = clip(C + K (o_set - o))
    cap = net.orig_cap_vph[net.metered_idx]
    occ = occupancy_from_density(x0[net.orig_seg[net.metered_idx]], cfg.occupancy_eff_length_m)
    o_set = occupancy_from_density(net.rho_crit[net.orig_seg[net.metered_idx]], cfg.occupancy_eff_length_m)
    expected = np.clip(cap + 70.0 * (o_set - occ), cfg.rate_min * cap, cfg.rate_max * cap)
    np.testing.assert_allclose(res.rates_vph, expected)
    assert np.all(res.rates_vph < cap)  # the law bites: occupancy above its set point closes the meter


def test_iteration_limit_applies_a_feasible_improving_iterate_instead_of_falling_back() -> None:
    """Suboptimal MPC: stopped 3 iterations short, the last iterate is feasible and beats holding the
    inputs, so it is applied (not ALINEA); its cost lies between the optimum and the hold plan."""
    net, _, demand = congested_case()
    x0 = steady_state(net, 45.0)
    x0[2 * net.n_seg:] = 30.0
    full = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3))
    opt = full.solve(x0, demand, net.default_u())
    n_opt = full.iter_counts[-1]
    short = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, max_iter=n_opt - 3))
    res = short.solve(x0, demand, net.default_u())
    assert not res.fallback and res.status.startswith("Suboptimal_Feasible")
    assert short.n_suboptimal == 1 and short.n_fallbacks == 0
    dmat = short.forecast_matrix(demand)
    p = np.concatenate([x0, dmat.ravel(order="F"), net.default_u()])
    hold = float(short._tts_fun(short._hold_plan(x0, dmat, net.default_u()), p))
    # (an iterate within the feasibility tolerance may undercut the optimum by a hair)
    assert opt.predicted_tts - 1e-3 <= res.predicted_tts < hold - 1e-3
    assert np.all((res.rates >= 0.0) & (res.rates <= 1.0))
    strict = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, max_iter=n_opt - 3, accept_improving_iterate=False))
    assert strict.solve(x0, demand, net.default_u()).fallback


def test_mumps_ordering_is_chosen_by_problem_size_unless_configured() -> None:
    from corridor.controllers.ramp_metering.mpc import METIS_FROM_VARIABLES, pivot_order_for

    assert pivot_order_for(METIS_FROM_VARIABLES - 1, None) == 7  # MUMPS's own choice for small NLPs
    assert pivot_order_for(METIS_FROM_VARIABLES, None) == 5  # METIS from there on
    assert pivot_order_for(10**6, 0) == 0  # a configured ordering always wins
    net, x0, demand = congested_case()
    small = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3))
    assert small.pivot_order == 7 and small.lay.offsets[-1] < METIS_FROM_VARIABLES
    # the ordering changes the pivots' round-off only: the same plan up to IPOPT's tolerance
    metis = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, mumps_pivot_order=5))
    a, b = small.solve(x0, demand, net.default_u()), metis.solve(x0, demand, net.default_u())
    assert not a.fallback and not b.fallback
    assert abs(a.predicted_tts - b.predicted_tts) <= 1e-4 * abs(a.predicted_tts)
    np.testing.assert_allclose(a.u, b.u, atol=1e-3)


def test_dual_warm_start_reaches_the_primal_warm_starts_plan() -> None:
    """Receding steps with the shifted multipliers (opt-in) end at the same plans as without them."""
    net, x0, demand = congested_case()
    plain = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3))
    duals = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=3, warm_start_duals=True))
    u_a = u_b = net.default_u()
    for _ in range(3):
        a, b = plain.solve(x0, demand, u_a), duals.solve(x0, demand, u_b)
        assert not a.fallback and not b.fallback
        assert abs(a.predicted_tts - b.predicted_tts) <= 1e-4 * abs(a.predicted_tts)
        np.testing.assert_allclose(a.u, b.u, atol=1e-3)
        u_a, u_b = a.u, b.u
    assert duals._warm.lam_x is not None and duals._warm_solver is not None  # the warm solver was used


def test_prediction_model_has_a_finite_jacobian_at_negative_density() -> None:
    """The NLP's states are free, so an iterate may hold a negative density: the prediction model's
    equilibrium speed takes the smooth positive part there (the plain model's is NaN)."""
    import casadi as ca

    net, x0, d = congested_case()
    mpc = RampMeteringMPC(net, MPCConfig(horizon_ctrl_steps=1))
    x = ca.SX.sym("x", net.nx)
    u = net.default_u()
    jac = ca.Function("j", [x], [ca.jacobian(mpc._pred_f(x, u, d)[0], x)])
    bad = np.array(x0, dtype=float)
    bad[0] = -0.5  # [veh/km/lane]
    assert np.all(np.isfinite(jac(bad).full()))
    plain = ca.Function("p", [x], [ca.jacobian(net.function(x, u, d)[0], x)])
    assert not np.all(np.isfinite(plain(bad).full()))
    # away from zero both models agree (to the smoothing's size)
    good = mpc._pred_f(x0, u, d)[0].full().ravel() - net.function(x0, u, d)[0].full().ravel()
    assert np.max(np.abs(good[: 2 * net.n_seg])) < 5.0  # the other smoothings (origin flows, destinations)
