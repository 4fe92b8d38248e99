"""METANET model: hand-computed single-segment steps, symbolic/numeric agreement, conservation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from corridor.traffic.macro.metanet import (
    MetanetNetwork,
    MetanetParams,
    equilibrium_speed,
    simulate,
    steady_state,
    step,
    step_with_flows,
)
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway

T_H = 10.0 / 3600.0  # [h]


def one_segment(onramp: bool) -> MetanetNetwork:
    """1 km, 2 lanes, Hegyi fundamental diagram; a mainstream origin or a metered on-ramp feeds it."""
    return MetanetNetwork(
        name="one", length_km=np.array([1.0]), lanes=np.array([2.0]), v_free_kmh=np.array([102.0]),
        rho_crit=np.array([33.5]), a=np.array([1.867]), rho_max=np.array([180.0]),
        up=np.array([-1]), down=np.array([-1]), exit_frac=np.array([0.0]),
        orig_seg=np.array([0]), orig_cap_vph=np.array([2000.0 if onramp else 4000.0]),
        orig_metered=np.array([onramp]), orig_onramp=np.array([onramp]), orig_source=np.array([0]),
        orig_split=np.array([-1]), orig_split_a=np.array([False]), orig_storage_veh=np.array([np.inf]),
        n_sources=1, params=MetanetParams())


def test_equilibrium_speed_formula() -> None:
    # V(rho_crit) = v_free exp(-1/a); V(0) = v_free
    assert equilibrium_speed(33.5, 102.0, 33.5, 1.867) == pytest.approx(102.0 * math.exp(-1 / 1.867))
    assert equilibrium_speed(0.0, 102.0, 33.5, 1.867) == pytest.approx(102.0)


def test_mainstream_segment_hand_step() -> None:
    net = one_segment(onramp=False)
    x = np.array([20.0, 90.0, 0.0])  # rho [veh/km/lane], v [km/h], origin queue [veh]
    x_next, q, q_o = step_with_flows(x, np.zeros(0), np.array([3000.0, 0.0]), net)
    # q = 20*90*2 = 3600; q_o = min(3000 + 0/T, 1*4000, 4000*(180-20)/(180-33.5)=4368.6) = 3000
    assert q[0] == pytest.approx(3600.0)
    assert q_o[0] == pytest.approx(3000.0)
    # rho+ = 20 + T/(1*2) (3000 - 3600) = 20 - 600/720 = 19.16667
    assert x_next[0] == pytest.approx(20.0 - 600.0 / 720.0, rel=1e-12)
    # V(20) = 102 exp(-(20/33.5)^1.867 / 1.867) = 83.139; relaxation (10/18)(83.139 - 90) = -3.8117;
    # convection 0 (v_up = v at the boundary); anticipation 0 (rho_down = min(20, 33.5) = 20)
    v_eq = 102.0 * math.exp(-((20.0 / 33.5) ** 1.867) / 1.867)
    assert v_eq == pytest.approx(83.139, abs=1e-3)
    assert x_next[1] == pytest.approx(90.0 + (10.0 / 18.0) * (v_eq - 90.0), rel=1e-12)
    assert x_next[1] == pytest.approx(86.188, abs=1e-3)
    # w+ = 0 + T (3000 - 3000) = 0
    assert x_next[2] == pytest.approx(0.0, abs=1e-12)


def test_onramp_segment_hand_step_with_anticipation_and_merge() -> None:
    net = one_segment(onramp=True)
    x = np.array([40.0, 60.0, 10.0])
    x_next, q, q_o = step_with_flows(x, np.array([0.5]), np.array([1500.0, 50.0]), net)
    # q = 40*60*2 = 4800; q_o = min(1500 + 10*360 = 5100, 0.5*2000 = 1000, 2000*140/146.5 = 1911) = 1000
    assert q[0] == pytest.approx(4800.0)
    assert q_o[0] == pytest.approx(1000.0)
    # rho+ = 40 + (1000 - 4800)/720 = 34.72222
    assert x_next[0] == pytest.approx(40.0 - 3800.0 / 720.0, rel=1e-12)
    # V(40) = 48.3817; relaxation (10/18)(48.3817 - 60) = -6.4546
    # anticipation: rho_down = max(min(40, 33.5), 50) = 50 -> 60*(10/18)*(50-40)/(40+40) = 4.16667
    # merge: 0.0122 * (1/360) * 1000 * 60 / (1*2*(40+40)) = 0.0127083
    v_eq = 102.0 * math.exp(-((40.0 / 33.5) ** 1.867) / 1.867)
    assert v_eq == pytest.approx(48.3817, abs=1e-3)
    expected = 60.0 + (10.0 / 18.0) * (v_eq - 60.0) - 60.0 * (10.0 / 18.0) * 10.0 / 80.0 \
        - 0.0122 * (1.0 / 360.0) * 1000.0 * 60.0 / 160.0
    assert x_next[1] == pytest.approx(expected, rel=1e-12)
    assert x_next[1] == pytest.approx(49.366, abs=1e-3)
    # w+ = 10 + (1500 - 1000)/360 = 11.38889
    assert x_next[2] == pytest.approx(10.0 + 500.0 / 360.0, rel=1e-12)


def test_casadi_function_matches_numpy_step() -> None:
    net = beltway(BeltwayLayout(n_interchanges=3))
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = np.concatenate([rng.uniform(5, 80, net.n_seg), rng.uniform(20, 100, net.n_seg),
                            rng.uniform(0, 40, net.n_orig)])
        u = np.concatenate([rng.uniform(0.2, 1, net.n_metered), rng.uniform(net.split_lo, net.split_hi)])
        d = rng.uniform(500, 3000, net.nd)
        np.testing.assert_allclose(step(x, u, d, net), net.function(x, u, d)[0].full().ravel(), rtol=1e-12)


def test_closed_ring_conserves_vehicles() -> None:
    net = beltway(BeltwayLayout(n_interchanges=4))
    closed = dataclasses.replace(net, exit_frac=np.zeros(net.n_seg))
    rng = np.random.default_rng(7)
    x0 = steady_state(closed, rng.uniform(10, 60, closed.n_seg))
    k = 200
    res = simulate(closed, x0, np.tile(closed.default_u(), (k, 1)), np.zeros((k, closed.nd)))
    veh = res.x[:, : closed.n_seg] @ closed.lane_km()
    np.testing.assert_allclose(veh, veh[0], rtol=1e-10)


def test_uniform_equilibrium_is_a_fixed_point() -> None:
    net = dataclasses.replace(beltway(), exit_frac=np.zeros(24))
    x0 = steady_state(net, 25.0)
    x1 = step(x0, net.default_u(), np.zeros(net.nd), net)
    np.testing.assert_allclose(x1, x0, atol=1e-9)


def test_cfl_violation_is_rejected() -> None:
    with pytest.raises(ValueError, match="CFL"):
        beltway(BeltwayLayout(spacing_km=0.5, seg_target_km=0.25))


def test_beltway_default_split_and_exits_follow_shortest_loop() -> None:
    net = beltway(BeltwayLayout(n_interchanges=4))
    # uniform OD over 3 destinations: one cw-shorter, one ccw-shorter, one tie -> cw share 0.5
    np.testing.assert_allclose(net.split_default, 0.5)
    # a cw link from k carries (k->k+1) + (k->k+2)/2 + (k-1->k+1)/2 = 2 units; 1 + 0.5 exit at k+1
    assert net.exit_frac.max() == pytest.approx(0.75)
