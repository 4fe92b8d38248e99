"""SUMO's collision report for an ego placed with ``moveToXY`` is lane-projected (issue 14).

``scenarios/parking.yaml`` (batch of 75 runs) had 5 runs with a SUMO collision "through car x ego"
while the ego reversed into its bay and corridor's box check kept the ego >= 0.20 m from every car.
The poses below are read back from libsumo at SUMO's report in run ``parallel-s23`` (t = 54.3 s):
the follower ``eastbound.0.4`` stands on ``east_0`` (front bumper x = 61.78 m, y = -5.15 m), the ego
reverses at 15 deg to the lane (front bumper x = 66.25 m, y = -6.70 m).  SUMO checks them as
lane-aligned boxes (ego: lane position 66.25 m minus its 4.5 m length = 61.75 m < 61.78 m; lateral
offset of the front bumper -1.45 m +- 0.9 m overlaps the follower's 0.10 +- 0.9 m), while the
real boxes are 0.9 m apart (the ego's rear stands in the bay).  The collision monitor now decides any
pair with a ``CONTROLLED`` row by its oriented-box check and only logs SUMO's report; a real overlap
still counts, and SUMO's reports between its own vehicles still count.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from corridor.analysis.monitoring.collisions import CollisionMonitor
from corridor.engine import Backend, RunContext, Simulation
from corridor.snapshot import Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot

DT = 0.1  # [s]
LENGTH_M, WIDTH_M = 4.5, 1.8  # [m] ego and follower (SUMO boxes of parking.yaml)
EGO_FRONT = (66.25102558833574, -6.6982731486895215)  # [m] libsumo getPosition (front bumper)
EGO_SUMO_ANGLE_DEG = 75.19688028744618  # libsumo getAngle (navigational)
FOLLOWER_FRONT = (61.779148896079775, -5.15)  # [m]
FOLLOWER_SUMO_ANGLE_DEG = 89.99305141080838


def centre(front: tuple[float, float], angle_deg: float) -> tuple[list[float], float]:
    yaw = math.radians(90.0 - angle_deg)
    return [front[0] - 0.5 * LENGTH_M * math.cos(yaw), front[1] - 0.5 * LENGTH_M * math.sin(yaw), 0.0], yaw


class SumoLike(Backend):
    """A road backend's part: two cars and SUMO's collision report, the same every tick."""

    def __init__(self, ego_role: int, ego_shift_m: tuple[float, float] = (0.0, 0.0)) -> None:
        super().__init__("sumo")
        self.period = DT
        (ep, eyaw), (fp, fyaw) = centre(EGO_FRONT, EGO_SUMO_ANGLE_DEG), centre(FOLLOWER_FRONT, FOLLOWER_SUMO_ANGLE_DEG)
        ep[0] += ego_shift_m[0]
        ep[1] += ego_shift_m[1]
        self.pos, self.yaw, self.role = np.array([ep, fp]), np.array([eyaw, fyaw]), ego_role
        self.t = 0.0

    def tick(self, ctx: RunContext) -> None:
        self.t = ctx.t

    def snapshot_part(self) -> WorldSnapshot:
        report = ((self.t, "eastbound.0.4", "ego", "collision"),)
        return WorldSnapshot(ids=np.array(["ego", "eastbound.0.4"], dtype=object),
                             kind=np.full(2, Kind.CAR, dtype=np.int8),
                             role=np.array([self.role, Role.OTHER], dtype=np.int8), position=self.pos.copy(),
                             velocity=np.zeros((2, 3)), heading=self.yaw.copy(),
                             size=np.tile((LENGTH_M, WIDTH_M, 1.5), (2, 1)),
                             road=RoadFrame(source="sumo", tables=RoadTables(), events=RoadEvents(collisions=report)))


def run(backend: SumoLike) -> tuple[dict, RunContext]:
    mon = CollisionMonitor("collisions", CollisionMonitor.Params(), SimpleNamespace(dt=DT))
    ctx = RunContext(run_seed=0, dt=DT, duration=3 * DT)
    return Simulation(ctx, [backend, mon]).run(), ctx


def test_lane_projected_report_of_controlled_ego_not_counted() -> None:
    m, ctx = run(SumoLike(Role.CONTROLLED))
    assert m["collisions"] == 0  # the real boxes are apart (was 1: SUMO's report counted)
    kinds = [e.kind for e in ctx.events.events]
    assert "road_collision_report" in kinds and "collision" not in kinds


def test_real_overlap_of_controlled_ego_still_counted() -> None:
    m, _ = run(SumoLike(Role.CONTROLLED, ego_shift_m=(-0.5, 1.2)))  # 1.2 m nearer the lane: boxes overlap
    assert m["collisions"] == 1


def test_report_between_sumo_vehicles_still_counted() -> None:
    m, _ = run(SumoLike(Role.OTHER))  # no controlled row: SUMO's own report is the collision
    assert m["collisions"] == 1


def _sumo_report_at_diagonal_pose(cache: str) -> tuple[list[tuple[str, str]], float]:
    """Real SUMO (parking street of parking.yaml, sublane model): a follower stands on ``east_0`` and the
    ego is put at the diagnosed diagonal pose with ``moveToXY``; SUMO's collision report and the real
    boxes' overlap depth along the separating direction (negative: apart)."""
    from pathlib import Path

    import libsumo

    from corridor.traffic.networks.registry import build_network

    net = build_network("parking_street", {"occupancy": 0.0}, Path(cache))
    libsumo.start(["sumo", "-n", str(net.net_file), "--no-step-log", "--no-warnings", "--step-length", "0.1",
                   "--collision.action", "warn", "--collision.mingap-factor", "0", "--lateral-resolution", "0.8"])
    try:
        libsumo.route.add("r", ["east"])
        libsumo.vehicle.add("f", "r", depart="0", departLane="0", departPos=f"{FOLLOWER_FRONT[0]:g}", departSpeed="0")
        libsumo.vehicle.add("ego", "r", depart="0", departLane="0", departPos="90", departSpeed="0")
        for vid in ("f", "ego"):
            libsumo.vehicle.setLength(vid, LENGTH_M)
            libsumo.vehicle.setWidth(vid, WIDTH_M)
        libsumo.vehicle.setSpeedMode("ego", 0)
        libsumo.simulationStep()
        libsumo.vehicle.setSpeed("f", 0.0)
        reports: list[tuple[str, str]] = []
        for _ in range(3):
            libsumo.vehicle.moveToXY("ego", "", -1, EGO_FRONT[0], EGO_FRONT[1], EGO_SUMO_ANGLE_DEG, 2)
            libsumo.simulationStep()
            reports += [(c.collider, c.victim) for c in libsumo.simulation.getCollisions()]
        poses = [(libsumo.vehicle.getPosition(v), libsumo.vehicle.getAngle(v)) for v in ("ego", "f")]
    finally:
        libsumo.close()
    from shapely.geometry import Polygon

    from corridor.analysis.safety import box_corners

    boxes = []
    for front, angle in poses:
        c, yaw = centre(front, angle)
        corners = box_corners(np.array([c[:2]]), np.array([yaw]), np.array([LENGTH_M]), np.array([WIDTH_M]))[0]
        boxes.append(Polygon(corners))
    return reports, float(boxes[0].distance(boxes[1]))


def test_sumo_reports_a_collision_the_real_boxes_do_not_have(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        reports, gap_m = pool.submit(_sumo_report_at_diagonal_pose, str(tmp_path)).result()
    assert ("f", "ego") in reports  # SUMO: the follower ran into the lane-aligned box of the ego
    assert gap_m > 0.5  # the real boxes are 0.77 m apart (0.9 m in the run: follower 0.1 m off its lane centre)
