"""V2X merging's safety layer counts on the braking its commanded vehicles deliver, and keeps them off
their own leader (issue 27).

In speed mode 27 (the default) SUMO executes a commanded braking up to the type's emergency decel; in
mode 31 only up to its ``decel`` (2 m/s² for the calibrated humans): a 6 m/s² budget is then one SUMO
never executes.
"""

from __future__ import annotations

import numpy as np

from corridor.controllers.merging.components import V2XMerging, deliverable_safety
from corridor.controllers.merging.safety_layer import lane_leaders
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file


def _budget(sets: list[str], mode: int | None = None) -> tuple[float, float]:
    sc, _ = load(scenario_file("merging"), sets)
    vsc = variant_scenarios(sc)["v2x_cps"]
    params = dict(vsc.controllers["merge"].params) | ({"command_speed_mode": mode} if mode is not None else {})
    comp = V2XMerging("merge", V2XMerging.Params.model_validate(params), vsc)
    s = deliverable_safety(comp.p.safety, vsc, comp.p.command_speed_mode, comp.period)
    return s.b_ego_mps2, s.reaction_s


def test_mode_31_limits_the_budget_to_the_connected_types_decel() -> None:
    assert _budget([], 31) == (2.0, 0.3)  # human_merge: decel 2.0; the layer's reaction 0.3 s >= the 0.1 s period


def test_mode_27_lets_the_layer_count_on_its_own_budget_below_the_emergency_decel() -> None:
    assert _budget([]) == (6.0, 0.3)  # emergency decel 9.0
    assert _budget(["road.demand.vehicle_types.car.emergency_decel=4.0"])[0] == 4.0


def test_lane_leaders_are_the_next_vehicle_ahead_on_the_same_lane() -> None:
    lane = np.array([0, 0, 1, 0, 1])
    pos = np.array([10.0, 50.0, 5.0, 30.0, 40.0])  # [m] front bumper along the lane
    assert lane_leaders(lane, pos).tolist() == [3, -1, 4, 1, -1]
