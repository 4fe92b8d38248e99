"""The road monitors and the V2X merging coordinator run on a scripted road frame, without SUMO.

``ScriptedRoad`` is a road backend that fills the snapshot's road frame from a script: vehicles at
constant speed along a straight mainline (lane ``upstream_0``) and a ramp (lane ``ramp_0``) towards
the merge, departing and arriving at scripted times, plus a scripted insertion backlog.  Everything
the consumers read comes through ``ctx.snapshot`` (rows, road frame, tables, events, landmarks).
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from corridor.engine import Backend, RunContext, Simulation
from corridor.snapshot import Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot
from corridor.traffic.networks.landmarks import OnrampLandmarks

DT = 0.1  # [s]
LENGTH = 5.0  # [m]
MAIN, RAMP = "upstream_0", "ramp_0"
LANDMARKS = OnrampLandmarks(
    upstream_edge="upstream", merge_edge="merge", downstream_edge="downstream", ramp_edge="ramp",
    accel_lane="merge_0", join_lanes=("upstream_0", "merge_1"), merge_junction="n_merge", mainline_lanes=2,
    lane_width_m=3.5, ramp_angle_deg=5.0, merge_start_x=1000.0, merge_end_x=1200.0, past_merge_x=1200.0,
    mainline_end_x=2000.0, accel_lane_length_m=200.0)


@dataclass
class Scripted:
    """A vehicle of the script: departs at ``depart_s`` at lane position ``pos0_m`` and drives at
    ``speed_mps`` until its route (``route_m`` long) ends."""

    vid: str
    lane: str
    pos0_m: float
    speed_mps: float
    depart_s: float = 0.0
    route_m: float = 1e9
    connected: bool = False
    depart_delay_s: float = 0.0


class ScriptedRoad(Backend):
    """Fills a road frame from a script (front-bumper lane positions; x = lane position)."""

    provides = frozenset({"road"})  # the monitors' road peer (their period: this one's)

    def __init__(self, script: list[Scripted], pending_wait_s: tuple[float, ...] = ()) -> None:
        super().__init__("road")
        self.period = DT
        self.script = script
        self.pending_wait_s = pending_wait_s
        self.tables = RoadTables(LANDMARKS)
        self.tables.add_route("main", ((1000.0, 25.0),))
        self.tables.add_route("ramp", ((300.0, 20.0), (700.0, 25.0)))
        for lane, limit in ((MAIN, 25.0), (RAMP, 20.0)):
            self.tables.add_lane(lane, limit)
        self.t = 0.0
        self.on_road: dict[str, float] = {}  # vid -> lane position [m]
        self.done: set[str] = set()
        self.commands: list[Any] = []
        self._part = WorldSnapshot(road=RoadFrame(self.name, self.tables))

    def static_part(self) -> WorldSnapshot:
        return self._part

    def snapshot_part(self) -> WorldSnapshot:
        return self._part

    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        self.commands += commands

    def tick(self, ctx: RunContext) -> None:
        self.t += DT
        tb, departed, arrived = self.tables, [], []
        for s in self.script:
            if s.vid in self.on_road:
                self.on_road[s.vid] += s.speed_mps * DT
                if self.on_road[s.vid] - s.pos0_m >= s.route_m - 1e-9:
                    del self.on_road[s.vid]
                    self.done.add(s.vid)
                    arrived.append(tb.uid_of[s.vid])
            elif s.vid not in self.done and self.t >= s.depart_s - 1e-9:
                self.on_road[s.vid] = s.pos0_m
                ramp = s.lane == RAMP
                departed.append(tb.add_vehicle(
                    s.vid, length=LENGTH, width=1.8, route=tb.route_code_of["ramp" if ramp else "main"],
                    role=Role.RAMP if ramp else Role.MAINLINE, connected=s.connected, speed_factor=1.0,
                    max_speed=50.0, depart_s=self.t, depart_delay_s=s.depart_delay_s))
        n_pending = len(self.pending_wait_s)
        events = RoadEvents(departed=np.array(departed, dtype=np.int64), arrived=np.array(arrived, dtype=np.int64),
                            pending_ids=tuple(f"p{k}" for k in range(n_pending)),
                            pending_wait_s=np.array(self.pending_wait_s, dtype=float),
                            pending_route=np.zeros(n_pending, dtype=np.int64),
                            pending_role=np.full(n_pending, Role.MAINLINE, dtype=np.int8))
        self._part = self._frame(events)

    def _frame(self, events: RoadEvents) -> WorldSnapshot:
        by_id = {s.vid: s for s in self.script}
        ids = list(self.on_road)
        n, tb = len(ids), self.tables
        lane_pos = np.array([self.on_road[v] for v in ids])
        speed = np.array([by_id[v].speed_mps for v in ids])
        lane = np.array([tb.lane_code_of[by_id[v].lane] for v in ids], dtype=np.int64)
        y = np.where(lane == tb.lane_code_of[RAMP], -9.0, -1.75)
        pos = np.column_stack([lane_pos - 0.5 * LENGTH, y, np.zeros(n)])
        vel = np.column_stack([speed, np.zeros(n), np.zeros(n)])
        uid = np.array([tb.uid_of[v] for v in ids], dtype=np.int64)
        road = RoadFrame(self.name, tb, t=self.t, uid=uid, lane=lane, lane_pos=lane_pos, accel=np.zeros(n),
                         distance=lane_pos - np.array([by_id[v].pos0_m for v in ids]), events=events)
        return WorldSnapshot(ids=np.array(ids, dtype=object), kind=np.full(n, Kind.CAR, dtype=np.int8),
                             role=tb.role[uid].copy(), position=pos, velocity=vel, heading=np.zeros(n),
                             size=np.tile([LENGTH, 1.8, 1.5], (n, 1)), road=road)


class Aircraft(Backend):
    """One entity of another backend, listed BEFORE the road: the road rows start at offset 1."""

    def snapshot_part(self) -> WorldSnapshot:
        return WorldSnapshot(ids=np.array(["uav"], dtype=object), kind=np.array([Kind.UAV], dtype=np.int8),
                             role=np.array([Role.OTHER], dtype=np.int8), position=np.array([[0.0, 0.0, 100.0]]),
                             velocity=np.zeros((1, 3)), heading=np.zeros(1), size=np.array([[0.5, 0.5, 0.2]]))


def scenario(duration_s: float) -> Any:
    return SimpleNamespace(dt=DT, duration=duration_s, warmup=0.0, channels={},
                           road=SimpleNamespace(sumo=SimpleNamespace(step_length=DT)))


def run(road: ScriptedRoad, components: list[Any], duration_s: float, with_uav: bool = True) -> Simulation:
    sc = scenario(duration_s)
    ctx = RunContext(run_seed=1, dt=DT, duration=duration_s, scenario=sc)
    backends = [Aircraft("air"), road] if with_uav else [road]
    sim = Simulation(ctx, [*backends, *components])
    sim.metrics = sim.run()
    return sim


def surrogate_safety_on_a_scripted_follower() -> None:
    from corridor.analysis.monitoring.road import SurrogateSafety

    # follower front at 100 m doing 20 m/s, leader (5 m long) front at 130 m doing 10 m/s
    road = ScriptedRoad([Scripted("lead", MAIN, 130.0, 10.0), Scripted("follow", MAIN, 100.0, 20.0)])
    mon = SurrogateSafety("safety", SurrogateSafety.Params(), scenario(1.0))
    sim = run(road, [mon], 1.0)
    assert sim.ctx.snapshot.road.offset == 1  # the UAV's row comes first
    # gap 25 m closing at 10 m/s; both appear after the first step (t = 0.1 s) and close 1 m per
    # tick from then on, so the smallest TTC is the last one: (25 - 9 x 1 m) / 10 m/s
    assert sim.metrics["min_ttc_s"] == pytest.approx((25.0 - 9 * 1.0) / 10.0)
    assert sim.metrics["max_drac_mps2"] == pytest.approx(10.0**2 / (2 * 16.0))


def trips_closed_form_delay() -> None:
    from corridor.traffic.sumo.trips import Trips

    # free-flow time of route main: 1000 m at min(50, 25 x 1.0) m/s = 40 s; it drives 1000 m at
    # 20 m/s (50 s) after waiting 2 s to be inserted: delay 50 + 2 - 40 = 12 s.  One vehicle is
    # still waiting for insertion at the end (3 s so far): it counts as unfinished with 3 s.
    road = ScriptedRoad([Scripted("car", MAIN, 0.0, 20.0, depart_s=0.1, route_m=1000.0, depart_delay_s=2.0)],
                        pending_wait_s=(3.0,))
    trips = Trips("trips", Trips.Params(), scenario(60.0))
    sim = run(road, [trips], 60.0)
    assert trips.delays(0.0)["mainline"] == pytest.approx([12.0])
    assert sorted(trips.delays(0.0, unfinished=True)["mainline"]) == pytest.approx([3.0, 12.0])
    assert trips.backlog() == 1
    assert sim.metrics["vehicles_departed"] == 1 and sim.metrics["vehicles_arrived"] == 1
    assert sim.metrics["vehicles_measured"] == 1 and sim.metrics["teleports"] == 0


def v2x_commands_the_connected_ramp_vehicle() -> None:
    from corridor.controllers.merging.components import V2XMerging
    from corridor.traffic.sumo.commands import SetSpeed

    script = [Scripted("m0", MAIN, 850.0, 22.0), Scripted("m1", MAIN, 810.0, 22.0),
              Scripted("r0", RAMP, 830.0, 15.0, connected=True), Scripted("r1", RAMP, 790.0, 15.0)]
    road = ScriptedRoad(script)
    ctl = V2XMerging("merge", V2XMerging.Params(), scenario(3.0))
    run(road, [ctl], 3.0)
    speeds = [c for c in road.commands if isinstance(c, SetSpeed)]
    assert speeds and {c.vid for c in speeds} == {"r0"}  # only the connected ramp vehicle is commanded
    assert ctl.commands_sent == len(speeds)
    assert ctl.x_merge == pytest.approx(1000.0 + 0.1 * 200.0)  # from the typed landmarks


def test_surrogate_safety_finds_the_ttc_of_a_scripted_follower() -> None:
    surrogate_safety_on_a_scripted_follower()


def test_trips_monitor_computes_the_closed_form_delay() -> None:
    trips_closed_form_delay()


def test_v2x_coordinator_commands_the_scripted_connected_ramp_vehicle() -> None:
    v2x_commands_the_connected_ramp_vehicle()


def test_road_consumers_run_without_libsumo() -> None:
    """All three in a fresh interpreter: libsumo is never imported."""
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import test_traffic_road_frame as t; "
            "t.surrogate_safety_on_a_scripted_follower(); t.trips_closed_form_delay(); "
            "t.v2x_commands_the_connected_ramp_vehicle(); "
            "assert 'libsumo' not in sys.modules, 'libsumo was imported'; print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("ok")


def test_no_closing_pair_is_a_missing_ttc_not_99() -> None:
    """The follower is slower than its leader: no closing pair, so min_ttc_s is NaN (not the old
    sentinel 99, which entered means) and the signal is +inf (TTC infinite) at every tick."""
    from corridor.analysis.monitoring.road import SurrogateSafety

    road = ScriptedRoad([Scripted("lead", MAIN, 130.0, 20.0), Scripted("follow", MAIN, 100.0, 10.0)])
    mon = SurrogateSafety("safety", SurrogateSafety.Params(), scenario(1.0))
    sim = run(road, [mon], 1.0)
    assert math.isnan(sim.metrics["min_ttc_s"])
    t, v = sim.ctx.signals.get("min_ttc")
    assert len(v) and np.all(np.isposinf(v))
