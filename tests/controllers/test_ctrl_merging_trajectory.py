"""Energy-optimal merging trajectory: boundary conditions, energy, limits and the feasible window."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from corridor.controllers.merging.trajectory import (
    MotionLimits,
    boundary_system,
    cubic_coefficients,
    feasible_horizon,
    merge_accel,
    min_time_to_go,
    plan,
)

CASES = [
    (-250.0, 18.0, 3.0, 16.0, 0.0, 22.0),
    (-100.0, 25.0, 10.0, 15.0, 0.0, 20.0),
    (5.0, 10.0, 0.0, 9.0, 120.0, 14.0),
]


@pytest.mark.parametrize(("x0", "v0", "t0", "tf", "L", "vf"), CASES)
@pytest.mark.parametrize("free_speed", [False, True])
def test_boundary_conditions_and_stationarity(x0, v0, t0, tf, L, vf, free_speed) -> None:
    vf_arg = None if free_speed else vf
    tr = plan(x0, v0, t0, tf, L, vf=vf_arg, limits=MotionLimits(v_max_mps=60, a_min_mps2=-20, a_max_mps2=20))
    assert tr.pos(t0) == pytest.approx(x0, abs=1e-9) and tr.vel(t0) == pytest.approx(v0, abs=1e-9)
    assert tr.pos(tf) == pytest.approx(L, abs=1e-9)
    if free_speed:
        assert tr.accel_unconstrained(tf) == pytest.approx(0.0, abs=1e-9)  # transversality u(tf) = 0
    else:
        assert tr.vel(tf) == pytest.approx(vf, abs=1e-9)
    # the control is linear in time and consistent with the cubic: v' = u, x' = v (finite differences)
    ts = np.linspace(t0 + 0.1, tf - 0.1, 7)
    h = 1e-5
    assert (tr.vel(ts + h) - tr.vel(ts - h)) / (2 * h) == pytest.approx(tr.accel_unconstrained(ts), abs=1e-5)
    assert (tr.pos(ts + h) - tr.pos(ts - h)) / (2 * h) == pytest.approx(tr.vel(ts), abs=1e-5)
    assert np.diff(tr.accel_unconstrained(ts), 2) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(("x0", "v0", "t0", "tf", "L", "vf"), CASES)
def test_energy_closed_form_and_optimality(x0, v0, t0, tf, L, vf) -> None:
    tr = plan(x0, v0, t0, tf, L, vf=vf)
    numeric, _ = quad(lambda t: 0.5 * tr.accel_unconstrained(t) ** 2, t0, tf)
    assert tr.energy() == pytest.approx(numeric, rel=1e-9)
    # any admissible perturbation (vanishing with its derivative at both ends) costs more energy
    T = tf - t0
    for eps in (0.3, -0.2):

        def u_pert(t: float, eps: float = eps) -> float:
            s = (t - t0) / T  # du = eps * d²/dt² [s²(1-s)²] keeps x, v at both ends
            return tr.accel_unconstrained(t) + eps * (2 - 12 * s + 12 * s**2) / T**2 * 10

        e_pert, _ = quad(lambda t: 0.5 * u_pert(t) ** 2, t0, tf)
        assert e_pert > tr.energy()
    # free terminal speed is the unconstrained minimum over vf
    free = plan(x0, v0, t0, tf, L)
    assert free.energy() <= tr.energy() + 1e-12
    for dv in (-1.0, 1.0):
        assert plan(x0, v0, t0, tf, L, vf=float(free.vel(tf)) + dv).energy() > free.energy()


@pytest.mark.parametrize("vf", [15.0, None])
def test_coefficients_solve_the_4x4_boundary_system(vf) -> None:
    coef = cubic_coefficients(3.0, 12.0, 8.0, 150.0, vf)
    m, r = boundary_system(3.0, 12.0, 8.0, 150.0, vf)
    assert m @ coef == pytest.approx(r, abs=1e-9)
    assert coef == pytest.approx(np.linalg.solve(m, r), rel=1e-8)


def test_infeasible_time_reports_feasible_window() -> None:
    lim = MotionLimits(v_min_mps=0.0, v_max_mps=30.0, a_min_mps2=-3.0, a_max_mps2=2.0)
    tr = plan(0.0, 20.0, 0.0, 7.0, 200.0, vf=20.0, limits=lim)  # needs u(0) = 7.35 m/s² > 2
    assert not tr.feasible
    assert tr.accel(0.0) == pytest.approx(2.0)  # saturated command
    assert tr.earliest_s > 7.0 and tr.latest_s > tr.earliest_s
    for t_edge in (tr.earliest_s, tr.latest_s):
        assert plan(0.0, 20.0, 0.0, t_edge, 200.0, vf=20.0, limits=lim).feasible
    assert not plan(0.0, 20.0, 0.0, tr.earliest_s - 1e-3, 200.0, vf=20.0, limits=lim).feasible
    assert not plan(0.0, 20.0, 0.0, tr.latest_s + 1e-3, 200.0, vf=20.0, limits=lim).feasible
    # limit case: at the earliest time the binding constraint is active (u(0) = a_max here)
    edge = plan(0.0, 20.0, 0.0, tr.earliest_s, 200.0, vf=20.0, limits=lim)
    u0, u_end = edge.accel_unconstrained(0.0), edge.accel_unconstrained(edge.tf_s)
    assert max(u0, u_end) == pytest.approx(2.0, abs=1e-6) or min(u0, u_end) == pytest.approx(-3.0, abs=1e-6)
    # coasting at 20 m/s takes 10 s: feasible and zero energy
    coast = plan(0.0, 20.0, 0.0, 10.0, 200.0, vf=20.0, limits=lim)
    assert coast.feasible and coast.energy() == pytest.approx(0.0, abs=1e-12)
    assert feasible_horizon(20.0, 200.0, lim, vf=20.0) == pytest.approx((tr.earliest_s, tr.latest_s))
    # free speed: slow arrival would need negative speed beyond T = 3 D / v0 / ... -> window bounded
    lo, hi = feasible_horizon(20.0, 200.0, lim)
    assert hi == pytest.approx(30.0, rel=1e-6)  # v(T) = v0 + 3 (D - v0 T) / (2T) = 0 at T = 30 s


def test_closed_loop_receding_horizon_reaches_merge_on_time() -> None:
    lim = MotionLimits()
    x, v, t, dt, tf, L = -200.0, 15.0, 0.0, 0.01, 11.0, 0.0
    while t < tf - 1e-9:
        a = merge_accel(x, v, t, tf, L, vf=20.0, limits=lim)
        assert lim.a_min_mps2 - 1e-9 <= a <= lim.a_max_mps2 + 1e-9
        x, v, t = x + v * dt + 0.5 * a * dt**2, v + a * dt, t + dt
    assert x == pytest.approx(L, abs=0.5) and v == pytest.approx(20.0, abs=0.3)


def test_min_time_to_go_closed_forms() -> None:
    lim = MotionLimits(v_max_mps=30.0, a_max_mps2=2.0)
    assert min_time_to_go(100.0, 30.0, lim) == pytest.approx(100.0 / 30.0)
    assert min_time_to_go(25.0, 0.0, lim) == pytest.approx(5.0)  # ½ a t² = 25 m
    t_acc, d_acc = 5.0, 20.0 * 5.0 + 0.5 * 2.0 * 25.0  # 20 -> 30 m/s
    assert min_time_to_go(400.0, 20.0, lim) == pytest.approx(t_acc + (400.0 - d_acc) / 30.0)
    assert min_time_to_go(-1.0, 20.0, lim) == 0.0
    with pytest.raises(ValueError):
        plan(0.0, 10.0, 5.0, 5.0, 100.0)


def test_the_start_acceleration_in_python_floats_is_the_cubics_bit_for_bit() -> None:
    """``start_accel`` (merge_accel's command without the numpy 4-vector; issue 27's seventh CPU pass) is
    b of ``cubic_coefficients`` with the same bits, free or with a terminal speed, over short and long horizons."""
    from corridor.controllers.merging.trajectory import start_accel

    rng = np.random.default_rng(7)
    for _ in range(20000):
        v0, dist = float(rng.uniform(0.0, 35.0)), float(rng.uniform(0.0, 400.0))
        t = float(rng.choice([rng.uniform(0.3, 3.0), rng.uniform(3.0, 60.0), round(rng.uniform(0.3, 30.0), 1)]))
        vf = None if rng.random() < 0.3 else float(rng.uniform(0.0, 35.0))
        want = float(cubic_coefficients(0.0, v0, t, dist, vf)[1])
        assert start_accel(v0, t, dist, vf) == want
