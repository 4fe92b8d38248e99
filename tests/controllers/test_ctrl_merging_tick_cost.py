"""V2X merging: the tick's cheaper paths give the bits of the ones they replaced (issue 27, the sixth and
seventh CPU passes).  The lane leaders (the safety layer's cap against the physical leader) come with the
compiled CAM stage, and a state without them searches them once, in the first commanding tick; the
crossing speed is the mainline's mean speed upstream of the zone with ``np.mean``'s bits."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.controllers.merging.components import V2XMerging, deliverable_safety
from corridor.controllers.merging.safety_layer import lane_leaders, safe_accel
from corridor.scenario import load
from corridor.variants import variant_scenarios
from tests.conftest import scenario_file


def _controller() -> V2XMerging:
    sc, _ = load(scenario_file("merging"), [])
    vsc = variant_scenarios(sc)["v2x_cps"]
    comp = V2XMerging("merge", V2XMerging.Params.model_validate(dict(vsc.controllers["merge"].params)), vsc)
    comp.safety = deliverable_safety(comp.p.safety, vsc, comp.p.command_speed_mode, comp.period)
    return comp


def _state(rng: np.random.Generator, n: int) -> dict:
    """A tick's sensed state as ``_sense`` returns it (the fields the tested paths read)."""
    lane = rng.integers(0, 3, n)
    lane_pos = np.round(rng.uniform(0.0, 400.0, n), 1)  # rounded: ties on a lane occur
    return {"lane": lane, "lane_pos": lane_pos, "length": rng.uniform(4.0, 12.0, n), "speed": rng.uniform(0.0, 35.0, n),
            "dist": rng.uniform(-100.0, 800.0, n), "ramp": rng.random(n) < 0.3}


def _run_v2x_cps(tmp_path) -> None:
    """merging's ``v2x_cps``, seed 0, 60 s without warm-up, in this process (so monkeypatches apply)."""
    from corridor.run import build

    sc, _ = load(scenario_file("merging"), ["duration=60", "warmup=0", "outputs.signals=false"])
    sim = build(variant_scenarios(sc)["v2x_cps"], 0, tmp_path)
    try:
        for c in sim.setup_order:
            c.setup(sim.ctx)
        for _ in range(round(sim.ctx.duration / sim.ctx.dt)):
            sim.step()
    finally:
        for c in sim.ctx.components.values():
            c.close()


def test_the_lane_leaders_are_found_once_a_tick_and_only_when_a_vehicle_is_capped() -> None:
    comp = _controller()
    rng = np.random.default_rng(27)
    for _ in range(50):
        s = _state(rng, int(rng.integers(2, 60)))
        assert "leader" not in s
        leaders = lane_leaders(s["lane"], s["lane_pos"])
        for k in rng.permutation(len(s["lane"]))[:5].tolist():
            acc = comp._physical_leader_cap(s, k, 1.0)
            j = int(leaders[k])
            want = 1.0 if j < 0 else safe_accel(float(s["lane_pos"][j] - s["length"][j] - s["lane_pos"][k]),
                                                float(s["speed"][k]), float(s["speed"][j]), 1.0, comp.safety)
            assert acc == want
        np.testing.assert_array_equal(s["leader"], leaders)


def test_every_tick_has_the_lane_leaders_of_the_compiled_stage(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """A real 60 s ``v2x_cps`` run: since the seventh CPU pass the lane leaders of every row come with the
    compiled CAM stage (``cam_kernel.lane_leaders``, every tick) instead of a lexsort in the first
    commanding tick (the sixth pass); they are ``safety_layer.lane_leaders``' in every tick, and the
    controller's own search never runs."""
    from corridor.controllers.merging import components
    from corridor.traffic.sumo.commands import SetSpeed

    calls, checked, commanding = [0], [0], [0]
    search, decide = components.lane_leaders, V2XMerging._decide

    def counted_search(*a):  # type: ignore[no-untyped-def]
        calls[0] += 1
        return search(*a)

    def checked_decide(self, t, s, *a):  # type: ignore[no-untyped-def]
        np.testing.assert_array_equal(s["leader"], lane_leaders(s["lane"], s["lane_pos"]))
        checked[0] += 1
        cmds = decide(self, t, s, *a)
        commanding[0] += any(isinstance(c, SetSpeed) for c in cmds)
        return cmds

    monkeypatch.setattr(components, "lane_leaders", counted_search)
    monkeypatch.setattr(V2XMerging, "_decide", checked_decide)
    _run_v2x_cps(tmp_path)
    assert checked[0] > 400 and commanding[0] > 100  # the run commands vehicles
    assert calls[0] == 0


@pytest.mark.parametrize("n", [0, 1, 7, 200])
def test_the_crossing_speed_has_the_bits_of_np_mean(n: int) -> None:
    comp = _controller()
    rng = np.random.default_rng(n)
    for _ in range(200):
        s = _state(rng, n)
        zone = comp.p.coordinator.control_zone_m
        near = ~s["ramp"] & (s["dist"] > zone) & (s["dist"] < zone + 300.0)
        v = float(np.mean(s["speed"][near])) if near.any() else comp.p.limits.v_max_mps
        want = min(max(v, 8.0), comp.p.limits.v_max_mps)
        assert comp._stream_speed(s) == want


def test_a_run_senses_from_the_raw_poses_with_the_geometrys_bits(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """A real 60 s ``v2x_cps`` run (issue 27's ninth CPU pass): a tick whose snapshot geometry is not derived
    yet is sensed from SUMO's raw poses without deriving it, and its speeds, front x and centres are the
    geometry's (a tick whose geometry a monitor derived before takes the geometry's path)."""
    from corridor.controllers.merging.cam_kernel import front_and_centre

    sense, seen = V2XMerging._sense, [0]

    def checked_sense(self, ctx):  # type: ignore[no-untyped-def]
        snap = ctx.snapshot
        lazy = bool(snap.pending_poses())  # not derived yet (a monitor derives it on some ticks before)
        s = sense(self, ctx)
        if s is None or not lazy:
            return s
        assert "poses" in s and snap.pending_poses()  # still not derived after _sense
        sl = snap.road.sl
        pos, size = snap.position[sl], snap.size[sl]  # derived here, for the check (elementwise: same bits)
        assert s["speed"].tobytes() == snap.speed[sl].tobytes()
        n = len(s["ids"])
        front_x, centre = np.empty(n), np.empty((n, 2))
        front_and_centre(*s["poses"][:2], *s["poses"][2:], front_x, centre)
        assert front_x.tobytes() == (pos[:, 0] + 0.5 * size[:, 0] * np.cos(snap.heading[sl])).tobytes()
        assert centre.tobytes() == np.ascontiguousarray(pos[:, :2]).tobytes()
        seen[0] += 1
        return s

    monkeypatch.setattr(V2XMerging, "_sense", checked_sense)
    _run_v2x_cps(tmp_path)
    assert seen[0] > 400
