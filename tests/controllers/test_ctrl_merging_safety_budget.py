"""V2X merging's safety layer counts on the braking its commanded vehicles deliver (issue 27).

Commands go out in SUMO's default speed mode, which keeps a commanded slowing within the type's
``decel``: with the calibrated humans (decel 2 m/s²) a 6 m/s² braking budget is one SUMO never executes.
"""

from __future__ import annotations

from corridor.controllers.merging.components import V2XMerging
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file


def _budget(sets: list[str]) -> tuple[float, float]:
    sc, _ = load(scenario_file("merging"), sets)
    vsc = variant_scenarios(sc)["v2x_cps"]
    spec = vsc.controllers["merge"]
    comp = V2XMerging("merge", V2XMerging.Params.model_validate(spec.params), vsc)
    s = comp._deliverable_safety(vsc)
    return s.b_ego_mps2, s.reaction_s


def test_the_budget_is_the_connected_types_decel() -> None:
    assert _budget([]) == (2.0, 0.3)  # human_merge: decel 2.0; the layer's reaction 0.3 s >= the 0.1 s period


def test_a_type_that_brakes_harder_than_the_layer_keeps_the_layers_budget() -> None:
    sets = ["road.demand.vehicle_types.car.decel=7.5"]
    assert _budget(sets)[0] == 6.0
