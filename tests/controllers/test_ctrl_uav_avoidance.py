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
    from corridor.controllers.uav_avoidance import UavNone

    ctrl = UavNone("c", UavNone.Params(min_alt_m=15.0, max_alt_m=150.0, fence_gain_per_s=0.5), None)
    v = np.array([1.0, 0.0, -3.0])
    assert ctrl.fence(np.array([0.0, 0.0, 17.0]), v)[2] == pytest.approx(-1.0)  # 0.5 x 2 m above floor
    assert ctrl.fence(np.array([0.0, 0.0, 10.0]), v)[2] == pytest.approx(2.5)  # below: forced climb
    assert ctrl.fence(np.array([0.0, 0.0, 80.0]), v)[2] == pytest.approx(-3.0)  # free in between
    assert ctrl.fence(np.array([0.0, 0.0, 149.0]), -v)[2] == pytest.approx(0.5)
