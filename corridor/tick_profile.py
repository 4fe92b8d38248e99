"""Where a run's CPU goes, tick by tick and part by part (opt-in: ``simulate(..., profile=True)``).

A :class:`TickProfile` times every part of every tick with the thread's CPU clock
(``time.thread_time``: user + system time of the thread, blind to the time the thread waits, so it
holds on a loaded machine): each component's ``tick``, the command hand-over (``act``) and the
snapshot's assembly (``snapshot``). In a sharded run (``corridor.shards``) the CPU spent inside the
collectives is taken out of the part that called them and kept apart (``exchange``, of which
``serialise`` is the pickling), and the communicator's trace of its collectives (the thread's CPU at
the entry and exit of each) gives the segments between two collectives: every rank runs the same
collectives in the same order, so a segment of the wall time lasts as long as its slowest rank's CPU
for it. :func:`predict_wall` sums these maxima: the wall time of the tick loop on one free core per
rank, and the speed-up over a one-process profile follows. Profiling never changes a trajectory.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

EXCHANGE = "exchange"  # [s] CPU inside the collectives (serialisation included)
SERIALISE = "serialise"  # [s] of which pickling and unpickling
IDLE_WORK = "idle work"  # [s] work a rank did inside the collectives while it waited (``ShardComm.idle``)


@dataclass
class TickProfile:
    """Per tick, the thread CPU [s] of each part; ``comm`` (a ``ShardComm``) in a sharded run."""

    comm: Any = None
    parts: dict[str, list[float]] = field(default_factory=dict)  # part -> CPU [s] per tick
    ticks: int = 0
    loop_cpu_s: float = 0.0  # [s] thread CPU of the whole tick loop
    rounds: tuple[int, int] = (0, 0)  # the communicator's collectives at the loop's start and end
    rounds_per_tick: list[int] = field(default_factory=list)  # collectives so far, at each tick's end
    rtt_s: float = 0.0  # [s] a sharded run: the smallest round trip of a small message between two ranks
    wait_s: float = 0.0  # [s] wall time inside the loop's collectives (exchange + waiting for the slower rank)
    _cpu0: float = 0.0
    _now: dict[str, float] = field(default_factory=dict)
    _stack: list[list[float]] = field(default_factory=list)

    def begin(self, comm: Any = None) -> None:
        """The tick loop starts (after every component's set-up); ``comm``: a sharded run's ``ShardComm``."""
        self.comm = comm
        self.rounds = (self._rounds(), 0)
        self.wait_s = -self.comm.wait_s if self.comm is not None else 0.0
        self._cpu0 = time.thread_time()

    def end(self) -> None:
        """The tick loop ended (before the components finish)."""
        self.loop_cpu_s = time.thread_time() - self._cpu0
        self.rounds = (self.rounds[0], self._rounds())
        self.wait_s += self.comm.wait_s if self.comm is not None else 0.0

    @contextmanager
    def part(self, name: str) -> Iterator[None]:
        """Time ``name`` in this tick: its CPU without the parts nested in it, and without the
        collectives it calls (those go to ``exchange``, their pickling also to ``serialise``, the
        idle work a waiting rank did inside them to ``idle work``)."""
        c0 = self._comm_cpu()
        self._stack.append([0.0, 0.0, 0.0, 0.0])  # the nested parts' CPU; their collectives', pickling's, idle work's
        t0 = time.thread_time()
        try:
            yield
        finally:
            cpu = time.thread_time() - t0
            c1 = self._comm_cpu()
            inner = self._stack.pop()
            own = [(b - a) - i for a, b, i in zip(c0, c1, inner[1:], strict=True)]  # comm, serialise, idle
            self._add(name, cpu - inner[0] - own[0])
            if own[0] > 0.0:
                self._add(EXCHANGE, own[0] - own[2])
                self._add(SERIALISE, own[1])
                if own[2] > 0.0:
                    self._add(IDLE_WORK, own[2])
            if self._stack:
                outer = self._stack[-1]
                outer[0] += cpu
                for k in range(3):
                    outer[k + 1] += c1[k] - c0[k]

    def end_tick(self) -> None:
        for name in self._now.keys() - self.parts.keys():
            self.parts[name] = [0.0] * self.ticks
        for name, series in self.parts.items():
            series.append(self._now.get(name, 0.0))
        self._now = {}
        self.ticks += 1
        self.rounds_per_tick.append(self._rounds())

    def table(self) -> dict[str, np.ndarray]:
        """Part -> CPU [s] per tick (arrays of ``ticks`` values)."""
        return {k: np.asarray(v) for k, v in self.parts.items()}

    def trace(self) -> np.ndarray:
        """The loop's collectives: (k, 3) thread CPU [s] at each one's entry and exit, and the CPU it kept
        the rank busy (its idle work only as far as it can have outlasted the wait; a sharded run)."""
        if self.comm is None:
            return np.zeros((0, 3))
        a, b = self.rounds
        return np.asarray(self.comm.trace[a:b], dtype=float).reshape(-1, 3)

    def summary(self) -> dict[str, Any]:
        """What another process needs (picklable, no communicator)."""
        return {"parts": self.table(), "ticks": self.ticks, "loop_cpu_s": self.loop_cpu_s, "trace": self.trace(),
                "cpu0_s": self._cpu0, "rtt_s": self.rtt_s,
                "wait_s": self.wait_s}

    def _add(self, name: str, cpu_s: float) -> None:
        self._now[name] = self._now.get(name, 0.0) + cpu_s

    def _comm_cpu(self) -> tuple[float, float, float]:
        c = self.comm
        return (c.cpu_s, c.ser_s, c.idle_s) if c is not None else (0.0, 0.0, 0.0)

    def _rounds(self) -> int:
        return self.comm.rounds if self.comm is not None else 0


def predict_wall(ranks: list[dict[str, Any]]) -> tuple[float, float]:
    """The tick loop's wall time [s] on one free core per rank, from the ranks' ``summary()``: per
    segment between two collectives, the slowest rank's CPU (its work and its side of the exchange),
    summed, plus a round trip per collective. Returns (that, the sum over ticks of the slowest rank's
    CPU of the tick: the same without the segments inside a tick)."""
    if len(ranks) == 1:
        return ranks[0]["loop_cpu_s"], ranks[0]["loop_cpu_s"]
    segs = np.array([_segments(r) for r in ranks])  # (ranks, collectives + 1)
    rtt = ranks[0]["rtt_s"]  # measured by rank 0
    per_tick = np.array([sum(r["parts"].values()) for r in ranks])  # (ranks, ticks)
    return float(segs.max(axis=0).sum() + rtt * (segs.shape[1] - 1)), float(per_tick.max(axis=0).sum())


def _segments(r: dict[str, Any]) -> np.ndarray:
    """A rank's busy CPU [s] per segment: from the loop's start (or a collective's exit) to the next
    collective's exit (or the loop's end), the collective's idle work left out (but its overrun)."""
    tr = r["trace"]
    if not len(tr):
        return np.array([r["loop_cpu_s"]])
    start = np.concatenate([[r["cpu0_s"]], tr[:-1, 1]])
    work = tr[:, 0] - start + tr[:, 2]
    return np.append(work, r["cpu0_s"] + r["loop_cpu_s"] - tr[-1, 1])
