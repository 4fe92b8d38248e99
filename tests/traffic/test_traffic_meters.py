"""Ramp-meter timing, route-guidance splitting (closed forms, statistics) and a meter in SUMO."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.traffic.sumo.meters import (
    MeterTiming,
    choice_set,
    divert_probability,
    guidance_assignments,
    loop_hops,
    parse_od_route,
    realised_rate_vph,
    red_time_s,
)
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "ramp_metering.yaml"


def test_red_time_is_cycle_minus_green() -> None:
    t = MeterTiming(green_s=2.0, min_red_s=1.0, open_rate_vph=1800.0)
    assert red_time_s(900.0, t) == pytest.approx(2.0)  # 4 s cycle
    assert red_time_s(360.0, t) == pytest.approx(8.0)  # 10 s cycle
    assert red_time_s(3000.0, t) == pytest.approx(1.0)  # clamped to the shortest red
    assert realised_rate_vph(360.0, t) == pytest.approx(360.0)
    assert realised_rate_vph(1500.0, t) == pytest.approx(1200.0)  # 2 s + 1 s: at most 1200 veh/h
    assert math.isinf(realised_rate_vph(1800.0, t))  # switched off
    with pytest.raises(ValueError):
        red_time_s(0.0, t)


def test_divert_probability_closed_forms() -> None:
    assert divert_probability(0.5, 0.7) == ("cw", pytest.approx(0.4))
    assert divert_probability(0.5, 0.2) == ("ccw", pytest.approx(0.6))
    assert divert_probability(0.4, 0.4)[1] == 0.0
    assert divert_probability(1.0, 1.0) == ("cw", 0.0)


def test_parse_od_route() -> None:
    assert parse_od_route("od_3_11_ccw") == (3, 11, "ccw")
    assert parse_od_route("od_1_2_up") is None
    assert parse_od_route("main") is None


def test_guidance_moves_the_expected_share() -> None:
    rng = np.random.default_rng(1)
    n = 20000
    cw = [(f"c{i}", "od_0_3_cw") for i in range(n)]
    ccw = [(f"a{i}", "od_0_3_ccw") for i in range(n)]
    other_origin = [(f"o{i}", "od_2_5_cw") for i in range(100)]
    moves = guidance_assignments(cw + ccw + other_origin, {0: 0.7}, {0: 0.5}, rng)
    moved = dict(moves)
    assert all(v.startswith("c") for v in moved)  # only cw drivers move towards ccw
    assert set(moved.values()) == {"od_0_3_ccw"}
    p_hat = len(moved) / n
    assert abs(p_hat - 0.4) < 4 * math.sqrt(0.4 * 0.6 / n)  # binomial, 4 sigma
    # resulting ccw share: (n + moved) / 2n -> target 0.7
    assert (n + len(moved)) / (2 * n) == pytest.approx(0.7, abs=0.01)


def test_choice_set_only_ties_have_a_choice() -> None:
    """6-ring: 0 -> 3 is 3 hops either way (a choice), 0 -> 1 is 1 vs 5 hops (none)."""
    assert loop_hops(0, 1, 6, "ccw") == 1 and loop_hops(0, 1, 6, "cw") == 5
    od = {(0, 3, "ccw"): 300.0, (0, 3, "cw"): 300.0, (0, 1, "ccw"): 400.0}
    cs = choice_set(od, 6)
    assert cs.has_choice(0, 3) and not cs.has_choice(0, 1) and not cs.has_choice(0, 2)
    assert cs.movable[0] == pytest.approx((0.3, 0.3))
    assert choice_set(od, 6, max_extra_hops=2).has_choice(0, 2)  # 2 vs 4 hops


def test_guidance_with_choices_moves_only_long_trips_and_the_same_share() -> None:
    """Origin 0 has 60 % ccw default (20 % short trips with no choice); target 40 % ccw."""
    rng = np.random.default_rng(2)
    n = 20000
    short = [(f"s{i}", "od_0_1_ccw") for i in range(n)]
    tie_ccw = [(f"a{i}", "od_0_3_ccw") for i in range(2 * n)]
    tie_cw = [(f"c{i}", "od_0_3_cw") for i in range(2 * n)]
    total = 5 * n
    cs = choice_set({(0, 1, "ccw"): 1.0, (0, 3, "ccw"): 2.0, (0, 3, "cw"): 2.0}, 6)
    moves = dict(guidance_assignments(short + tie_ccw + tie_cw, {0: 0.4}, {0: 0.6}, rng, cs))
    assert all(v.startswith("a") for v in moves)  # no short trip is sent the long way round
    # ccw share must drop by 0.2 of all drivers: p = 0.2 / 0.4 (movable ccw share) = 0.5
    p_hat = len(moves) / (2 * n)
    assert abs(p_hat - 0.5) < 4 * math.sqrt(0.25 / (2 * n))
    assert (3 * n - len(moves)) / total == pytest.approx(0.4, abs=0.01)


def test_low_fixed_rate_limits_ramp_flow_in_sumo() -> None:
    """A meter at 360 veh/h lets at most ~one vehicle per 10 s cycle pass; meters off let more pass."""
    from corridor.run import simulate
    from corridor.scenario import load

    passed = {}
    for ctrl in ("{type: ramp_fixed, params: {fixed_rate_vph: 360}}", "{type: ramp_none}"):
        sc, _ = load(SCENARIO, [f"controllers.ramps={ctrl}", "duration=420"])  # ramp travel ~80 s
        _, ctx, _ = simulate(sc, seed=3)
        det = ctx.components["detectors"]
        passed[ctrl] = np.array(list(det.passed_total.values()), dtype=float)
    fixed, free = passed.values()
    assert fixed.max() <= 420 / 10 + 1  # cycle 10 s (2 s green + 8 s red), one vehicle per green
    assert fixed.mean() >= 15  # the meter does serve vehicles (demand exceeds the rate)
    assert free.mean() > 1.4 * fixed.mean()
