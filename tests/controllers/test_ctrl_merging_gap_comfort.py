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
