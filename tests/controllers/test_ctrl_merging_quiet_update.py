"""``HybridAutomaton.quiet_update`` (issue 27's eighth CPU pass): the merge automata driven by it (and by
``update`` when it declines) jump, locate their crossings, log and keep their g values exactly as when driven
by ``update`` alone; it declines whenever a guard fires and whenever switching is stochastic or decided."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.merging.switching import (
    MergeBoundaries,
    MergeState,
    QuietMerge,
    VirtualGap,
    clone_automaton,
    merge_automaton,
    resolved,
)
from corridor.events import EventLog
from corridor.modes import SwitchingParams


def _states(rng: np.random.Generator, n: int) -> list[MergeState]:
    """A drifting vehicle: distance, predecessor's road and ahead flags, virtual gaps (some unknown)."""
    d = float(rng.uniform(50.0, 250.0))
    out = []
    for _ in range(n):
        d = max(d - float(rng.uniform(0.0, 3.0)), 0.0) if rng.random() < 0.95 else float(rng.uniform(0.0, 250.0))
        gap = (VirtualGap(True, float(rng.uniform(-15.0, 15.0)), float(rng.uniform(0.0, 30.0)), 0.1, 5.0)
               if rng.random() < 0.9 else VirtualGap(False))
        cross_pred = bool(rng.random() < 0.6)
        out.append(MergeState("ramp", d, cross_pred, _gap=gap, cross_ahead=bool(rng.random() < 0.3) and not cross_pred))
    return out


def _same(g: dict[str, float], h: dict[str, float]) -> bool:
    """The same boundaries in the same order with the same bits (NaN: a boundary without a known gap)."""
    return list(g) == list(h) and all(np.float64(g[k]).tobytes() == np.float64(h[k]).tobytes() for k in g)


@pytest.mark.parametrize("road", ["ramp", "main"])
def test_quiet_updates_leave_the_automaton_and_the_log_as_updates_do(road: str) -> None:
    rng = np.random.default_rng(3)
    theta = resolved(MergeBoundaries(open_ahead={"dist_m": 150.0}), 100.0)
    quiet_ticks = 0
    for case in range(30):
        a, b = merge_automaton("m", "v", road, theta), merge_automaton("m", "v", road, theta)
        ev_a, ev_b = EventLog(), EventLog()
        for j, x in enumerate(_states(rng, 300)):
            t = round(0.1 * (j + 1), 1)
            x.road = road
            a.update(t, x, ev_a, settle=3)
            if b.quiet_update(t, x):
                quiet_ticks += 1
            else:
                b.update(t, x, ev_b, settle=3)
            assert (b.mode, b._t_prev, b._t_last) == (a.mode, a._t_prev, a._t_last), (case, j)
            assert _same(b.g_now, a.g_now) and _same(b._g_prev, a._g_prev), (case, j)
        assert b.history == a.history and len(a.history) > 3
        assert [(e.t, e.kind, e.message, e.data) for e in ev_b.events] == [(e.t, e.kind, e.message, e.data)
                                                                           for e in ev_a.events]
    assert quiet_ticks > 1000


def test_quiet_update_declines_for_stochastic_switching_and_decided_outcomes() -> None:
    theta = resolved(MergeBoundaries(), 100.0)
    x = MergeState("ramp", 200.0, False)
    ha = merge_automaton("m", "v", "ramp", theta, SwitchingParams(temperature=0.1), np.random.default_rng(0))
    assert not ha.quiet_update(0.1, x)
    ha = merge_automaton("m", "v", "ramp", theta)
    assert ha.quiet_update(0.1, x)
    ha.decided["merge_enter"] = False
    assert not ha.quiet_update(0.2, x)
    ha = merge_automaton("m", "v", "ramp", theta)
    assert not ha.quiet_update(0.1, MergeState("ramp", 50.0, False))  # merge_enter holds: a jump
    assert ha.mode == "approach" and ha.g_now == {}  # nothing changed


def _edgy_states(seed: int, n: int) -> list[MergeState]:
    """``_states`` with a distance or a gap put exactly on a boundary now and then (g = 0: strict or not)."""
    rng = np.random.default_rng(seed)
    out = _states(rng, n)
    for x in out:
        u = rng.random()
        if u < 0.1:
            x.dist_m = float(rng.choice([100.0, 120.0, 150.0]))
        elif u < 0.2 and x._gap is not None and x._gap.known:
            x._gap.gap_m = float(rng.choice([-5.0, -2.5]))
    return out


@pytest.mark.parametrize("road", ["ramp", "main"])
@pytest.mark.parametrize("open_m", [0.0, 150.0])
def test_quiet_merge_is_quiet_update_written_out(road: str, open_m: float) -> None:
    """``QuietMerge`` (the eleventh CPU pass) against ``quiet_update``: the same answer on every state of
    drifting vehicles through every mode, the same g values (bits, keys, order) and times kept, the same
    jumps and log when both fall back to ``update``; each call reads the virtual gap only as the other does."""
    theta = resolved(MergeBoundaries(open_ahead={"dist_m": open_m}, gap_accept={"lag_lengths": 0.5},
                                     yield_exit={"dist_m": 120.0}), 100.0)
    quiet = QuietMerge(theta)
    seen: dict[str, int] = {}
    answers = {True: 0, False: 0}
    for case in range(40):
        a, b = merge_automaton("m", "v", road, theta), merge_automaton("m", "v", road, theta)
        ev_a, ev_b = EventLog(), EventLog()
        for j, (xa, xb) in enumerate(zip(_edgy_states(case, 300), _edgy_states(case, 300), strict=True)):
            t = round(0.1 * (j + 1), 1)
            xa.road = xb.road = road
            seen[a.mode] = seen.get(a.mode, 0) + 1
            assert quiet.usable(b)
            got_a, got_b = a.quiet_update(t, xa), quiet(b, t, xb)
            assert got_a == got_b, (case, j, a.mode)
            answers[got_a] += 1
            if not got_a:
                a.update(t, xa, ev_a, settle=3)
                b.update(t, xb, ev_b, settle=3)
            assert (b.mode, b._t_prev, b._t_last) == (a.mode, a._t_prev, a._t_last), (case, j)
            assert _same(b.g_now, a.g_now) and _same(b._g_prev, a._g_prev), (case, j)
            assert (xa._gap is None) == (xb._gap is None), (case, j)
        assert b.history == a.history
        assert [(e.t, e.kind, e.message, e.data) for e in ev_b.events] == [(e.t, e.kind, e.message, e.data)
                                                                           for e in ev_a.events]
    modes = {"ramp": {"approach", "behind", "ahead"}, "main": {"free", "open", "pass"} | ({"early"} if open_m else set())}
    assert modes[road] <= set(seen) and min(answers.values()) > 500, (seen, answers)


def test_quiet_merge_declines_as_quiet_update_does() -> None:
    theta = resolved(MergeBoundaries(), 100.0)
    quiet = QuietMerge(theta)
    ha = merge_automaton("m", "v", "ramp", theta, SwitchingParams(temperature=0.1), np.random.default_rng(0))
    assert not quiet.usable(ha)
    ha = merge_automaton("m", "v", "ramp", theta)
    ha.decided["merge_enter"] = False
    assert not quiet.usable(ha)
    ha = merge_automaton("m", "v", "ramp", theta)
    ha.decider = lambda *a: None
    assert not quiet.usable(ha)
    ha = merge_automaton("m", "v", "ramp", theta)
    assert not quiet(ha, 0.1, MergeState("ramp", 50.0, False))  # merge_enter holds: a jump
    assert ha.mode == "approach" and ha.g_now == {}  # nothing changed
    assert quiet(ha, 0.1, MergeState("ramp", 150.0, False)) and ha.g_now == {"merge_enter": -50.0}


@pytest.mark.parametrize("road", ["ramp", "main"])
def test_a_cloned_automaton_is_merge_automatons(road: str) -> None:
    """``clone_automaton`` (the thirteenth CPU pass) from a template that several clones share: each clone jumps,
    locates its crossings, logs (its own vehicle's tag and data) and keeps its g values exactly as the automaton
    ``merge_automaton`` builds for its vehicle, and shares no state with the template or the other clones."""
    theta = resolved(MergeBoundaries(open_ahead={"dist_m": 150.0}), 100.0)
    template = merge_automaton("m", "", road, theta)
    clones = [clone_automaton(template, f"v{case}") for case in range(10)]
    rng = np.random.default_rng(5)
    for case, b in enumerate(clones):
        a = merge_automaton("m", f"v{case}", road, theta)
        assert set(vars(b)) == set(vars(a))
        ev_a, ev_b = EventLog(), EventLog()
        for j, x in enumerate(_states(rng, 300)):
            t = round(0.1 * (j + 1), 1)
            x.road = road
            a.update(t, x, ev_a, settle=3)
            b.update(t, x, ev_b, settle=3)
            assert (b.mode, b._t_prev, b._t_last) == (a.mode, a._t_prev, a._t_last), (case, j)
            assert _same(b.g_now, a.g_now) and _same(b._g_prev, a._g_prev), (case, j)
        assert b.history == a.history and len(a.history) > 3
        assert [(e.t, e.source, e.kind, e.message, e.data) for e in ev_b.events] == [
            (e.t, e.source, e.kind, e.message, e.data) for e in ev_a.events]
    fresh = merge_automaton("m", "", road, theta)
    assert (template.mode, template.history, template.g_now, template.decided) == (
        fresh.mode, fresh.history, fresh.g_now, fresh.decided)  # the template untouched
    state = ("history", "g_now", "_g_prev", "decided", "_held", "pending_draws", "event_data")
    assert all(getattr(c, k) is not getattr(template, k) for c in clones for k in state)
    with pytest.raises(ValueError, match="random generator"):
        clone_automaton(merge_automaton("m", "", road, theta, SwitchingParams(temperature=0.1),
                                        np.random.default_rng(0)), "v")
