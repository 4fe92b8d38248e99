"""UAV avoidance controllers in the engine: they see the others only through the MAVLink link's
tracked picture, fly straight without it, and emit velocity commands the air backend flies."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from corridor.run import build
from corridor.scenario import validate


def scenario(controller: str, loss_p: float, duration: float = 4.0) -> Any:
    """Two quads 70 m apart flying head-on (goals swapped) and a c172x passing 1 km away."""
    return validate({
        "name": "t", "duration": duration, "dt": 0.1,
        "channels": {"m": {"range_m": 5000, "latency_s": 0.05, "jitter_s": 0.02,
                           "loss": {"model": "bernoulli", "p": loss_p}}},
        "backends": {
            "air": {"type": "jsbsim_fleet", "params": {"aircraft": [
                {"id": "a", "start_enu": (-35, 0, 50), "goal_enu": (200, 0, 50), "cruise_speed_mps": 6},
                {"id": "b", "start_enu": (35, 2, 50), "goal_enu": (-200, 2, 50), "cruise_speed_mps": 6},
                {"id": "c172", "model": "c172x", "start_enu": (0, -1000, 300), "yaw_deg": 0, "speed_mps": 50,
                 "role": "piloted"}]}},
            "link": {"type": "mavlink_link", "params": {"channel": "m"}},
        },
        "controllers": {"avoid": {"type": controller, "period": 0.2}},
        "monitors": {"sep": {"type": "uav_separation"}},
    }, "test")


def run(controller: str, loss_p: float, tmp_path: Path, duration: float = 4.0) -> tuple[dict[str, Any], Any]:
    sim = build(scenario(controller, loss_p, duration), 0, tmp_path)
    return sim.run(), sim


def test_controller_never_reads_the_others_from_the_snapshot(tmp_path: Path) -> None:
    # a link that delivers nothing: the other UAV, 70 m ahead and closing, is invisible -> no avoidance
    m_blind, sim_blind = run("potential_field", 1.0, tmp_path)
    assert m_blind["link_delivered"] == 0 and m_blind["link_fused_reports"] == 0
    assert m_blind["avoid_share"] == 0.0
    # the same encounter with a working link: the field reacts
    m, sim = run("potential_field", 0.0, tmp_path)
    assert m["link_fused_reports"] > 0 and m["avoid_share"] > 0.5
    assert any(e.kind == "mode" and "avoid" in e.message for e in sim.ctx.events.events)
    # and the trajectories differ only because of what the link delivered
    ia, ib = sim_blind.ctx.snapshot.index()["a"], sim.ctx.snapshot.index()["a"]
    assert abs(sim.ctx.snapshot.position[ib, 1] - sim_blind.ctx.snapshot.position[ia, 1]) > 0.5


def test_tracked_picture_matches_truth_and_flags_the_piloted_aircraft(tmp_path: Path) -> None:
    _, sim = run("uav_none", 0.0, tmp_path, duration=3.0)
    link, s = sim.ctx.get("link"), sim.ctx.snapshot
    picture = {o.id: o for o in link.picture("a", sim.ctx.t, s.position[s.index()["a"]])}
    assert set(picture) == {"b", "c172"}
    for oid, o in picture.items():
        k = s.index()[oid]
        # predicted over the link latency + the message period: within a metre / 0.5 m/s of the truth
        assert np.linalg.norm(o.pos - s.position[k]) < 1.0 + 0.02 * np.linalg.norm(s.velocity[k])
        assert np.linalg.norm(o.vel - s.velocity[k]) < 0.5 + 0.02 * np.linalg.norm(s.velocity[k])
        assert o.sigma_m > 0.0
    assert picture["c172"].is_piloted and not picture["b"].is_piloted


def test_uav_none_flies_straight_at_cruise_speed_and_tracks_nothing(tmp_path: Path) -> None:
    m, sim = run("uav_none", 0.0, tmp_path, duration=6.0)
    s = sim.ctx.snapshot
    a = s.index()["a"]
    assert m["link_fused_reports"] == 0 and m["avoid_share"] == 0.0
    assert s.velocity[a, 0] == pytest.approx(6.0, abs=0.3) and abs(s.position[a, 1]) < 0.3


def test_control_tube_turns_away_within_its_speed_limit(tmp_path: Path) -> None:
    m, sim = run("control_tube", 0.0, tmp_path)
    s = sim.ctx.snapshot
    a, b = s.index()["a"], s.index()["b"]
    assert m["avoid_share"] > 0.0 and m["tube_solver_failures"] == 0
    assert np.hypot(*s.velocity[a, :2]) < 6.0 + 0.5  # cruise speed is the UAV's limit
    # both turn right of their course (rules of the air): a (eastbound) goes south, b (westbound) north
    assert s.position[a, 1] < -1.0 and s.position[b, 1] > 3.0


def test_vertical_geofence_clamps_descent_near_the_floor() -> None:
    from corridor.controllers.uav.components import UavNone

    ctrl = UavNone("c", UavNone.Params(min_alt_m=15.0, max_alt_m=150.0, fence_gain_per_s=0.5), None)
    v = np.array([1.0, 0.0, -3.0])
    assert ctrl.fence(np.array([0.0, 0.0, 17.0]), v)[2] == pytest.approx(-1.0)  # 0.5 x 2 m above floor
    assert ctrl.fence(np.array([0.0, 0.0, 10.0]), v)[2] == pytest.approx(2.5)  # below: forced climb
    assert ctrl.fence(np.array([0.0, 0.0, 80.0]), v)[2] == pytest.approx(-3.0)  # free in between
    assert ctrl.fence(np.array([0.0, 0.0, 149.0]), -v)[2] == pytest.approx(0.5)


def test_relevance_range_leaves_far_uavs_untracked_but_keeps_near_ones_and_piloted(tmp_path: Path) -> None:
    """A UAV beyond the receiver's relevance range is neither fused nor tracked (its messages still
    arrive and are counted); a near one and the piloted aircraft are tracked."""
    from corridor.vehicles.mavlink.air_link import Relevance

    sc = scenario("uav_none", 0.0, duration=3.0).model_dump()
    sc["backends"]["air"]["params"]["aircraft"].append(
        {"id": "far", "start_enu": (-35, 600, 50), "goal_enu": (200, 600, 50), "cruise_speed_mps": 6})
    sim = build(validate(sc, "test"), 0, tmp_path)
    sim.run()
    link, s = sim.ctx.get("link"), sim.ctx.snapshot
    own = s.position[s.index()["a"]]
    pending = link.latest.copy()
    row = link.latest.receivers.index("a")

    def tracked() -> set[str]:
        return {src for src, alive in zip(link.latest.sources, link.tracks.alive[row], strict=True) if alive}

    fresh = {src for src, f in zip(pending.sources, pending.fresh[row], strict=True) if f}
    assert {"b", "far", "c172"} <= fresh  # every aircraft's reports reached a
    near = {o.id for o in link.picture("a", sim.ctx.t, own, Relevance(200.0, 2.5))}
    assert near == {"b", "c172"} and "far" not in tracked()
    link.latest = pending.copy()  # the same reports, no range: the far UAV is tracked as well
    assert {o.id for o in link.picture("a", sim.ctx.t, own)} == {"b", "c172", "far"}
    # a track that leaves the range is dropped at the next picture
    link.latest = pending.copy()
    assert {o.id for o in link.picture("a", sim.ctx.t, own, Relevance(10.0, 0.0))} == {"c172"}
    assert tracked() == {"c172"}
    assert link.finish(sim.ctx)["link_delivered"] > 0


def _at_relevance_edge(ctrl: Any, speed_mps: float, extra_m: float) -> Any:
    """An observation with one UAV head-on (closing at the worst case) just outside / inside the
    controller's relevance range, its track uncertainty within the margin."""
    from corridor.controllers.uav.models import AvoidanceObservation
    from corridor.vehicles.tracks.agent import TrackedAgent

    own_v = np.array([ctrl.cruise["a"], 0.0, 0.0])
    rel = ctrl.relevance("a", own_v)
    d = rel.base_m + rel.per_speed_s * speed_mps + extra_m
    other = TrackedAgent("x", np.array([d, 0.0, 50.0]), np.array([-speed_mps, 0.0, 0.0]), sigma_m=3.0)
    return AvoidanceObservation(0.0, np.array([0.0, 0.0, 50.0]), own_v, np.array([500.0, 0.0, 50.0]), (other,))


@pytest.mark.parametrize("controller", ["potential_field", "control_tube"])
def test_relevance_range_covers_everything_the_method_reacts_to(controller: str, tmp_path: Path) -> None:
    """Outside its relevance range an aircraft has no effect on the method (zero potential-field
    force / no tube); inside it (and nearer) it does: the range never hides an aircraft that matters."""
    sim = build(scenario(controller, 0.0), 0, tmp_path)
    for c in sim.ctx.components.values():
        c.setup(sim.ctx)
    ctrl = sim.ctx.get("avoid")
    method = ctrl.methods["a"]
    for speed in (0.0, 6.0, 10.0):
        outside = _at_relevance_edge(ctrl, speed, 1.0)
        alone = type(outside)(outside.t, outside.own_pos, outside.own_vel, outside.goal, ())
        if controller == "potential_field":
            assert np.array_equal(method.field(outside)[0], method.field(alone)[0])
            near = _at_relevance_edge(ctrl, speed, -ctrl.params.relevance_margin_m - 15.0)
            assert np.linalg.norm(method.field(near)[0] - method.field(alone)[0]) > 0.0
        else:
            v_ego = method._ego_speed_bound(outside.own_vel)
            assert method._relevant(outside, v_ego) == []
            near = _at_relevance_edge(ctrl, speed, -ctrl.params.relevance_margin_m - 5.0)
            assert len(method._relevant(near, v_ego)) == 1
    for c in sim.ctx.components.values():
        c.close()
