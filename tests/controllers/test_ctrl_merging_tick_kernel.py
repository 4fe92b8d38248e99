"""V2X merging: the CAM stage, the delivery and fuse, and the coordination in one compiled call
(``tick_kernel.fused_tick_into``, issue 27's ninth CPU pass) give what the three separate calls give: two
real runs side by side, one with the fused call and one without it, the same commands every tick, the same
tracks, coordinator state, assignments, event log and metrics; the Python steps around the call (the
admission, the fuse completed for a new interval, the pool of sensor draws refilled) all happen in them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numba import types

from corridor.controllers.merging.components import V2XMerging
from corridor.run import build
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file


def _run(variant: str, fused: bool, tmp: Path, monkeypatch: pytest.MonkeyPatch, extra: list[str]) -> dict:
    counts = {"fused": 0, "admit": 0, "own_coordination": 0, "draws": 0}
    setup, fused_call, admit = V2XMerging.setup, V2XMerging._fused_call, V2XMerging._admit
    coordinate, coordinated, decide = V2XMerging._coordinate, V2XMerging._coordinated, V2XMerging._decide
    commands: list[str] = []

    def logged_decide(self, t, s, zone, target):  # type: ignore[no-untyped-def]
        cmds = decide(self, t, s, zone, target)
        commands.append(f"{target!r} {sorted(zone.items())!r} {cmds!r}")
        return cmds

    def set_up(self, ctx):  # type: ignore[no-untyped-def]
        setup(self, ctx)
        self._fused = self._fused and fused

    def counted_call(self, t, s):  # type: ignore[no-untyped-def]
        counts["fused"] += 1
        return fused_call(self, t, s)

    def counted_admit(self, t, s):  # type: ignore[no-untyped-def]
        counts["admit"] += 1
        return admit(self, t, s)

    def counted_coordinate(self, t, s, target):  # type: ignore[no-untyped-def]
        counts["own_coordination"] += 1
        return coordinate(self, t, s, target)

    def counted_coordinated(self, t, s, target, status, nz, n):  # type: ignore[no-untyped-def]
        counts["draws"] += status == 2
        return coordinated(self, t, s, target, status, nz, n)

    with monkeypatch.context() as m:
        m.setattr(V2XMerging, "setup", set_up)
        m.setattr(V2XMerging, "_fused_call", counted_call)
        m.setattr(V2XMerging, "_admit", counted_admit)
        m.setattr(V2XMerging, "_coordinate", counted_coordinate)
        m.setattr(V2XMerging, "_coordinated", counted_coordinated)
        m.setattr(V2XMerging, "_decide", logged_decide)
        sc, _ = load(scenario_file("merging"), ["duration=90", "warmup=0", "outputs.signals=false", *extra])
        sim = build(variant_scenarios(sc)[variant], 0, tmp)
        ctl = sim.ctx.components["merge"]
        ticks = []
        try:
            for c in sim.setup_order:
                c.setup(sim.ctx)
            for _ in range(round(sim.ctx.duration / sim.ctx.dt)):
                sim.step()
                tracks = ctl.tracks
                ticks.append((repr(ctl.assigned), list(ctl.coord.sequence), tracks.x.tobytes(), tracks.P.tobytes(),
                              tracks.t_s.tobytes(), ctl.controlled.copy(), commands[-1] if commands else ""))
            metrics = ctl.finish(sim.ctx)
        finally:
            for c in sim.ctx.components.values():
                c.close()
    events = [(e.t, e.source, e.kind, e.message, sorted(e.data.items())) for e in sim.ctx.events.events]
    return {"ticks": ticks, "metrics": metrics, "events": events, "counts": counts,
            "draws": ctl.sensor_rng.standard_normal(), "channel": ctl.channel.stats()}


# the flagship's channel, a lossy one whose queue overflows (its room is the send's), bursty loss (a third uniform
# per copy in range)
@pytest.mark.parametrize(("variant", "extra"), [
    ("v2x_cps", []), ("v2x_fifo", []),
    ("v2x_cps", ["channels.v2x.max_in_flight=40", "channels.v2x.loss.p=0.2", "channels.v2x.jitter_s=0.3"]),
    ("v2x_fifo", ["channels.v2x.loss={model: gilbert_elliott, p_good_to_bad: 0.05, p_bad_to_good: 0.3}"])])
def test_the_fused_call_gives_the_separate_calls_bit_for_bit(variant: str, extra: list[str], tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    got = _run(variant, True, tmp_path / "a", monkeypatch, extra)
    want = _run(variant, False, tmp_path / "b", monkeypatch, extra)
    assert want["counts"]["fused"] == 0
    c = got["counts"]
    assert c["fused"] > 700 and c["admit"] > 50 and c["own_coordination"] >= 1 and c["draws"] >= 1, c
    assert len(got["ticks"]) == len(want["ticks"])
    for j, (a, b) in enumerate(zip(got["ticks"], want["ticks"], strict=True)):
        assert a == b, j
    assert got["events"] == want["events"] and len(got["events"]) > 10
    for k, v in want["metrics"].items():
        assert (np.isnan(v) and np.isnan(got["metrics"][k])) if isinstance(v, float) and np.isnan(v) else got["metrics"][k] == v, k
    assert got["draws"] == want["draws"] and repr(got["channel"]) == repr(want["channel"])
    st = got["channel"]
    if extra:  # the lossy channels lose copies; the small queue overflows
        assert st.lost_random > 100, st
        assert (st.dropped_overflow > 100) == any("max_in_flight" in e for e in extra), st


def test_every_call_passes_the_types_the_entry_point_was_compiled_for(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The controller calls the compiled overload's entry point (``tick_kernel.FUSED_TICK``), which unboxes its
    arguments for the one signature without checking them: on every call of real runs (the flagship's channel
    and a lossy one) each argument's type is the signature's, or one the dispatcher converts to it (a writable
    array for a read-only one)."""
    from numba import typeof

    from corridor.controllers.merging import components
    from corridor.controllers.merging.tick_kernel import FUSED_TICK, fused_tick_into

    assert FUSED_TICK is not fused_tick_into and len(fused_tick_into.signatures) == 1
    declared = fused_tick_into.signatures[0]
    conv = fused_tick_into.typingctx.can_convert
    calls = [0]

    def checked(*args):  # type: ignore[no-untyped-def]
        calls[0] += 1
        assert len(args) == len(declared)
        for j, (a, ty) in enumerate(zip(args, declared, strict=True)):
            got = typeof(a)
            assert got == ty or conv(got, ty) is not None and (not isinstance(ty, types.Array) or (
                got.dtype == ty.dtype and got.ndim == ty.ndim and (got.mutable or not ty.mutable))), (j, got, ty)
        return FUSED_TICK(*args)

    monkeypatch.setattr(components, "FUSED_TICK", checked)
    _run("v2x_cps", True, tmp_path / "a", monkeypatch, [])
    _run("v2x_fifo", True, tmp_path / "b", monkeypatch, ["channels.v2x.loss.p=0.2", "channels.v2x.max_in_flight=40"])
    assert calls[0] > 1500


def test_the_admission_updates_the_rows_nodes_as_a_rebuild_would(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """``_admit`` writes the nodes it registered into the rows' node array in place (the eleventh CPU pass; it
    made the array again): after every admission of a real run the array is each row's node by name."""
    admit = V2XMerging._admit
    seen = {"in_place": 0, "checked": 0}

    def checked_admit(self, t, s):  # type: ignore[no-untyped-def]
        seen["in_place"] += self._row_node_key is s["ids"]
        admit(self, t, s)
        index = self.channel.index
        got = self._row_nodes(s)
        assert got.tolist() == [index.get(v, -1) for v in s["ids"]], t
        seen["checked"] += 1

    monkeypatch.setattr(V2XMerging, "_admit", checked_admit)
    _run("v2x_cps", True, tmp_path / "a", monkeypatch, [])
    _run("v2x_fifo", False, tmp_path / "b", monkeypatch, ["channels.v2x.latency_s=0", "channels.v2x.jitter_s=0"])
    assert seen["in_place"] > 100 and seen["checked"] > 200, seen
