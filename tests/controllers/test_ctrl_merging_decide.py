"""V2X merging's decisions (issue 27, the eleventh and thirteenth CPU passes): ``_decide`` with the quiet vehicles
in one compiled call (``decide_kernel.decide_into``, the thirteenth), and its Python path (the merge automata's
quiet updates written out (``switching.QuietMerge``), the physical leader's cap and the commanded speed inline and
the rows read per vehicle, the eleventh) give what the general path gives (every automaton updated through
``HybridAutomaton.update``, the cap and the speed through ``_physical_leader_cap`` and ``_command_speed``):
real runs side by side, the same commands, modes and g values every tick, the same event log and metrics."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from corridor.controllers.merging import components
from corridor.controllers.merging.components import V2XMerging
from corridor.controllers.merging.switching import QuietMerge
from corridor.run import build
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file


def _run(variant: str, path: str, tmp: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """A 120 s run of ``variant`` with its decisions ``path``: "compiled" (the default), "python" (the compiled
    call off) or "general" (the reference); every tick's commands, automata and smallest virtual gap."""
    general = path == "general"
    counts = {"quiet": 0, "cap": 0, "speed": 0, "compiled": 0}
    decide, quiet = V2XMerging._decide, QuietMerge.__call__
    decide_into = components.decide_into
    cap, speed = V2XMerging._physical_leader_cap, V2XMerging._command_speed
    automaton = V2XMerging._automaton
    ticks: list[str] = []

    def logged_decide(self, t, s, zone, target):  # type: ignore[no-untyped-def]
        if general:  # the reference: the cap as a method
            self.__dict__["_physical_leader_cap"] = self._physical_leader_cap  # the cap as a method
        cmds = decide(self, t, s, zone, target)
        modes = [(v, ha.mode, ha._t_prev, ha._t_last, {k: np.float64(g).tobytes() for k, g in ha.g_now.items()},
                  {k: np.float64(g).tobytes() for k, g in ha._g_prev.items()}) for v, ha in self.automata.items()]
        ticks.append(f"{cmds!r} {modes!r} {self.min_virtual_gap!r}")
        return cmds

    def general_automaton(self, vid, road):  # type: ignore[no-untyped-def]
        ha = automaton(self, vid, road)
        if general:  # the reference: every automaton through update (a decider that leaves it the decision)
            ha.decider = lambda *a: None
        return ha

    def counted_quiet(self, ha, t, x):  # type: ignore[no-untyped-def]
        counts["quiet"] += 1
        return quiet(self, ha, t, x)

    def counted_cap(self, s, k, acc):  # type: ignore[no-untyped-def]
        counts["cap"] += 1
        return cap(self, s, k, acc)

    def counted_speed(self, v, acc):  # type: ignore[no-untyped-def]
        counts["speed"] += 1
        return speed(self, v, acc)

    def counted_decide_into(*args):  # type: ignore[no-untyped-def]
        counts["compiled"] += args[2].shape[0] - decide_into(*args)  # the vehicles it decided
        return 0

    with monkeypatch.context() as m:
        m.setattr(components, "decide_into", counted_decide_into)
        m.setattr(V2XMerging, "compiled_decisions", path == "compiled")
        m.setattr(V2XMerging, "clone_automata", not general)  # the reference: merge_automaton per vehicle
        m.setattr(V2XMerging, "_decide", logged_decide)
        m.setattr(V2XMerging, "_automaton", general_automaton)
        m.setattr(QuietMerge, "__call__", counted_quiet)
        m.setattr(V2XMerging, "_physical_leader_cap", counted_cap)
        m.setattr(V2XMerging, "_command_speed", counted_speed)
        sc, _ = load(scenario_file("merging"), ["duration=120", "warmup=0", "outputs.signals=false"])
        sim = build(variant_scenarios(sc)[variant], 0, tmp)
        ctl = sim.ctx.components["merge"]
        try:
            for c in sim.setup_order:
                c.setup(sim.ctx)
            for _ in range(round(sim.ctx.duration / sim.ctx.dt)):
                sim.step()
            metrics = ctl.finish(sim.ctx)
        finally:
            for c in sim.ctx.components.values():
                c.close()
    events = [(e.t, e.source, e.kind, e.message, sorted(e.data.items())) for e in sim.ctx.events.events]
    return {"ticks": ticks, "metrics": metrics, "events": events, "counts": counts}


def _same(fast: dict[str, Any], ref: dict[str, Any]) -> None:
    assert len(fast["ticks"]) == len(ref["ticks"]) > 1000
    for j, (a, b) in enumerate(zip(fast["ticks"], ref["ticks"], strict=True)):
        assert a == b, j
    assert sum("mode" == e[2] for e in ref["events"]) > 20
    assert fast["events"] == ref["events"]
    assert repr(fast["metrics"]) == repr(ref["metrics"])


@pytest.mark.parametrize("variant", ["v2x_cps", "v2x_fifo"])
def test_decide_as_the_general_path(variant: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ref = _run(variant, "general", tmp_path / "ref", monkeypatch)
    assert ref["counts"]["quiet"] == ref["counts"]["compiled"] == 0
    assert ref["counts"]["cap"] > 500 and ref["counts"]["speed"] > 500
    py = _run(variant, "python", tmp_path / "py", monkeypatch)
    assert py["counts"]["quiet"] > 1000 and py["counts"]["compiled"] == 0
    assert py["counts"]["cap"] == py["counts"]["speed"] == 0
    _same(py, ref)
    fast = _run(variant, "compiled", tmp_path / "fast", monkeypatch)
    # the compiled call decides most vehicles; the Python path the few whose automaton jumps or is new
    assert fast["counts"]["compiled"] > 10 * fast["counts"]["quiet"] > 100
    assert fast["counts"]["cap"] == fast["counts"]["speed"] == 0
    _same(fast, ref)
