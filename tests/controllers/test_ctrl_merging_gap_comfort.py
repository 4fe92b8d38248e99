"""V2X merging: the gap-opening rule brakes at most comfortably; only the safety layer brakes harder
(issue 27, the hard brakes of the flagship's V2X variants).

A follower whose predecessor from the other road is put ahead of it (first come, first served at the
merge point) follows that predecessor projected onto its own road.  The constant-time-gap rule that
opens the gap asked for -6 to -14 m/s² when the projected predecessor appeared close ahead and slower,
far beyond what the safety layer needed.
"""

from __future__ import annotations

import pytest

from corridor.controllers.merging.components import V2XMerging, deliverable_safety
from corridor.controllers.merging.safety_layer import safe_accel
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file

HARD_BRAKE_MPS2 = -4.5  # the scenario's surrogate-safety threshold (hard_brakes)


def _controller(variant: str) -> V2XMerging:
    sc, _ = load(scenario_file("merging"), [])
    vsc = variant_scenarios(sc)[variant]
    comp = V2XMerging("merge", V2XMerging.Params.model_validate(dict(vsc.controllers["merge"].params)), vsc)
    comp.safety = deliverable_safety(comp.p.safety, vsc, comp.p.command_speed_mode, comp.period)
    return comp


@pytest.mark.parametrize("variant", ["v2x_fifo", "v2x_cps"])
def test_a_follower_whose_virtual_leader_is_put_close_ahead_brakes_no_harder_than_safety_needs(variant: str) -> None:
    comp = _controller(variant)
    v, v_lead, gap = 20.0, 10.0, 31.0  # [m/s], [m/s], [m]: a ramp vehicle 10 m/s slower, projected 31 m ahead
    assert comp._merge_gap_accel(gap, v, v_lead) < HARD_BRAKE_MPS2  # the rule alone would brake hard
    a_min = comp.p.limits.a_min_mps2
    needed = safe_accel(gap, v, v_lead, a_min, comp.safety)  # what the safety layer requires
    assert HARD_BRAKE_MPS2 < needed < a_min  # more than comfortable, less than a hard brake
    acc = comp._gap_opening_accel(0.0, gap, v, v_lead)
    assert acc == pytest.approx(needed)
    assert acc > HARD_BRAKE_MPS2


@pytest.mark.parametrize("variant", ["v2x_fifo", "v2x_cps"])
def test_the_rule_opens_the_gap_at_the_comfortable_deceleration_when_the_state_is_safe(variant: str) -> None:
    comp = _controller(variant)
    v, v_lead, gap = 25.0, 18.0, 40.0  # [m/s], [m/s], [m]: safe, but short of the rule's s0 + v h
    assert safe_accel(gap, v, v_lead, comp.p.limits.a_min_mps2, comp.safety) == comp.p.limits.a_min_mps2
    acc = comp._gap_opening_accel(0.0, gap, v, v_lead)
    assert comp.p.limits.a_min_mps2 <= acc < 0.0  # it opens the gap, comfortably
    assert acc == pytest.approx(comp._merge_gap_accel(gap, v, v_lead))  # the rule itself, within limits


@pytest.mark.parametrize("variant", ["v2x_fifo", "v2x_cps"])
def test_the_safety_layer_keeps_its_authority_to_brake_hard(variant: str) -> None:
    comp = _controller(variant)
    v, v_lead, gap = 25.0, 25.0, 15.0  # [m/s], [m/s], [m]: too close for a leader that may brake at 8 m/s²
    acc = comp._gap_opening_accel(0.0, gap, v, v_lead)
    assert acc == pytest.approx(-comp.safety.b_ego_mps2)  # the layer's full braking (6 m/s²)
    assert acc < HARD_BRAKE_MPS2


@pytest.mark.parametrize("variant", ["v2x_fifo", "v2x_cps"])
def test_a_vehicle_above_v_max_is_brought_down_comfortably_not_in_one_step(variant: str) -> None:
    comp = _controller(variant)
    lim, dt = comp.p.limits, comp.period
    v = lim.v_max_mps + 3.7  # [m/s] a driver with a speed factor above 1 (33.7 m/s at v_max 30)
    v_next = comp._command_speed(v, lim.a_min_mps2)
    assert v_next == pytest.approx(v + lim.a_min_mps2 * dt)  # comfortable braking, not a 3.7 m/s step
    assert comp._command_speed(v, 0.0) == pytest.approx(v + lim.a_min_mps2 * dt)  # cruising: still comes down
    assert comp._command_speed(v, -comp.safety.b_ego_mps2) == pytest.approx(v - comp.safety.b_ego_mps2 * dt)  # safety
    assert comp._command_speed(lim.v_max_mps - 0.1, lim.a_max_mps2) == pytest.approx(lim.v_max_mps)  # the cap holds
    assert comp._command_speed(0.1, lim.a_min_mps2) == 0.0  # never backwards


def test_the_held_out_run_whose_first_command_stopped_a_car_on_the_open_road_has_no_collision() -> None:
    """Held-out seed 3805499706 of the merge learning benchmark (issue 28 (b): v2x_cps, 180 s, warm-up
    60 s, its draws): clipped to v_max in one step, `main_car.0.0` fell from 33.7 to 30 m/s (-37 m/s²),
    its EIDM driver kept braking from there to a standstill, and `main_car.0.1` ran into it at 43 s."""
    from corridor.run import RunSpec, execute
    from corridor.scenario.overrides import load_raw

    path = scenario_file("merging")
    raw = load_raw(path, ["duration=180", "warmup=60"])
    draws = {"channels.v2x.loss.p": 0.01025621552585739,
             "road.demand.flows.main_car.connected_share": 0.9858391428817979,
             "road.demand.flows.ramp_car.connected_share": 0.8779775196262836,
             "road.demand.scale": 0.9746564157042139}
    row = execute(RunSpec(run_id="held-out-110", scenario="merging", source=str(path), variant="v2x_cps",
                          seed=3805499706, base=raw, overrides={**raw["sweep"]["v2x_cps"], **draws}, draws=draws))
    assert row["status"] == "ok", row["error"]
    assert row["collisions"] == 0
