"""Safety layer: no collision with a leader braking at its maximum, even with every message lost."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.channel import BernoulliLoss, Channel, ChannelConfig
from corridor.controllers.merging.safety_layer import (
    IdmParams,
    SafetyParams,
    idm_accel,
    safe_accel,
    safe_speed,
    worst_case_leader,
)

P = SafetyParams(reaction_s=0.3, b_ego_mps2=6.0, b_lead_mps2=8.0, s0_m=2.0)
IDM = IdmParams()
DT_FINE_S = 0.01  # [s] integration step inside one command hold


def _advance(x: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact constant-acceleration step that stops at v = 0 (no reversing)."""
    t_move = np.where(a < 0, np.minimum(dt, v / np.maximum(-a, 1e-12)), dt)
    return x + v * t_move + 0.5 * a * t_move**2, np.maximum(v + a * t_move, 0.0)


def _initially_safe(gap: np.ndarray, v: np.ndarray, v_l: np.ndarray) -> np.ndarray:
    b = min(P.b_ego_mps2, P.b_lead_mps2)
    return v**2 / (2 * b) <= gap - P.s0_m + v_l**2 / (2 * P.b_lead_mps2)


def _run_braking_leader(
    gap0, v0, vl0, a_cmd_fn, hold_s: float, use_layer: bool, t_end_s: float = 12.0
) -> np.ndarray:
    """Leader brakes at its maximum from t = 0; returns the minimum bumper gap per state."""
    x_e, v_e = np.zeros_like(gap0), v0.copy()
    x_l, v_l = gap0.copy(), vl0.copy()
    a_lead = np.full_like(gap0, -P.b_lead_mps2)
    min_gap = gap0.copy()
    n_sub = round(hold_s / DT_FINE_S)
    for _ in range(round(t_end_s / hold_s)):
        a_cmd = a_cmd_fn(v_e)
        gap = x_l - x_e
        a = (
            np.array([safe_accel(g, ve, vl, ac, P) for g, ve, vl, ac in zip(gap, v_e, v_l, a_cmd)])
            if use_layer
            else a_cmd
        )
        for _ in range(n_sub):
            x_e, v_e = _advance(x_e, v_e, a, DT_FINE_S)
            x_l, v_l = _advance(x_l, v_l, a_lead, DT_FINE_S)
            min_gap = np.minimum(min_gap, x_l - x_e)
    return min_gap


@pytest.mark.parametrize("hold_s", [0.1, 0.3])
def test_no_collision_with_leader_braking_at_maximum(hold_s: float) -> None:
    rng = np.random.default_rng(2)
    n = 1500
    gap, v, v_l = rng.uniform(0.0, 120.0, n), rng.uniform(0.0, 35.0, n), rng.uniform(0.0, 35.0, n)
    ok = _initially_safe(gap, v, v_l)
    gap, v, v_l = gap[ok], v[ok], v_l[ok]
    assert ok.sum() > 500

    def flat_out(v_e: np.ndarray) -> np.ndarray:  # the most aggressive command: full throttle
        return np.full_like(v_e, 3.0)

    min_gap = _run_braking_leader(gap, v, v_l, flat_out, hold_s, use_layer=True)
    # the gap never drops below s0 (or below the initial gap when that was already smaller)
    assert np.all(min_gap >= np.minimum(gap, P.s0_m) - 1e-6)
    assert min_gap.min() > 0.0
    # the property is not vacuous: without the layer most of these states collide
    raw = _run_braking_leader(gap, v, v_l, flat_out, hold_s, use_layer=False)
    assert (raw < 0).mean() > 0.5


def test_grid_of_states_random_commands() -> None:
    g, ve, vl = np.meshgrid(np.linspace(0.5, 80, 12), np.linspace(0, 35, 12), np.linspace(0, 35, 12))
    gap, v, v_l = g.ravel(), ve.ravel(), vl.ravel()
    ok = _initially_safe(gap, v, v_l)
    rng = np.random.default_rng(9)

    def random_cmd(v_e: np.ndarray) -> np.ndarray:
        return rng.uniform(-4.0, 4.0, v_e.size)

    min_gap = _run_braking_leader(gap[ok], v[ok], v_l[ok], random_cmd, 0.3, use_layer=True)
    assert np.all(min_gap >= np.minimum(gap[ok], P.s0_m) - 1e-6)


def _leader_profile(rng: np.random.Generator, n_steps: int, dt: float) -> np.ndarray:
    """Target speeds [m/s] of the leader: random cruise levels with sudden full stops (NaN = brake fully)."""
    levels = np.repeat(rng.uniform(5.0, 30.0, n_steps // 100 + 1), 100)[:n_steps]
    brake = np.zeros(n_steps, dtype=bool)
    for k in np.flatnonzero(rng.random(n_steps) < 0.01):
        brake[k : k + round(2.0 / dt)] = True  # 2 s emergency braking episodes
    return np.where(brake, np.nan, levels)


def _leader_accel(v_target: float, v_l: float) -> float:
    if np.isnan(v_target):
        return -P.b_lead_mps2
    return float(np.clip(0.8 * (v_target - v_l), -P.b_lead_mps2, 2.0))


def _follow(
    rng: np.random.Generator, channel: Channel | None, t_end_s: float = 60.0, dt: float = 0.1
) -> dict:
    """Ego follows a leader it only knows from messages (or from the t=0 message alone)."""
    x_l, v_l = np.array([40.0]), np.array([25.0])
    x_e, v_e = np.array([0.0]), np.array([25.0])
    known = (0.0, 40.0, 25.0)  # (t_sent, x, v) of the newest leader info
    profile = _leader_profile(rng, round(t_end_s / dt), dt)
    gaps, speeds, n_stale = [], [], 0
    for k, v_target in enumerate(profile):
        t = k * dt
        a_l = _leader_accel(v_target, float(v_l[0]))
        if channel is not None:
            channel.send(t, "lead", (t, float(x_l[0]), float(v_l[0])))
            for d in channel.deliver(t):
                if d.dst == "ego" and d.payload[0] > known[0]:
                    known = d.payload
        age = t - known[0]
        n_stale += age > 0.5
        x_wc, v_wc = worst_case_leader(known[1], known[2], age, P.b_lead_mps2)
        gap_est = x_wc - float(x_e[0])
        a_cmd = idm_accel(gap_est, float(v_e[0]), v_wc, IDM)
        a = np.array([max(safe_accel(gap_est, float(v_e[0]), v_wc, a_cmd, P), -P.b_ego_mps2)])
        for _ in range(round(dt / DT_FINE_S)):
            x_e, v_e = _advance(x_e, v_e, a, DT_FINE_S)
            x_l, v_l = _advance(x_l, v_l, np.array([a_l]), DT_FINE_S)
            gaps.append(float(x_l[0] - x_e[0]))
        speeds.append(float(v_e[0]))
    return {"gaps": np.array(gaps), "speeds": np.array(speeds), "n_stale": n_stale}


@pytest.mark.parametrize("seed", range(5))
def test_gap_stays_positive_when_every_message_is_lost(seed: int) -> None:
    out = _follow(np.random.default_rng(seed), channel=None)
    assert out["gaps"].min() >= P.s0_m - 1e-6
    # with no information the ego ends stopped (behind the worst-case stop point of the old state)
    assert out["speeds"][-1] == pytest.approx(0.0, abs=1e-6)
    assert out["n_stale"] > 500


@pytest.mark.parametrize("seed", range(3))
def test_gap_stays_positive_with_30pct_loss_and_100ms_latency(seed: int) -> None:
    cfg = ChannelConfig(latency_s=0.1, jitter_s=0.02, loss=BernoulliLoss(p=0.3))
    ch = Channel(cfg, np.random.default_rng(100 + seed))
    ch.attach("ego")
    ch.attach("lead")
    out = _follow(np.random.default_rng(seed), channel=ch)
    assert out["gaps"].min() >= P.s0_m - 1e-6
    assert out["speeds"].mean() > 3.0  # still drives: information keeps arriving
    assert ch.stats().delivery_ratio == pytest.approx(0.7, abs=0.06)


def test_bound_closed_forms() -> None:
    # Gipps: the allowed speed after τ makes the stopping point exactly reach gap - s0 + leader stop
    gap, v, vl = 30.0, 20.0, 15.0
    v1 = safe_speed(gap, v, vl, P)
    b, tau = 6.0, P.reaction_s
    reach = v * tau + 0.5 * (v1 - v) * tau + v1**2 / (2 * b)
    assert reach == pytest.approx(gap - P.s0_m + vl**2 / (2 * P.b_lead_mps2))
    assert safe_accel(gap, v, vl, 10.0, P) == pytest.approx((v1 - v) / tau)
    assert safe_accel(gap, v, vl, -1.0, P) == -1.0 or (v1 - v) / tau < -1.0
    assert safe_accel(math.inf, v, vl, 1.7, P) == 1.7
    assert safe_accel(0.1, 30.0, 0.0, 1.0, P) == -P.b_ego_mps2  # unavoidable: brake fully
    assert worst_case_leader(100.0, 16.0, 1.0, 8.0) == pytest.approx((112.0, 8.0))
    assert worst_case_leader(100.0, 16.0, 5.0, 8.0) == pytest.approx((116.0, 0.0))


def test_idm_closed_forms() -> None:
    assert idm_accel(math.inf, 0.0, 0.0, IDM) == pytest.approx(IDM.a_mps2)
    assert idm_accel(math.inf, IDM.v0_mps, 0.0, IDM) == pytest.approx(0.0)
    v = 20.0
    s_star = IDM.s0_m + v * IDM.time_headway_s
    s_eq = s_star / math.sqrt(
        1 - (v / IDM.v0_mps) ** IDM.delta
    )  # equilibrium gap behind an equal-speed leader
    assert idm_accel(s_eq, v, v, IDM) == pytest.approx(0.0, abs=1e-12)
    assert idm_accel(0.5 * s_eq, v, v, IDM) < -IDM.b_mps2
