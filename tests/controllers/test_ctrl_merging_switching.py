"""V2X merging's switching as named boundaries (issue 28): the ramp vehicle's gap acceptance and the
mainline vehicle's yield decision, with theta from the scenario's params and located crossings."""

from __future__ import annotations

import math
from typing import Any

import pytest

from corridor.controllers.merging.switching import (
    MergeBoundaries,
    MergeState,
    VirtualGap,
    merge_automaton,
    resolved,
)
from corridor.events import EventLog
from tests.conftest import SCENARIOS

L = 4.8  # [m] predecessor length


def _state(road: str, d: float, cross: bool = True, gap: float | None = None) -> MergeState:
    vg = VirtualGap(False) if gap is None else VirtualGap(True, gap, 25.0, 0.0, L)
    return MergeState(road, d, cross, probe=lambda: vg)


def _theta(**kw: Any) -> dict[str, dict[str, float]]:
    return resolved(MergeBoundaries(**kw), virtual_leader_m=100.0)


def test_defaults_are_the_controllers_constants():
    th = _theta()
    assert th["merge_enter"] == th["yield_enter"] == th["yield_exit"] == {"dist_m": 100.0}
    assert th["gap_accept"] == th["gap_reject"] == th["yield_pass"] == th["yield_hold"] == {"lag_lengths": 1.0}
    assert resolved(MergeBoundaries(), virtual_leader_m=70.0)["merge_enter"] == {"dist_m": 70.0}


def test_scenario_params_fill_distances_from_virtual_leader_m():
    from corridor.controllers.merging.components import V2XMerging
    from corridor.learn import boundary_params
    from corridor.scenario import load

    assert V2XMerging.Params(virtual_leader_m=70.0).boundaries.yield_exit.dist_m == 70.0
    assert V2XMerging.Params(boundaries={"yield_enter": {"dist_m": 30.0}}).boundaries.yield_enter.dist_m == 30.0
    sc, raw = load(SCENARIOS / "merging.yaml")
    have = boundary_params(sc, raw, "v2x_cps")["merge"]  # what --learn reads: numbers
    assert have["merge_enter.dist_m"] == 100.0 and have["gap_reject.lag_lengths"] == 1.0


def test_ramp_vehicle_switches_at_its_theta_with_located_crossing():
    ev = EventLog()
    ha = merge_automaton("merge", "r1", "ramp", _theta(merge_enter={"dist_m": 50.0}))
    ha.update(0.0, _state("ramp", 80.0), ev, settle=3)
    ha.update(0.1, _state("ramp", 52.0), ev, settle=3)
    assert ha.in_mode("approach")  # 52 m: still outside the 50 m boundary (100 m by default)
    ha.update(0.2, _state("ramp", 48.0, gap=3.0), ev, settle=3)
    assert ha.path() == ("ramp", "merge", "behind")
    (e,) = ev.of_kind("mode")
    assert e.data["boundary"] == "merge_enter" and e.data["located"]
    assert e.data["t_cross"] == pytest.approx(0.15)  # g: -2 m at 0.1 s, +2 m at 0.2 s
    assert e.data["g"] == pytest.approx(2.0)


@pytest.mark.parametrize(("lag", "gap", "mode"), [(1.0, -1.5 * L, "ahead"), (2.0, -1.5 * L, "behind"),
                                                  (1.0, -0.5 * L, "behind"), (0.0, -0.1, "ahead")])
def test_gap_acceptance_follows_lag_lengths(lag: float, gap: float, mode: str):
    ha = merge_automaton("merge", "r1", "ramp", _theta(gap_reject={"lag_lengths": lag},
                                                         gap_accept={"lag_lengths": lag}))
    ha.update(0.0, _state("ramp", 30.0, gap=gap), None, settle=3)  # enters merge and decides in one update
    assert ha.mode == mode
    ha.update(0.1, _state("ramp", 28.0, gap=10.0), None, settle=3)  # the predecessor pulls ahead again
    assert ha.mode == "behind"


def test_mainline_yields_only_to_a_ramp_predecessor_within_its_theta():
    ha = merge_automaton("merge", "m1", "main", _theta(yield_enter={"dist_m": 60.0}, yield_exit={"dist_m": 60.0}))
    ha.update(0.0, _state("main", 90.0, gap=5.0), None, settle=3)
    assert ha.mode == "free"
    ha.update(0.1, _state("main", 55.0, cross=False), None, settle=3)
    assert ha.mode == "free"  # a mainline predecessor: its own driver follows it
    ha.update(0.2, _state("main", 53.0, gap=-2.0 * L), None, settle=3)
    assert ha.path() == ("main", "yield", "pass")  # the ramp vehicle is two lengths behind: not yielded to
    ha.update(0.3, _state("main", 51.0, gap=2.0), None, settle=3)
    assert ha.path() == ("main", "yield", "open")
    ha.update(0.4, _state("main", 49.0, cross=False), None, settle=3)
    assert ha.mode == "free"


def test_unknown_gap_never_switches():
    ha = merge_automaton("merge", "r1", "ramp", _theta())
    ha.update(0.0, _state("ramp", 30.0, gap=None), None, settle=3)
    assert ha.mode == "behind" and math.isnan(ha.g_now["gap_reject"])


# ---- in SUMO: theta from the scenario reaches the controller's decisions -------------------------------

def _run(sets: list[str]) -> tuple[dict[str, Any], list[Any], dict[str, Any]]:
    from corridor.run import simulate
    from corridor.scenario import load
    from corridor.variants import variant_scenarios

    pre = "sweep.v2x_cps.controllers.merge.params"
    sc, _ = load(SCENARIOS / "merging.yaml", ["duration=120", "warmup=30", "outputs.signals=false",
                                              *(f"{pre}.{s}" for s in sets)])
    metrics, ctx, _ = simulate(variant_scenarios(sc)["v2x_cps"], 0)
    return metrics, ctx.events.of_kind("mode"), ctx.components["merge"].overlays()


def test_theta_from_the_scenario_changes_the_decisions():
    base, base_ev, base_drawn = _run([])
    same, _, _ = _run(["boundaries.yield_enter.dist_m=100", "boundaries.merge_enter.dist_m=100"])
    near, near_ev, drawn = _run(["boundaries.yield_enter.dist_m=30", "boundaries.yield_exit.dist_m=30",
                          "boundaries.merge_enter.dist_m=30"])
    keys = ("v2x_commands", "delay_mean_s", "hard_brakes", "min_virtual_gap_m", "events_mode")
    assert {k: same[k] for k in keys} == {k: base[k] for k in keys}  # the defaults are today's 100 m
    # a 30 m boundary: mainline vehicles yield later, so fewer are commanded
    assert near["v2x_commands"] < base["v2x_commands"]
    for ev in (base_ev, near_ev):
        enters = [e for e in ev if e.data.get("boundary") in ("merge_enter", "yield_enter")]
        assert enters and all(e.data["t_cross"] <= e.t for e in enters)
        assert any(e.data["located"] and e.t - 0.1 < e.data["t_cross"] < e.t for e in enters)
    # Rerun draws the boundary where theta puts it: 30 m before the conflict point
    (line,) = drawn["boundaries/yield_enter"][1]
    conflict_x = line[0, 0] + 30.0
    (base_line,) = base_drawn["boundaries/yield_enter"][1]
    assert base_line[0, 0] == pytest.approx(conflict_x - 100.0)


def test_stochastic_switching_near_the_merging_boundaries_scores_their_theta():
    """blrl's policy on the merging boundaries: draws near yield_enter/merge_enter (T = 0.05 log units:
    within 100 m x e^(+-0.2) = 82-122 m of the conflict point), their score-function gradients summed
    into the row per boundary parameter."""
    row, ev, _ = _run(["switching.temperature=0.05"])
    assert row["blrl.draws"] > 0
    assert row["blrl.score.merge.merge_enter.dist_m"] != 0.0 and row["blrl.score.merge.yield_enter.dist_m"] != 0.0
