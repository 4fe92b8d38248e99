"""Air backend: encounter/swarm geometry in closed form, bus commands flown by JSBSim, snapshot kinds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from corridor.engine import Controller, RunContext, Simulation
from corridor.scenario import validate
from corridor.snapshot import Kind
from corridor.vehicles.air.autopilot import VelocityCommand
from corridor.vehicles.air.backend import (
    AirBackend,
    AircraftCommand,
    EncounterSpec,
    SwarmSpec,
    encounter_aircraft,
    swarm_aircraft,
)


@pytest.mark.parametrize("geometry, rel_deg", [(0, 180.0), (1, 90.0), (2, 0.0)])
def test_encounter_paths_meet_at_the_conflict_point_at_the_same_time(geometry: int, rel_deg: float) -> None:
    e = EncounterSpec(geometry=geometry, course_deg=30.0, heading_offset_deg=10.0, alt_offset_m=2.0,
                      conflict_enu=(5.0, -7.0, 60.0), time_to_conflict_s=20.0)
    a, b, c172 = encounter_aircraft(e)
    c = np.array(e.conflict_enu)
    for ac, lift in ((a, 0.0), (b, 2.0)):
        start, goal = np.array(ac.start_enu), np.array(ac.goal_enu)
        # straight at cruise speed: at the conflict point (B shifted by alt_offset) after exactly 20 s
        assert np.linalg.norm(start + (goal - start) / np.linalg.norm(goal - start) * ac.cruise_speed_mps * 20.0
                              - (c + [0, 0, lift])) == pytest.approx(0.0, abs=1e-9)
    course = {ac.id: np.degrees(np.arctan2(*(np.subtract(ac.goal_enu, ac.start_enu)[1::-1]))) for ac in (a, b)}
    assert (course["uav_b"] - course["uav_a"] - rel_deg - 10.0 + 180.0) % 360.0 == pytest.approx(180.0)
    if geometry == 2:
        assert b.cruise_speed_mps > a.cruise_speed_mps
    # the goals are apart (beyond LoS): the UAVs do not end up hovering inside each other's cylinder
    assert np.linalg.norm(np.subtract(a.goal_enu, b.goal_enu)) > 61.0
    assert c172.model == "c172x" and c172.is_piloted and c172.speed_mps == 50.0
    # the c172 is over the conflict point (30 m up) after piloted_time_s at its speed
    over = np.array(c172.start_enu) + 50.0 * e.piloted_time_s * np.array(
        [np.cos(np.radians(120.0)), np.sin(np.radians(120.0)), 0.0])
    assert np.allclose(over, c + [0, 0, 30.0], atol=1e-6)


def test_swarm_goals_are_antipodal_through_the_centre() -> None:
    ac = swarm_aircraft(SwarmSpec(n=12, centre_enu=(10.0, 20.0, 60.0), radius_m=100.0))
    assert len({a.id for a in ac}) == 12
    for a in ac:
        mid = (np.array(a.start_enu) + np.array(a.goal_enu)) / 2.0
        assert np.allclose(mid, [10.0, 20.0, 60.0]) and np.linalg.norm(np.subtract(a.goal_enu, a.start_enu)) == pytest.approx(200.0)


def test_duplicate_ids_are_rejected() -> None:
    with pytest.raises(ValidationError, match="unique"):
        AirBackend.Params(aircraft=[{"id": "q", "start_enu": (0, 0, 10)}, {"id": "q", "start_enu": (5, 0, 10)}])


class ConstantVelocity(Controller):
    """Puts one velocity command (and a command for an unknown aircraft) on the bus every period."""

    def __init__(self, v_enu: tuple[float, float, float]) -> None:
        super().__init__("cmd")
        self.period = 0.5
        self.v_enu = v_enu

    def step(self, obs: Any) -> list[Any]:
        return [AircraftCommand("q", VelocityCommand(self.v_enu)),
                AircraftCommand("nobody", VelocityCommand((9.0, 9.0, 0.0))), "not a command"]


def air_scenario(aircraft: list[dict[str, Any]], duration: float) -> Any:
    return validate({"name": "t", "duration": duration, "dt": 0.1,
                     "backends": {"air": {"type": "jsbsim_fleet", "params": {"aircraft": aircraft}}}}, "test")


def test_backend_flies_bus_velocity_commands_and_exports_kinds(tmp_path: Path) -> None:
    sc = air_scenario([{"id": "q", "start_enu": (0, 0, 30)},
                       {"id": "c", "model": "c172x", "start_enu": (0, -800, 300), "yaw_deg": 90, "speed_mps": 50,
                        "role": "piloted"}], 10.0)
    backend = AirBackend("air", AirBackend.Params(**sc.backends["air"].params), sc)
    ctx = RunContext(run_seed=0, dt=0.1, duration=10.0, scenario=sc, workdir=tmp_path)
    sim = Simulation(ctx, [backend, ConstantVelocity((2.0, 0.0, 0.0))])
    metrics = sim.run()
    s = ctx.snapshot
    i = s.index()
    q, c = i["q"], i["c"]
    assert s.kind[q] == Kind.UAV and s.kind[c] == Kind.AIRCRAFT
    # after 10 s of a 2 m/s east command: flying east at 2 m/s, ~18 m covered, altitude held
    assert s.velocity[q, 0] == pytest.approx(2.0, abs=0.2)
    assert abs(s.velocity[q, 1]) < 0.2
    assert s.position[q, 0] == pytest.approx(2.0 * 10.0 - 2.0, abs=2.5)
    assert s.position[q, 2] == pytest.approx(30.0, abs=0.5)
    # the c172 flies north at ~50 m/s
    assert s.velocity[c, 1] == pytest.approx(50.0, abs=2.0)
    assert metrics["air_commands"] == 20  # only the commands addressed to 'q' (every 0.5 s for 10 s)


def test_goal_quad_flies_straight_to_its_goal_without_any_controller(tmp_path: Path) -> None:
    sc = air_scenario([{"id": "q", "start_enu": (0, 0, 30), "goal_enu": (60, 0, 30), "cruise_speed_mps": 6}], 18.0)
    backend = AirBackend("air", AirBackend.Params(**sc.backends["air"].params), sc)
    ctx = RunContext(run_seed=0, dt=0.1, duration=18.0, scenario=sc, workdir=tmp_path)
    Simulation(ctx, [backend]).run()
    p = ctx.snapshot.position[0]
    assert np.linalg.norm(p - [60.0, 0.0, 30.0]) < 2.0


def test_link_counts_and_drops_garbage_and_corrupted_frames(tmp_path: Path) -> None:
    from corridor.run import build
    from corridor.vehicles.geodesy import Origin
    from corridor.vehicles.mavlink.encode import MavlinkEndpoint

    sc = validate({"name": "t", "duration": 2.0, "dt": 0.1, "backends": {
        "air": {"type": "jsbsim_fleet", "params": {"aircraft": [
            {"id": "a", "start_enu": (0, 0, 30), "goal_enu": (50, 0, 30)},
            {"id": "b", "start_enu": (0, 40, 30), "goal_enu": (50, 40, 30)}]}},
        "link": {"type": "mavlink_link", "params": {}}}}, "test")
    sim = build(sc, 0, tmp_path)
    for c in sim.ctx.components.values():
        c.setup(sim.ctx)
    link = sim.ctx.get("link")
    frame = bytearray(MavlinkEndpoint(77, Origin(48.137, 11.575, 0.0)).heartbeat())
    frame[12] ^= 0xFF  # corrupt the payload: the CRC must reject it
    for _ in range(10):
        sim.step()
    link.inject(sim.ctx.t, "b", b"\x00\x01not mavlink at all", dst="a")
    link.inject(sim.ctx.t, "b", bytes(frame), dst="a")
    for _ in range(10):
        sim.step()
    m = link.finish(sim.ctx)
    link.close()
    assert m["mavlink_bad_data"] >= 1 and m["mavlink_bad_crc"] == 1
    # the picture still works after the garbage: b is tracked by a where it really is
    s = sim.ctx.snapshot
    pic = {o.id: o for o in link.picture("a", sim.ctx.t)}
    assert np.linalg.norm(pic["b"].pos - s.position[s.index()["b"]]) < 1.0
