"""The ego bicycle in SUMO and the ``overtaking`` component, checked on short SUMO runs.

Closed forms (RK4 is exact for constant acceleration on a straight road), the SUMO row of the ego
against the ego's own state (front bumper, angle), SUMO traffic reacting to the ego, collisions seen by
SUMO's own check and by the kernel's box overlap, and the controller's road-frame observation.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from corridor.analysis.safety import obb_overlap_pairs
from corridor.controllers.overtaking.components import OvertakingSumo
from corridor.engine import Simulation
from corridor.run import build
from corridor.scenario import validate
from corridor.snapshot import Role
from corridor.traffic.sumo.backend import SumoBackend
from corridor.vehicles.ground.ego_bicycle import EgoBicycle, EgoInput

CAR = {"car_following": "Krauss", "sigma": 0.0, "length": 4.5, "width": 1.8, "max_speed": 30,
       "speed_dev": 0.0, "decel": 4.5}


def scenario(companions: dict[str, Any], oncoming_vph: float = 0.0, controller: bool = False,
             duration: float = 10.0) -> Any:
    """A 1.5 km rural road, the ego at 300 m (15 m/s) from t = 0, optional oncoming flow."""
    data: dict[str, Any] = {
        "name": "ego_test", "duration": duration, "dt": 0.1,
        "road": {"network": {"type": "rural_two_lane", "params": {"length_m": 1500, "speed_mps": 25}},
                 "demand": {"vehicle_types": {"car": CAR, "ego": {**CAR, "decel": 6.0, "length": 5.5}},
                            "flows": {}},
                 "sumo": {"time_to_teleport": -1}},
        "backends": {"ego": {"type": "ego_bicycle", "params": {
            "depart_s": 0.0, "depart_pos_m": 300.0, "depart_speed_mps": 15.0, "companions": companions}}},
    }
    if oncoming_vph > 0:
        data["road"]["demand"]["flows"]["oncoming"] = {"route": "west", "vtype": "car", "flow_vph": oncoming_vph,
                                                       "arrivals": "uniform"}
    if controller:
        data["controllers"] = {"overtaking": {"type": "overtaking", "params": {"sensor_pos_noise_m": 0.0,
                                                                               "sensor_speed_noise_mps": 0.0}}}
        data["monitors"] = {"safety": {"type": "overtaking_safety"}}  # the spec signals (not the controller's)
    return validate(data, "test")


def started(sc: Any, tmp_path: Path, seed: int = 0) -> Simulation:
    sim = build(sc, seed, tmp_path)
    for c in sim.ctx.components.values():
        c.setup(sim.ctx)
    return sim


def run_ticks(sim: Simulation, n: int, u: tuple[float, float] | None = None) -> None:
    for _ in range(n):
        if u is not None:
            sim.ctx.commands.append(EgoInput("ego", *u))
        sim.step()


@pytest.fixture
def close_after() -> Any:
    sims: list[Simulation] = []
    yield sims
    for sim in sims:
        for c in sim.ctx.components.values():
            c.close()


def ego_row(sim: Simulation) -> int:
    return sim.ctx.snapshot.index()["ego"]


def test_constant_accel_closed_form_and_sumo_row(tmp_path: Path, close_after: list[Simulation]) -> None:
    sim = started(scenario({}), tmp_path)
    close_after.append(sim)
    ego: EgoBicycle = sim.ctx.get("ego")  # type: ignore[assignment]
    run_ticks(sim, 2)  # departs in the first step, corridor takes over in the second
    assert ego.active
    x0, v0 = float(ego.state[0]), float(ego.state[3])
    assert v0 == pytest.approx(15.0)
    run_ticks(sim, 30, u=(1.0, 0.0))  # 3 s at 1 m/s^2
    t = 3.0
    assert ego.state[0] == pytest.approx(x0 + v0 * t + 0.5 * t * t, abs=1e-6)
    assert ego.state[3] == pytest.approx(v0 + t, abs=1e-9)
    s = sim.ctx.snapshot
    k = ego_row(sim)
    assert list(s.ids).count("ego") == 1  # the ego is in the snapshot exactly once
    assert s.role[k] == Role.CONTROLLED
    assert s.size[k, 0] == pytest.approx(ego.p.bicycle.length_m)  # the bicycle's box, not the vType's 5.5 m
    centre = ego.state[:2] + 0.5 * ego.p.bicycle.wheelbase_m * np.array([math.cos(ego.state[2]), math.sin(ego.state[2])])
    assert np.allclose(s.position[k, :2], centre, atol=1e-3)  # SUMO put it where corridor integrated it
    assert s.heading[k] == pytest.approx(ego.state[2], abs=1e-6)
    # SUMO reports the distance moved in its last step over the step: the step's mean speed
    assert s.speed[k] == pytest.approx(ego.state[3] - 0.5 * 1.0 * 0.1, abs=1e-3)


def test_steering_moves_ego_into_the_opposite_lane(tmp_path: Path, close_after: list[Simulation]) -> None:
    sim = started(scenario({}), tmp_path)
    close_after.append(sim)
    ego: EgoBicycle = sim.ctx.get("ego")  # type: ignore[assignment]
    sumo: SumoBackend = sim.ctx.get("road")  # type: ignore[assignment]
    run_ticks(sim, 2)
    y0 = float(ego.state[1])
    run_ticks(sim, 10, u=(0.0, 0.03))  # steer left ...
    run_ticks(sim, 10, u=(0.0, -0.03))  # ... and straighten
    assert ego.state[1] - y0 > 2.0
    k = ego_row(sim)
    assert sumo.snapshot_part().position[k, 1] > 0.0  # SUMO sees it left of the centreline
    road = sim.ctx.snapshot.road
    assert road.tables.lane_names[road.lane[k - road.offset]].startswith("west")  # mapped onto the oncoming lane


def test_follower_reacts_to_ego_braking(tmp_path: Path, close_after: list[Simulation]) -> None:
    sim = started(scenario({"follower": {"offset_m": -25.0, "speed_mps": 15.0}}), tmp_path)
    close_after.append(sim)
    run_ticks(sim, 10, u=(0.0, 0.0))
    k = sim.ctx.snapshot.index()["follower"]
    v_before = float(sim.ctx.snapshot.speed[k])
    run_ticks(sim, 40, u=(-3.0, 0.0))  # the ego brakes to 3 m/s
    s = sim.ctx.snapshot
    k = s.index()["follower"]
    assert v_before > 14.0
    assert s.speed[k] < 8.0  # SUMO's driver slowed down behind the ego
    assert sim.ctx.get("collisions").pairs == {}


def test_rear_end_collision_seen_by_sumo_and_by_box_overlap(tmp_path: Path,
                                                            close_after: list[Simulation]) -> None:
    # far enough ahead that SUMO's insertion check lets the slow car in at t = 0
    sim = started(scenario({"lead": {"offset_m": 60.0, "speed_mps": 3.0, "max_speed_mps": 3.0}}), tmp_path)
    close_after.append(sim)
    sumo_collisions: list = []
    seen_box = False
    for _ in range(70):
        run_ticks(sim, 1, u=(0.0, 0.0))  # the ego keeps 15 m/s into a 3 m/s car 55 m ahead
        if sim.ctx.t < 0.15:
            assert "lead" in sim.ctx.snapshot.index()
        s = sim.ctx.snapshot
        pairs = obb_overlap_pairs(s.position[:, :2], s.heading, s.size[:, 0], s.size[:, 1],
                                  s.position[:, 2], s.size[:, 2])
        seen_box |= any({str(s.ids[i]), str(s.ids[j])} == {"ego", "lead"} for i, j in pairs)
        sumo_collisions += s.road.events.collisions
    assert seen_box
    assert any({c[1], c[2]} == {"ego", "lead"} for c in sumo_collisions)
    assert ("ego", "lead") in sim.ctx.get("collisions").pairs


def test_observation_in_road_frame(tmp_path: Path, close_after: list[Simulation]) -> None:
    comps = {"lead": {"offset_m": 30.0, "speed_mps": 14.0, "max_speed_mps": 14.0},
             "follower": {"offset_m": -30.0, "speed_mps": 15.0}}
    sc = scenario(comps, oncoming_vph=900.0, controller=True, duration=60.0)
    sim = started(sc, tmp_path)
    close_after.append(sim)
    ctrl: OvertakingSumo = sim.ctx.get("overtaking")  # type: ignore[assignment]
    run_ticks(sim, 3)
    obs = ctrl.observe(sim.ctx)
    assert obs is not None
    assert obs.lead is not None and obs.lead.id == "lead"
    s = sim.ctx.snapshot
    assert obs.lead.x_m == pytest.approx(s.position[s.index()["lead"], 0], abs=1e-9)
    assert [f.id for f in obs.followers] == ["follower"]
    assert abs(obs.ego[1]) < 0.05 and abs(obs.ego[2]) < 1e-6  # in the own lane centre, along the road
    run_ticks(sim, 250)  # oncoming traffic arrives from the far end
    obs = ctrl.observe(sim.ctx)
    assert obs is not None and obs.oncoming
    assert all(o.v_mps < 0 for o in obs.oncoming)
    for name in ("gap_lead", "ahead_lead", "lat_lead", "lat_onc", "gap_onc", "lane_offset"):
        t, v = sim.ctx.signals.get(name)
        assert len(t) > 50 and np.all(np.isfinite(v))
