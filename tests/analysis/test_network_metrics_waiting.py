"""Flow's average speed, and the same with the vehicles waiting to enter counted at 0 m/s (issue 27).

Flow's figure (``avg_speed_mps``) is the mean speed of the vehicles *in* the network: a controller
that moves a queue from inside the network to its entrance (SUMO's insertion backlog) raises it
without moving anyone faster.  ``avg_speed_all_mps`` counts the waiting vehicles at 0 m/s.  Closed
forms on a road part whose speeds and backlog are set per step.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import ClassVar

import numpy as np
import pytest

from corridor.analysis.monitoring.network_metrics import NetworkMetrics
from corridor.engine import Backend, RunContext, Simulation
from corridor.snapshot import Kind, RoadEvents, RoadFrame, RoadTables, Role, WorldSnapshot

DT = 0.5  # [s]


class Scripted(Backend):
    """A road part whose step ``i`` holds vehicles at ``speeds[i]`` [m/s] and ``waiting[i]`` vehicles
    waiting to be inserted."""

    provides: ClassVar[frozenset[str]] = frozenset({"road"})

    def __init__(self, speeds: list[list[float]], waiting: list[int]) -> None:
        super().__init__("sumo")
        self.period = DT
        self.speeds, self.waiting = speeds, waiting
        self.i = -1

    def tick(self, ctx: RunContext) -> None:
        self.i += 1

    def static_part(self) -> WorldSnapshot:
        return WorldSnapshot(road=RoadFrame(source="sumo", tables=RoadTables()))

    def snapshot_part(self) -> WorldSnapshot:
        i = max(self.i, 0)
        v = np.asarray(self.speeds[i], dtype=float)
        n = len(v)
        pending = tuple(f"wait.{j}" for j in range(self.waiting[i]))
        road = RoadFrame(source="sumo", tables=RoadTables(), uid=np.arange(n), lane=np.zeros(n, dtype=np.int64),
                         lane_pos=np.zeros(n), events=RoadEvents(pending_ids=pending))
        vel = np.zeros((n, 3))
        vel[:, 0] = v
        return WorldSnapshot(ids=np.array([f"car.{j}" for j in range(n)], dtype=object),
                             kind=np.full(n, Kind.CAR, dtype=np.int8), role=np.full(n, Role.MAINLINE, dtype=np.int8),
                             position=np.zeros((n, 3)), velocity=vel, heading=np.zeros(n),
                             size=np.tile((4.5, 1.8, 1.5), (n, 1)), road=road)


def run(speeds: list[list[float]], waiting: list[int]) -> dict:
    mon = NetworkMetrics("network", NetworkMetrics.Params(), SimpleNamespace(warmup=0.0))
    ctx = RunContext(run_seed=0, dt=DT, duration=len(speeds) * DT)
    return Simulation(ctx, [Scripted(speeds, waiting), mon]).run()


def test_no_backlog_both_figures_equal() -> None:
    m = run([[10.0, 20.0]] * 4, [0] * 4)
    assert m["avg_speed_mps"] == pytest.approx(15.0)
    assert m["avg_speed_all_mps"] == pytest.approx(15.0)


def test_waiting_vehicles_count_at_standstill() -> None:
    # steps: 2 moving + 0 waiting (15), 2 moving + 2 waiting (30 / 4), nobody in but 3 waiting (0)
    speeds = [[10.0, 20.0], [10.0, 20.0], [], [10.0, 20.0]]
    waiting = [0, 2, 3, 0]
    m = run(speeds, waiting)
    assert m["avg_speed_mps"] == pytest.approx(15.0)  # Flow's: the waiting ones and the empty step left out
    assert m["avg_speed_all_mps"] == pytest.approx((15.0 + 7.5 + 0.0 + 15.0) / 4)
