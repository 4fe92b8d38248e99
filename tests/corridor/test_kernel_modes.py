"""Hybrid automata: named boundaries with located crossings, hierarchy with entry/exit, invariants."""

from __future__ import annotations

import pytest

from corridor.events import EventLog
from corridor.modes import Boundary, HybridAutomaton, Mode, Transition, crossing_time


def _speed_automaton(limit_mps: float) -> HybridAutomaton:
    fast = Boundary("too_fast", lambda x, th: x["v"] - th["limit_mps"], {"limit_mps": limit_mps})
    slow = Boundary("slow_again", lambda x, th: th["limit_mps"] - x["v"], {"limit_mps": limit_mps}, strict=True)
    return HybridAutomaton("car", ["cruise", "brake"], "cruise",
                           [Transition("cruise", "brake", fast, "over the limit"),
                            Transition("brake", "cruise", slow, "under the limit")])


def test_boundary_crossing_time_is_located_by_interpolation() -> None:
    ha, ev = _speed_automaton(10.0), EventLog()
    for k, v in enumerate([8.0, 9.0, 12.0, 13.0]):  # v crosses 10 at t = 1 + 1/3 s
        ha.update(float(k), {"v": v}, ev)
    (jump,) = ev.of_kind("mode")
    assert jump.t == 2.0 and jump.data["boundary"] == "too_fast"
    assert jump.data["t_cross"] == pytest.approx(1.0 + 1.0 / 3.0)
    assert jump.data["g"] == pytest.approx(2.0)


def test_theta_moves_the_switch() -> None:
    """The same trajectory switches later with a higher limit: theta decides, not the code."""
    times = {}
    for limit in (10.0, 12.5):
        ha, ev = _speed_automaton(limit), EventLog()
        for k, v in enumerate([8.0, 9.0, 12.0, 13.0]):
            ha.update(float(k), {"v": v}, ev)
        times[limit] = ev.of_kind("mode")[0].data["t_cross"]
    assert times[12.5] == pytest.approx(2.5)
    assert times[10.0] < times[12.5]


def test_strict_boundary_does_not_fire_at_zero() -> None:
    ha = _speed_automaton(10.0)
    ha.update(0.0, {"v": 11.0})
    assert ha.mode == "brake"
    ha.update(1.0, {"v": 10.0})  # g = 0: strict, stays
    assert ha.mode == "brake"
    ha.update(2.0, {"v": 9.0})
    assert ha.mode == "cruise"


def test_no_location_when_the_boundary_was_not_evaluated_just_before() -> None:
    ha, ev = _speed_automaton(10.0), EventLog()
    ha.update(0.0, {"v": 12.0}, ev)  # first evaluation: nothing to interpolate from
    assert ev.of_kind("mode")[0].data["t_cross"] == 0.0


def test_hierarchy_enters_initial_child_and_runs_entry_exit_actions() -> None:
    log: list[str] = []
    avoid = Mode("avoid", children=(Mode("clear", entry=lambda t: log.append("in clear")),
                                    Mode("deflect", exit=lambda t: log.append("out deflect"))),
                 entry=lambda t: log.append("in avoid"), exit=lambda t: log.append("out avoid"))
    ha = HybridAutomaton("uav", [Mode("mission"), avoid], "mission", [
        Transition("mission", "avoid", lambda x: x == "threat"),
        Transition("clear", "deflect", lambda x: x == "deflect"),
        Transition("avoid", "mission", lambda x: x == "gone"),  # a composite's jump leaves any child
    ])
    ha.update(0.0, "threat")
    assert ha.mode == "clear" and ha.path() == ("avoid", "clear") and ha.in_mode("avoid")
    ha.update(1.0, "deflect")
    assert ha.mode == "deflect"
    ha.update(2.0, "gone")
    assert ha.mode == "mission" and not ha.in_mode("avoid")
    assert log == ["in avoid", "in clear", "out deflect", "out avoid"]


def test_outer_jump_preempts_inner() -> None:
    ha = HybridAutomaton("uav", [Mode("mission"), Mode("avoid", children=(Mode("a"), Mode("b")))], "avoid", [
        Transition("a", "b", lambda x: True), Transition("avoid", "mission", lambda x: True)])
    assert ha.mode == "a"
    ha.update(0.0, None)
    assert ha.mode == "mission"


def test_invariant_violation_is_an_event() -> None:
    ha = HybridAutomaton("ego", [Mode("pass", invariant=lambda x: x["t"] <= 12.0), Mode("follow")], "pass", [
        Transition("pass", "follow", lambda x: x["done"])])
    ev = EventLog()
    ha.update(11.0, {"t": 11.0, "done": False}, ev)
    ha.update(13.0, {"t": 13.0, "done": False}, ev)
    assert ha.invariant_violations == 1 and ev.of_kind("invariant")[0].data["mode"] == "pass"


def test_unknown_and_duplicate_modes_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown mode"):
        HybridAutomaton("x", ["a"], "a", [Transition("a", "b", lambda x: True)])
    with pytest.raises(ValueError, match="twice"):
        HybridAutomaton("x", ["a", Mode("b", children=(Mode("a"),))], "a", [])


def test_crossing_time_with_infinite_values_falls_back_to_the_tick() -> None:
    assert crossing_time(0.0, float("-inf"), 1.0, 2.0) == 1.0


def test_a_decider_takes_the_guard_inside_the_band_and_nowhere_else() -> None:
    """The learning agent's hook (corridor.decision_env): asked only where blrl would draw (a shift of the
    limit within band x T = 0.2 log units flips the guard: 8.19 < v < 12.21 m/s), and only while the
    transition's discrete condition holds; elsewhere the sign of g decides as before."""
    from corridor.modes import SwitchingParams, in_band

    band = SwitchingParams(temperature=0.1, band=2.0)
    asked: list[float] = []

    def never_inside(ha: HybridAutomaton, b: Boundary, t: float, g: float, x: dict) -> bool | None:
        if not in_band(b, x, g, band):
            return None
        asked.append(x["v"])
        return False

    speeds = [5.0, 9.0, 11.0, 13.0]
    plain, hooked = _speed_automaton(10.0), _speed_automaton(10.0)
    hooked.decider = never_inside
    for k, v in enumerate(speeds):
        plain.update(float(k), {"v": v})
        hooked.update(float(k), {"v": v})
    assert plain.history[0][0] == 2.0  # over the limit at 11 m/s
    assert asked == [9.0, 11.0] and hooked.history[0][0] == 3.0  # held inside the band, out at 13 m/s
    assert not in_band(plain.boundaries["too_fast"], {"v": 11.0}, 1.0, None)  # deterministic: no band
    gated = HybridAutomaton("car", ["cruise", "brake"], "cruise", [Transition(
        "cruise", "brake", plain.boundaries["too_fast"], "over the limit", when=lambda x: x["brakes_ok"])])
    gated.decider = never_inside
    asked.clear()
    for k, v in enumerate(speeds):
        gated.update(float(k), {"v": v, "brakes_ok": False})
    assert asked == [] and gated.mode == "cruise"
