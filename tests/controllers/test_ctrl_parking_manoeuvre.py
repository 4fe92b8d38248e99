"""The parking manoeuvre automaton and its path following: the mode sequence of a plan with a cusp,
the goal pose reached on highway-env's kinematics, abort and re-plan when a new obstacle blocks the
path, and giving up after ``max_replans`` failed plans.  References are closed-form bicycle arcs
(no planner: the automaton takes any ``plan_fn``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from corridor.controllers.parking.clearance import box_polygons
from corridor.controllers.parking.manoeuvre import (
    Footprint,
    ManoeuvreParams,
    ParkingManoeuvre,
    ParkingObservation,
)
from corridor.controllers.parking.tracking import TrackingParams, split_segments
from corridor.engine import RunContext
from corridor.events import EventLog
from corridor.vehicles.ground.highway_env_parking import EGO_ID, HighwayEnvParking, ParkingInput


@dataclass(frozen=True)
class Ref:
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta: np.ndarray
    v: np.ndarray
    a: np.ndarray
    steer: np.ndarray


def arcs(start: np.ndarray, pieces: list[tuple[float, float, float]], wheelbase_m: float, dt: float = 0.1) -> Ref:
    """Exact rear-axle bicycle motion through (speed [m/s], steer [rad], duration [s]) pieces."""
    x, y, th = (float(v) for v in start)
    out = [(x, y, th, 0.0, 0.0)]
    for v, steer, dur in pieces:
        k = math.tan(steer) / wheelbase_m
        for _ in range(round(dur / dt)):
            ds = v * dt
            if abs(k) < 1e-12:
                x, y = x + ds * math.cos(th), y + ds * math.sin(th)
            else:
                x += (math.sin(th + k * ds) - math.sin(th)) / k
                y -= (math.cos(th + k * ds) - math.cos(th)) / k
                th += k * ds
            out.append((x, y, th, v, steer))
    a = np.array(out)
    n = len(a)
    return Ref(np.arange(n) * dt, a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.zeros(n), a[:, 4])


PIECES = [(1.5, 0.4, 4.0), (-1.0, -0.3, 3.0), (1.0, 0.0, 4.0)]


def test_split_segments_at_cusps() -> None:
    ref = arcs(np.zeros(3), PIECES, 5.0)
    segs = split_segments(ref.x, ref.y, ref.theta, ref.v, ref.steer, 5.0)
    assert [s.direction for s in segs] == [1, -1, 1]
    assert [s.length_m for s in segs] == pytest.approx([6.0, 3.0, 4.0], abs=1e-4)  # chords of 0.15 m arcs
    assert segs[0].kappa[1] == pytest.approx(math.tan(0.4) / 5.0)


def lot_run(seed: int = 5) -> tuple[ParkingManoeuvre, Ref, np.ndarray]:
    """Drive a reference on highway-env's kinematics (empty lot) through the automaton."""
    ctx = RunContext(run_seed=seed, dt=0.1, duration=60.0)
    b = HighwayEnvParking("lot", HighwayEnvParking.Params(vehicles_count=0), None)
    b.setup(ctx)
    lot = b.lot
    fp = Footprint(lot.vehicle_length_m, lot.vehicle_width_m, lot.rear_offset_m)
    refs: list[Ref] = []

    def plan_fn(start: np.ndarray, goal: np.ndarray, obstacles: list[np.ndarray]) -> Ref:
        refs.append(arcs(start, PIECES, lot.wheelbase_m))
        return refs[-1]

    tp = TrackingParams(wheelbase_m=lot.wheelbase_m, max_steer_rad=lot.max_steer_rad)
    man = ParkingManoeuvre(ManoeuvreParams(tracking=tp), fp, plan_fn, EventLog())
    pose = np.zeros(3)
    for _ in range(500):
        s = b.snapshot_part()
        h = float(s.heading[0])
        d = np.array([math.cos(h), math.sin(h)])
        pose = np.array([*(s.position[0, :2] - lot.rear_offset_m * d), h])
        obs = ParkingObservation(ctx.t, pose, float(s.velocity[0, :2] @ d), np.zeros(3), None, (), np.zeros((0, 4, 2)))
        accel, steer = man.step(obs)
        if man.mode == "parked":
            break
        b.apply([ParkingInput(EGO_ID, accel, steer)], ctx)
        b.tick(ctx)
        ctx.t += b.period
    b.close()
    return man, refs[0], pose


def test_modes_follow_the_plan_and_reach_its_end_pose() -> None:
    man, ref, pose = lot_run()
    # the last segment (4 m) is "position" until its final straighten_m = 3 m
    assert [h[2] for h in man.ha.history] == ["slot_found", "position", "reverse_in", "position", "straighten",
                                              "parked"]
    assert [h[3] for h in man.ha.history][2:] == ["cusp", "cusp", "last segment", "at the goal"]
    assert math.hypot(pose[0] - ref.x[-1], pose[1] - ref.y[-1]) < 0.1
    assert abs(pose[2] - ref.theta[-1]) < 0.02
    assert len(man.events.of_kind("mode")) == 6


def test_same_inputs_same_transitions() -> None:
    a, _, pa = lot_run(5)
    b, _, pb = lot_run(5)
    assert a.ha.history == b.ha.history and np.array_equal(pa, pb)


class PointCar:
    """The rear-axle bicycle integrated exactly (a simulator for the automaton alone)."""

    def __init__(self, L: float) -> None:
        self.L, self.pose, self.v = L, np.zeros(3), 0.0

    def step(self, accel: float, steer: float, dt: float) -> None:
        self.v += accel * dt
        x, y, th = self.pose
        self.pose = np.array([x + self.v * math.cos(th) * dt, y + self.v * math.sin(th) * dt,
                              th + self.v * math.tan(steer) / self.L * dt])


def run_point(plan_fn, obstacle_at_s: float | None, max_replans: int = 3, t_end_s: float = 60.0):
    L = 2.8
    car = PointCar(L)
    fp = Footprint(4.0, 1.8, 1.4)
    man = ParkingManoeuvre(ManoeuvreParams(tracking=TrackingParams(wheelbase_m=L), max_replans=max_replans),
                           fp, plan_fn, EventLog())
    block = box_polygons(np.array([[8.0, 0.0]]), np.zeros(1), np.array([0.6]), np.array([0.6]))
    t = 0.0
    while t < t_end_s and man.mode != "parked":
        there = obstacle_at_s is not None and t >= obstacle_at_s
        obs = ParkingObservation(t, car.pose.copy(), car.v, np.array([12.0, 3.0, 0.0]), None,
                                 ("ped",) if there else (), block if there else np.zeros((0, 4, 2)))
        car.step(*man.step(obs), 0.1)
        t += 0.1
    return man, car


def test_new_obstacle_on_the_path_aborts_and_replans_around_it() -> None:
    calls: list[int] = []

    def plan_fn(start, goal, obstacles):
        calls.append(len(obstacles))
        if not obstacles:  # straight along y = 0, through x = 8 where the pedestrian will appear
            return arcs(start, [(1.5, 0.0, 8.0)], 2.8)
        # around it: a left-right S that ends 3 m to the left, heading east
        return arcs(start, [(1.0, 0.5, 4.0), (1.0, -0.5, 4.0), (1.0, 0.0, 3.0)], 2.8)

    man, car = run_point(plan_fn, obstacle_at_s=1.0)
    dst = [h[2] for h in man.ha.history]
    assert dst[:3] == ["slot_found", "position", "abort"] and "replan" in dst and dst[-1] == "parked"
    assert man.reasons == ["path blocked"] and calls == [0, 1] and man.replans == 1
    assert car.pose[0] < 8.0 - 0.3 - 2.6 or abs(car.pose[1]) > 0.3 + 0.9  # never drove into it


def test_failed_plans_abort_and_stop_after_max_replans() -> None:
    def plan_fn(start, goal, obstacles):
        raise RuntimeError("no solution within 1 s")

    man, car = run_point(plan_fn, obstacle_at_s=None, max_replans=2, t_end_s=10.0)
    dst = [h[2] for h in man.ha.history]
    assert dst == ["slot_found", "abort", "replan", "abort", "replan", "abort"]
    assert man.mode == "abort" and man.plan_failures == 3 and man.replans == 2 and abs(car.v) < 1e-9
    assert len(man.events.of_kind("plan")) == 3


def test_a_shuffle_between_two_forward_runs_is_no_cusp() -> None:
    """An optimiser's 1 cm back-and-forth while it turns the wheels standing is not a manoeuvre: the
    forward runs around it are one segment."""
    ref = arcs(np.zeros(3), [(1.0, 0.0, 3.0), (-0.1, 0.0, 0.1), (1.0, 0.2, 3.0), (-1.0, 0.0, 2.0)], 2.8)
    segs = split_segments(ref.x, ref.y, ref.theta, ref.v, ref.steer, 2.8)
    assert [s.direction for s in segs] == [1, -1]
    assert segs[0].length_m == pytest.approx(3.0 + 0.01 + 3.0, abs=1e-3) and segs[1].length_m == pytest.approx(2.0, abs=1e-3)
