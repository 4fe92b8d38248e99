"""V2X merging's ``open_ahead`` boundary (issue 28 (b), new boundaries): a mainline car behind a mainline
predecessor opens the gap early to the ramp vehicle ahead of that predecessor in the crossing order, so
that it does not inherit the ramp vehicle a few metres ahead when its predecessor leaves the order (the
67 of 144 hard-brake onsets of docs/guide/merging-flagship.md).  Default ``dist_m`` 0: off, today's
decisions."""

from __future__ import annotations

from typing import Any

import pytest

from corridor.controllers.merging.switching import (
    MergeBoundaries,
    MergeState,
    VirtualGap,
    merge_automaton,
    resolved,
)
from tests.conftest import scenario_file

L = 4.8  # [m] predecessor length


def _theta(**kw: Any) -> dict[str, dict[str, float]]:
    return resolved(MergeBoundaries(**kw), virtual_leader_m=100.0)


def _main(d: float, cross_pred: bool = False, cross_ahead: bool = True) -> MergeState:
    vg = VirtualGap(True, 5.0, 25.0, 0.0, L)
    return MergeState("main", d, cross_pred, probe=lambda: vg, cross_ahead=cross_ahead)


def test_the_default_is_off_at_every_distance() -> None:
    assert _theta()["open_ahead"] == {"dist_m": 0.0}
    ha = merge_automaton("merge", "m1", "main", _theta())
    for k, d in enumerate([240.0, 120.0, 50.0, 5.0, 0.0]):
        ha.update(0.1 * k, _main(d), None, settle=3)
        assert ha.mode == "free"


@pytest.mark.parametrize(("dist_m", "d", "mode"), [(150.0, 151.0, "free"), (150.0, 150.0, "free"),
                                                   (150.0, 149.0, "early"), (60.0, 90.0, "free"), (60.0, 59.0, "early")])
def test_a_car_behind_a_mainline_predecessor_opens_early_within_its_theta(dist_m: float, d: float, mode: str) -> None:
    ha = merge_automaton("merge", "m1", "main", _theta(open_ahead={"dist_m": dist_m}))
    ha.update(0.0, _main(d), None, settle=3)
    assert ha.mode == mode  # strict: at d == dist_m it does not switch yet


def test_early_only_with_a_ramp_vehicle_ahead_and_leaves_for_yield_or_free() -> None:
    th = _theta(open_ahead={"dist_m": 200.0})
    ha = merge_automaton("merge", "m1", "main", th)
    ha.update(0.0, _main(150.0, cross_ahead=False), None, settle=3)
    assert ha.mode == "free"  # nothing of the other road ahead in the order
    ha.update(0.1, _main(148.0), None, settle=3)
    assert ha.mode == "early"
    ha.update(0.2, _main(146.0, cross_ahead=False), None, settle=3)
    assert ha.mode == "free"  # the ramp vehicle left the order (or was re-sequenced behind)
    ha.update(0.3, _main(144.0), None, settle=3)
    ha.update(0.4, _main(90.0, cross_pred=True, cross_ahead=False), None, settle=3)
    assert ha.path() == ("main", "yield", "open")  # inherited the ramp vehicle inside yield_enter: yields


def test_the_controller_opens_to_the_nearest_ramp_vehicle_ahead_within_its_listening_depth() -> None:
    from corridor.controllers.merging.components import V2XMerging
    from corridor.scenario import load
    from corridor.variants import variant_scenarios

    sc, _ = load(scenario_file("merging"), ["sweep.v2x_cps.controllers.merge.params.boundaries.open_ahead.dist_m=150"])
    vsc = variant_scenarios(sc)["v2x_cps"]
    comp = V2XMerging("merge", V2XMerging.Params.model_validate(dict(vsc.controllers["merge"].params)), vsc)
    assert comp._opens_ahead and comp._listen_depth == 3
    road = {"r1": "ramp", "m1": "main", "m2": "main", "m3": "main", "m4": "main"}
    order = ["r1", "m1", "m2", "m3", "m4"]
    assert comp._cross_ahead(order, 2, road) == "r1"  # m2 behind m1 behind r1
    assert comp._cross_ahead(order, 3, road) == "r1"  # two mainline cars between: still heard (depth 3)
    assert comp._cross_ahead(order, 4, road) is None  # beyond its listening depth
    assert comp._cross_ahead(order, 1, road) is None  # its predecessor is the ramp vehicle: yield_enter's case
    assert comp._cross_ahead(order, 0, road) is None
    off = V2XMerging("merge", V2XMerging.Params(), vsc)
    assert not off._opens_ahead  # the default: the RSU sends no cross_ahead, nothing changes


def _run(sets: list[str]) -> tuple[dict[str, Any], list[Any]]:
    from corridor.run import simulate
    from corridor.scenario import load
    from corridor.variants import variant_scenarios

    pre = "sweep.v2x_cps.controllers.merge.params"
    sc, _ = load(scenario_file("merging"), ["duration=120", "warmup=30", "outputs.signals=false",
                                            *(f"{pre}.{s}" for s in sets)])
    metrics, ctx, _ = simulate(variant_scenarios(sc)["v2x_cps"], 0)
    return metrics, ctx.events.of_kind("mode")


def test_in_sumo_the_boundary_switches_cars_to_early_and_commands_them_and_zero_is_today() -> None:
    base, base_ev = _run([])
    zero, _ = _run(["boundaries.open_ahead.dist_m=0"])
    on, on_ev = _run(["boundaries.open_ahead.dist_m=200"])
    same = lambda a, b: a == b or (a != a and b != b)  # noqa: E731  (NaN == NaN)
    assert zero.keys() == base.keys() and all(same(zero[k], base[k]) for k in base)  # the default, written out
    assert not any("-> main.early" in e.message for e in base_ev)
    early = [e for e in on_ev if e.data.get("boundary") == "open_ahead"]
    assert early and all(e.data["t_cross"] <= e.t for e in early)
    assert on["v2x_commands"] != base["v2x_commands"]  # cars in `early` that must brake are commanded
