"""blrl's stochastic switching: one draw per band visit (no chatter), shared by a hysteresis pair,
and a learner that cannot invert an enter/exit hysteresis."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.controllers.merging.switching import MergeBoundaries, MergeState, merge_automaton, resolved
from corridor.errors import CorridorError
from corridor.events import EventLog
from corridor.modes import Boundary, HybridAutomaton, SwitchingParams, Transition


def _gate(temperature: float, seed: int = 0) -> HybridAutomaton:
    b = Boundary("enter", lambda x, th: th["dist_m"] - x, {"dist_m": 100.0})
    return HybridAutomaton("uav", ["mission", "avoid"], "mission", [Transition("mission", "avoid", b, "threat")],
                           switching=SwitchingParams(temperature=temperature), rng=np.random.default_rng(seed))


def test_an_agent_staying_in_the_band_keeps_its_one_draw() -> None:
    """T = 0.05: band 100 m x e^(+-0.2) = 82-122 m.  50 updates at 103 m are one band visit: one draw,
    one decision (before: a draw at every update).  Leaving the band (300 m) ends the visit; coming
    back draws again."""
    for seed in range(20):
        ha, ev = _gate(0.05, seed), EventLog()
        modes = []
        for k in range(50):
            ha.update(0.1 * k, 103.0, ev)
            modes.append(ha.mode)
        assert len(ev.of_kind("switch_draw")) == 1
        assert modes == [modes[0]] * 50
        ha.reset(0.0)
        ha.update(5.0, 300.0, ev)
        ha.update(5.1, 103.0, ev)
        assert len(ev.of_kind("switch_draw")) == 2


def test_the_draw_is_a_moved_boundary_with_the_score_of_its_log_density() -> None:
    """The held draw moves the gate to 100 e^eps m: the switch falls where d crosses it, and the
    score is d log f(eps) / d dist_m = tanh(eps / 2T) / (T dist_m)."""
    for seed in range(10):
        ha, ev = _gate(0.05, seed), EventLog()
        d_switch = None
        for k, d in enumerate(np.arange(125.0, 75.0, -0.25)):
            ha.update(0.1 * k, float(d), ev)
            if ha.mode == "avoid" and d_switch is None:
                d_switch = float(d)
        (draw,) = ev.of_kind("switch_draw")
        eps = draw.data["eps"]
        assert abs(eps) <= 4 * 0.05
        assert d_switch == pytest.approx(100.0 * math.exp(eps), abs=0.25)
        assert draw.data["score"] == {"enter.dist_m": pytest.approx(math.tanh(eps / 0.1) / (0.05 * 100.0))}


def _mainline(seed: int, temperature: float = 0.5) -> HybridAutomaton:
    theta = resolved(MergeBoundaries(), 100.0)
    return merge_automaton("merge", "m0", "main", theta, SwitchingParams(temperature=temperature),
                           np.random.default_rng(seed))


def test_a_mainline_vehicle_crossing_the_band_draws_once_and_switches_once() -> None:
    """The benchmark (b) defect: at T0 = 0.5 the band of the 100 m yield gate spans 14-740 m, and a
    draw at every 0.1 s update switched free <-> yield tick by tick (hundreds of mode events for
    one vehicle).  Now yield_enter and yield_exit share one draw per band visit: a vehicle driving
    from 800 m to the conflict point enters yield once and stays."""
    for seed in range(10):
        ha, ev = _mainline(seed), EventLog()
        for k, d in enumerate(np.arange(800.0, 0.0, -3.0)):  # 30 m/s, one update per 0.1 s
            ha.update(0.1 * k, MergeState("main", float(d), True), ev, settle=3)
        assert len(ev.of_kind("switch_draw")) == 1
        assert [(e.data["src"], e.data["dst"]) for e in ev.of_kind("mode")] == [("free", "open")]
        (draw,) = ev.of_kind("switch_draw")
        assert set(draw.data["score"]) == {"yield_enter.dist_m", "yield_exit.dist_m"}


def test_a_drawn_pair_keeps_its_hysteresis() -> None:
    """A vehicle standing at 100 m (both the enter and the exit gate) for 100 updates: one draw decides
    for both guards, so it never flips between yield and free."""
    for seed in range(20):
        ha, ev = _mainline(seed, 0.05), EventLog()
        for k in range(100):
            ha.update(0.1 * k, MergeState("main", 100.0, True), ev, settle=3)
        assert len(ev.of_kind("mode")) <= 1 and len(ev.of_kind("switch_draw")) == 1


KEYS = "merge_enter.dist_m,yield_enter.dist_m,yield_exit.dist_m,gap_accept.lag_lengths"


def _merge_problem(sets: list[str] | None = None):  # type: ignore[no-untyped-def]
    from corridor import learn

    return learn.problem("merging", KEYS, "-delay_mean_s", ["collisions == 0"], 32, "blrl", "v2x_cps", sets or [])


def test_the_learner_cannot_invert_the_yield_hysteresis() -> None:
    """blrl's run of benchmark (b) learned yield_exit = 55 m below yield_enter = 107 m: mainline
    vehicles between the two switched at every update.  The exit is now learned as a margin >= 0 in
    log units over the enter (and gap_accept stays <= gap_reject): no coordinates give an inverted
    pair, and the start maps to itself."""
    pb = _merge_problem()
    assert np.allclose(pb.theta(pb.u0()), pb.theta0)
    rng = np.random.default_rng(0)
    for _ in range(500):
        th = pb.theta(pb.u0() + rng.normal(0.0, 1.0, 4))
        assert th[2] >= th[1] and th[3] <= 1.0
    u = pb.u0()
    u[1], u[2] = math.log(107.0), math.log(55.0)  # the coordinates of the inverted pair, as before
    assert pb.theta(u)[2] >= pb.theta(u)[1]


def test_an_inverted_start_is_refused_with_one_line() -> None:
    base = "sweep.v2x_cps.controllers.merge.params.boundaries"
    with pytest.raises(CorridorError, match="yield_exit.dist_m = 55 and yield_enter.dist_m = 107 invert"):
        _merge_problem([f"{base}.yield_exit.dist_m=55", f"{base}.yield_enter.dist_m=107"])
