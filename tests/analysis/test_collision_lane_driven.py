"""A speed-commanded SUMO vehicle is judged by SUMO's collision check, like every SUMO driver (issue 27).

The merging sweep's one collision (cell ``p10_r800_L50``, seed 1, 188.6 s) was an oriented-box overlap
that SUMO did not report.  The commanded ramp car ``ramp_car.2.4`` queued behind its ramp leader at
the start of the 50 m acceleration lane, and SUMO's own lane-change model moved it, at standstill,
from the acceleration lane to the left mainline lane in 0.5 s while its rear still lay on the
junction's ramp lane.  SUMO then draws it from its front on the left lane to that rear (angle 34.2 deg,
56 deg to the road) and keeps drawing it so while it stands; its dynamics and its collision check
(junctions checked, mingap factor 0) keep it on the left lane at lateral offset 0.  The human
``main_car.2.10`` passed on the right lane through the drawn rear.  The box check saw it only because
the car's speed was commanded (role ``CONTROLLED``); a human in the same pose is never box-checked.
The poses below are libsumo's at 188.6 s.
"""

from __future__ import annotations

import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from types import SimpleNamespace

import numpy as np

from corridor.analysis.monitoring.collisions import CollisionMonitor
from corridor.engine import Backend, RunContext, Simulation
from corridor.snapshot import Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot

DT = 0.1  # [s]
LENGTH_M, WIDTH_M = 4.8, 1.8  # [m] both cars (human_merge cars of the merging sweep)
RAMP_FRONT, RAMP_ANGLE_DEG = (1504.0210044267997, -1.75), 34.17486907840935  # libsumo: front bumper, getAngle
MAIN_FRONT, MAIN_ANGLE_DEG = (1501.4043775182333, -5.25), 90.0


def centre(front: tuple[float, float], angle_deg: float) -> tuple[list[float], float]:
    yaw = math.radians(90.0 - angle_deg)
    return [front[0] - 0.5 * LENGTH_M * math.cos(yaw), front[1] - 0.5 * LENGTH_M * math.sin(yaw), 0.0], yaw


class SumoLike(Backend):
    """A SUMO road part of two road rows with the recorded poses; ``posed``: the backend's list of
    controlled rows it does not move itself; ``report``: SUMO's collision report of the pair."""

    def __init__(self, posed: frozenset[str] | None, report: bool = False) -> None:
        super().__init__("sumo")
        self.period = DT
        (rp, ryaw), (mp, myaw) = centre(RAMP_FRONT, RAMP_ANGLE_DEG), centre(MAIN_FRONT, MAIN_ANGLE_DEG)
        self.pos, self.yaw = np.array([rp, mp]), np.array([ryaw, myaw])
        self.posed, self.report = posed, report
        self.t = 0.0

    def tick(self, ctx: RunContext) -> None:
        self.t = ctx.t

    def snapshot_part(self) -> WorldSnapshot:
        events = RoadEvents(collisions=((self.t, "main_car.2.10", "ramp_car.2.4", "collision"),) if self.report else ())
        road = RoadFrame(source="sumo", tables=RoadTables(), uid=np.arange(2), lane=np.zeros(2, dtype=np.int64),
                         lane_pos=np.array([2.4, 3.0]), events=events, posed=self.posed)
        return WorldSnapshot(ids=np.array(["ramp_car.2.4", "main_car.2.10"], dtype=object),
                             kind=np.full(2, Kind.CAR, dtype=np.int8),
                             role=np.array([Role.CONTROLLED, Role.MAINLINE], dtype=np.int8), position=self.pos.copy(),
                             velocity=np.zeros((2, 3)), heading=self.yaw.copy(),
                             size=np.tile((LENGTH_M, WIDTH_M, 1.5), (2, 1)), road=road)


def run(backend: SumoLike) -> tuple[dict, RunContext]:
    mon = CollisionMonitor("collisions", CollisionMonitor.Params(), SimpleNamespace(dt=DT))
    ctx = RunContext(run_seed=0, dt=DT, duration=3 * DT)
    return Simulation(ctx, [backend, mon]).run(), ctx


def test_drawn_pose_of_speed_commanded_car_is_not_a_collision() -> None:
    m, ctx = run(SumoLike(posed=frozenset()))
    assert m["collisions"] == 0  # was 1: the box drawn from SUMO's angle crosses the right lane


def test_the_drawn_boxes_do_overlap() -> None:
    """The same poses, the car posed from outside SUMO (moveToXY): its box is checked and overlaps."""
    m, _ = run(SumoLike(posed=frozenset({"ramp_car.2.4"})))
    assert m["collisions"] == 1
    m, _ = run(SumoLike(posed=None))  # a road backend that does not say: every controlled row is posed
    assert m["collisions"] == 1


def test_sumo_report_of_speed_commanded_car_counts() -> None:
    m, ctx = run(SumoLike(posed=frozenset(), report=True))
    assert m["collisions"] == 1
    assert [e.kind for e in ctx.events.events] == ["collision"]
    assert "sumo (collision)" in ctx.events.events[0].message


def _sweep_cell_row(seed: int) -> dict:
    from pathlib import Path

    from corridor.batch import expand
    from corridor.run import execute
    from corridor.scenario.loader import load

    path = str(Path(__file__).resolve().parents[2] / "scenarios" / "sweeps" / "merging_sweep.yaml")
    sc, raw = load(path)
    return execute(expand(sc, raw, path, 1, seed, None, ["p10_r800_L50"])[0])


def test_merging_sweep_cell_has_no_collision() -> None:
    """The run itself (real SUMO, 420 s): the commanded car changes lanes at standstill and stays
    drawn across the right lane; SUMO reports no collision, and now neither does corridor."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        row = pool.submit(_sweep_cell_row, 1).result()
    assert row["status"] == "ok", row["error"]
    assert row["v2x_fallbacks"] >= 1 and row["v2x_commands"] > 0  # the commanded run of the report
    assert row["collisions"] == 0  # was 1 (main_car.2.10 x ramp_car.2.4, box overlap at 188.6 s)


class SameArrays(SumoLike):
    """SUMO's part publishing the same read-only role and kind arrays every tick (a road backend's
    rows and controlled vehicles unchanged); the car is posed from ``posed_from`` [s] on."""

    def __init__(self, posed_from: float) -> None:
        super().__init__(posed=frozenset())
        self.posed_from = posed_from
        self.kind = np.full(2, Kind.CAR, dtype=np.int8)
        self.role = np.array([Role.CONTROLLED, Role.MAINLINE], dtype=np.int8)
        self.kind.flags.writeable = self.role.flags.writeable = False

    def snapshot_part(self) -> WorldSnapshot:
        self.posed = frozenset({"ramp_car.2.4"}) if self.t >= self.posed_from - 1e-9 else frozenset()
        part = super().snapshot_part()
        part.kind, part.role = self.kind, self.role
        return part


def test_the_kept_role_and_kind_codes_do_not_skip_a_posed_row() -> None:
    """The monitor keeps what it found of the last arrays with a controlled row (no reduction again on
    the same arrays): the row's being posed is still read every tick."""
    m, _ = run(SameArrays(posed_from=2 * DT))
    assert m["collisions"] == 1 and m["first_collision_s"] > 1.5 * DT  # not before the car is posed
    m, _ = run(SameArrays(posed_from=10.0))
    assert m["collisions"] == 0
