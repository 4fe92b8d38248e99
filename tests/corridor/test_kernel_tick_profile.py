"""corridor.tick_profile: CPU per tick and part (nested parts apart, collectives apart), and the
predicted wall time of a sharded tick loop (per segment between collectives, the slowest rank)."""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np
import pytest

from corridor.engine import Component, Phase, RunContext, Simulation
from corridor.events import Event
from corridor.shards import ShardComm, run_sharded
from corridor.tick_profile import EXCHANGE, SERIALISE, TickProfile, predict_wall


def _spin(cpu_s: float) -> None:
    t0 = time.thread_time()
    while time.thread_time() - t0 < cpu_s:
        pass


class Busy(Component):
    """Burns ``outer_s`` of CPU, then ``inner_s`` inside a nested part ``<name>.inner``."""

    def __init__(self, name: str, outer_s: float, inner_s: float) -> None:
        super().__init__(name)
        self.phase, self.period, self.outer_s, self.inner_s = Phase.DETECT, 0.1, outer_s, inner_s

    def tick(self, ctx: RunContext) -> None:
        _spin(self.outer_s)
        with ctx.part(f"{self.name}.inner"):
            _spin(self.inner_s)


def test_parts_per_tick_nested_apart() -> None:
    sim = Simulation(RunContext(run_seed=1, dt=0.1, duration=0.5), [Busy("mon", 0.004, 0.002)])
    sim.ctx.profile = TickProfile()
    sim.run()
    t = sim.ctx.profile.table()
    assert sim.ctx.profile.ticks == 5 and len(t["mon"]) == 5
    assert np.all(t["mon"] >= 0.004) and np.all(t["mon"] < 0.0055)  # its own CPU, the nested part not in it
    assert np.all(t["mon.inner"] >= 0.002) and np.all(t["mon.inner"] < 0.0035)
    assert "snapshot" in t and EXCHANGE not in t  # one process: no collectives
    assert sim.ctx.profile.loop_cpu_s >= 5 * 0.006


def test_an_unprofiled_run_times_nothing() -> None:
    sim = Simulation(RunContext(run_seed=1, dt=0.1, duration=0.2), [Busy("mon", 0.0, 0.0)])
    sim.run()
    assert sim.ctx.profile is None


def _rank(work_s: list[list[float]], comm: ShardComm) -> tuple[dict[str, Any], list[Event]]:
    """Per tick: work, an allgather inside a part, more work (rank r burns work_s[r][...])."""
    prof = TickProfile()
    prof.rtt_s = comm.round_trip(20)
    prof.begin(comm)
    mine = work_s[comm.rank]
    for tick in range(2):
        with prof.part("a"):
            _spin(mine[2 * tick])
            comm.allgather(np.zeros(1000))
        with prof.part("b"):
            _spin(mine[2 * tick + 1])
        prof.end_tick()
    prof.end()
    return {"profiles": comm.allgather(prof.summary())}, []


def test_prediction_takes_the_slowest_rank_per_segment() -> None:
    # rank 0 is slow before each exchange, rank 1 after it: per tick they are even, per segment not
    work = [[0.02, 0.0, 0.02, 0.0], [0.0, 0.02, 0.0, 0.02]]
    metrics, _, _ = run_sharded(partial(_rank, work), partial(_rank, work), 2)
    ranks = metrics["profiles"]
    for r in ranks:
        parts = r["parts"]
        assert parts[EXCHANGE].sum() > 0.0 and 0.0 < parts[SERIALISE].sum() <= parts[EXCHANGE].sum()
        assert len(r["trace"]) == 2  # the loop's collectives only (not the round trips, not the gather)
    wall, per_tick = predict_wall(ranks)
    # segments (rank 0 | rank 1): [0.02 | 0], [0 + 0.02 | 0.02 + 0], [0 | 0.02]: 0.06 s on the slowest
    # rank each; per tick each rank burns 0.02 s: 0.04 s. The spins are exact in thread CPU; the
    # collectives' own CPU (pickling, pipes) is not, and grows on a loaded machine: bound it by what
    # the ranks measured instead of a fixed tolerance
    work = np.array([r["parts"]["a"] + r["parts"]["b"] for r in ranks])  # (ranks, ticks)
    comm = np.array([sum(v for k, v in r["parts"].items() if k not in ("a", "b")) for r in ranks])
    comm_cpu = float(comm.sum(axis=1).max())  # the busiest rank's CPU inside the collectives [s]
    assert float(work.max(axis=0).sum()) == pytest.approx(0.04, abs=0.004)
    assert 0.04 - 0.004 <= per_tick <= 0.04 + 0.004 + comm_cpu
    assert 0.06 - 0.006 <= wall <= 0.06 + 0.006 + comm_cpu * 2 + ranks[0]["rtt_s"] * 2
    assert 0.0 < ranks[0]["rtt_s"] < 0.05
