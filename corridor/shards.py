"""One run split over shard processes that each step the whole world and divide the work.

A component asks for shards with its ``shard_count`` (the multi-fidelity air backend's
``params.shards``). :func:`run_sharded` then runs the simulation in ``K`` processes (rank 0 is the
calling process, ranks 1..K-1 are spawned), each from the same scenario and seed, each with a
:class:`ShardComm` as ``ctx.shard``. Every rank steps the same replicated state (cheap per-aircraft
arrays stay identical because every rank computes them from the same inputs); the expensive work is
divided: a component that supports shards does only its rank's part (the JSBSim aircraft of its
pool groups, the separation and collision checks of the pairs in its region of the world, see
:class:`Strips`) and exchanges the results it shares (``allgather``: numpy arrays through pipes,
once per tick, never an object per aircraft). At the end each sharded component combines its
partial metrics over the ranks itself (``allreduce`` of counts, minima, per-aircraft arrays), so
every rank finishes with the one-process run's metrics; rank 0 returns them, and the event log is
the union of the ranks' logs (:func:`merge_events`).

The kernel knows no domain: this module only moves objects between processes and splits a plane.
"""

from __future__ import annotations

import multiprocessing as mp
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any

import numpy as np

from corridor.events import Event

MAX_SHARDS = 8


@dataclass
class ShardComm:
    """A rank's pipes to every other rank; collectives are called by every rank in the same order."""

    rank: int
    size: int
    conns: dict[int, Connection]
    rounds: int = 0  # collectives so far (diagnostics)
    wait_s: float = 0.0  # [s] wall time inside collectives: the exchange plus waiting for slower ranks
    cpu_s: float = 0.0  # [s] thread CPU inside collectives (serialisation, pipe reads and writes)
    ser_s: float = 0.0  # [s] of which pickling and unpickling
    # per collective: thread CPU [s] at its entry and exit, and the CPU it kept this rank busy
    trace: list[tuple[float, float, float]] = field(default_factory=list)
    peer_cpu_s: list[float] = field(default_factory=list)  # [s] every rank's CPU at the last cpu_gather
    # work for a rank that waits for a peer (one short chunk per call; False: nothing left), run once a
    # receive has waited idle_after_s, between polls of the pipe; it must not change what any rank computes
    idle: Callable[[], bool] | None = None
    idle_after_s: float = 0.002  # [s]
    idle_s: float = 0.0  # [s] thread CPU of the idle work (inside the collectives' cpu_s)
    _overrun: float = 0.0  # [s] this collective: the idle chunks that may have outlasted the wait
    strips: Strips | None = None  # the run's split of the plane, when a component balances it for the others
    carried: list[list[Any]] = field(default_factory=list)  # per rank: what it posted for the last allgather
    _posted: list[Any] = field(default_factory=list)

    def post(self, obj: Any) -> None:
        """Send ``obj`` with the next ``allgather`` (one message fewer than an allgather of its own;
        every rank posts as many objects at the same points); after it, ``carried[r]`` is rank r's."""
        self._posted.append(obj)

    def allgather(self, obj: Any) -> list[Any]:
        """``obj`` of every rank, in rank order (pairwise: the lower rank sends first, so a large
        message cannot fill both pipes at once)."""
        t0, c0, idle0 = time.perf_counter(), time.thread_time(), self.idle_s
        self._overrun = 0.0
        out: list[Any] = [None] * self.size
        msg = (obj, self._posted)
        out[self.rank] = msg
        for peer in sorted(self.conns):
            if self.rank < peer:
                self._send(peer, msg)
                out[peer] = self._recv(peer)
            else:
                out[peer] = self._recv(peer)
                self._send(peer, msg)
        self.carried, self._posted = [m[1] for m in out], []
        out = [m[0] for m in out]
        self.rounds += 1
        c1 = time.thread_time()
        self.wait_s += time.perf_counter() - t0
        self.cpu_s += c1 - c0
        # busy: the idle work counts only as far as it can have kept this rank late (its last chunk)
        self.trace.append((c0, c1, c1 - c0 - (self.idle_s - idle0) + self._overrun))
        return out

    def _send(self, peer: int, obj: Any) -> None:
        c0 = time.thread_time()
        buf = ForkingPickler.dumps(obj)  # what Connection.send does, timed apart
        self.ser_s += time.thread_time() - c0
        try:
            self.conns[peer].send_bytes(buf)
        except OSError:  # the peer is gone: its last word (a failure) may still be in the pipe
            self._recv(peer)
            raise RuntimeError(f"shard {peer} ended during a collective") from None

    def _recv(self, peer: int) -> Any:
        try:
            if self.idle is not None:
                self._idle_until(self.conns[peer])
            buf = self.conns[peer].recv_bytes()
        except (EOFError, OSError):
            raise RuntimeError(f"shard {peer} ended during a collective") from None
        c0 = time.thread_time()
        msg = ForkingPickler.loads(buf)
        self.ser_s += time.thread_time() - c0
        return _checked(msg, peer)

    def _idle_until(self, conn: Connection) -> None:
        """Chunks of idle work while ``conn`` has nothing after ``idle_after_s`` of waiting (a peer
        this far behind is in a long stall: a chunk does not make this rank the late one)."""
        if conn.poll(self.idle_after_s):
            return
        c0 = c = time.thread_time()
        while self.idle is not None and self.idle():
            last, c = c, time.thread_time()
            if conn.poll():
                self._overrun += c - last  # the message came during this chunk at the latest
                break
        self.idle_s += time.thread_time() - c0

    def round_trip(self, times: int = 200) -> float:
        """[s] the smallest round trip of a small message between rank 0 and each other rank (every
        rank calls it; not a collective: nothing is counted). On a loaded machine the smallest of
        many is still near the idle machine's."""
        best = float("inf")
        for _ in range(times):
            for peer in sorted(self.conns):
                if self.rank == 0:
                    t0 = time.perf_counter()
                    self.conns[peer].send_bytes(b"x")
                    self.conns[peer].recv_bytes()
                    best = min(best, time.perf_counter() - t0)
                elif peer == 0:
                    self.conns[0].recv_bytes()
                    self.conns[0].send_bytes(b"x")
        return best

    def sum(self, value: float) -> float:
        """The sum over the ranks (in rank order: the same float on every rank)."""
        return float(sum(self.allgather(float(value))))

    def min_array(self, a: np.ndarray) -> np.ndarray:
        """The elementwise minimum over the ranks."""
        out: np.ndarray = np.minimum.reduce(self.allgather(np.asarray(a)))
        return out

    def cpu_gather(self) -> float:
        """[s] the CPU time of every rank's process (kept in ``peer_cpu_s``); returns their sum."""
        self.peer_cpu_s = [float(c) for c in self.allgather(time.process_time())]
        return float(sum(self.peer_cpu_s))

    def close(self) -> None:
        for conn in self.conns.values():
            conn.close()


def _checked(msg: Any, peer: int) -> Any:
    if isinstance(msg, _Failed):
        raise RuntimeError(f"shard {peer} failed: {msg.message}")
    return msg


@dataclass(frozen=True)
class _Failed:
    message: str


class Strips:
    """A split of the plane into ``size`` strips along x (east), as many aircraft in each at the start
    (the edges are the quantiles of the first positions: the same on every rank); ``rebalance`` moves
    the edges to even out the ranks' work."""

    def __init__(self, x_m: np.ndarray, size: int) -> None:
        self.size = size
        self.edges = np.quantile(x_m, np.arange(1, size) / size) if len(x_m) else np.zeros(size - 1)  # [m]

    def rebalance(self, x_m: np.ndarray, fixed: np.ndarray, max_step_m: float) -> None:
        """Move every edge toward :func:`balanced_edges` (``x_m``: the points whose work a strip
        divides, one unit each; ``fixed``: the units each rank has besides), at most ``max_step_m``
        [m]. Sorted edges stay sorted; the same inputs give the same edges on every rank."""
        target = balanced_edges(x_m, fixed, self.size)
        if target is not None:
            self.edges = self.edges + np.clip(target - self.edges, -max_step_m, max_step_m)

    def owner(self, x_m: np.ndarray) -> np.ndarray:
        """The rank whose strip holds each x [m] (a point on an edge belongs to the strip east of it)."""
        return np.searchsorted(self.edges, x_m, side="right")

    def within(self, x_m: np.ndarray, rank: int, halo_m: float = 0.0) -> np.ndarray:
        """Boolean: x [m] in strip ``rank`` widened by ``halo_m`` on both sides."""
        lo = self.edges[rank - 1] - halo_m if rank > 0 else -np.inf
        hi = self.edges[rank] + halo_m if rank < self.size - 1 else np.inf
        return (x_m >= lo) & (x_m < hi)


def balanced_edges(x_m: np.ndarray, fixed: np.ndarray, size: int) -> np.ndarray | None:
    """The strip edges [m] that give every rank the same work: rank r, with ``fixed[r]`` units of its
    own, gets ``max(0, T - fixed[r])`` of the points ``x_m`` (one unit each), T such that every point
    has a strip (water-filling); None with fewer than two points."""
    xs = np.sort(np.asarray(x_m, float))
    n, f = len(xs), np.asarray(fixed, float)
    if n < 2:
        return None
    lo, hi = float(f.min()), float(f.max()) + n
    for _ in range(64):  # bisection on T: sum(max(0, T - f)) = n
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if np.maximum(0.0, mid - f).sum() > n else (mid, hi)
    counts = np.maximum(0.0, lo - f)
    cut = np.clip(np.round(np.cumsum(counts)[:-1] * n / counts.sum()).astype(int), 1, n - 1)
    edges: np.ndarray = 0.5 * (xs[cut - 1] + xs[cut])
    return edges


def merge_events(logs: list[list[Event]]) -> list[Event]:
    """The ranks' event logs as one, in time order: rank 0's, then each event of another rank that
    rank 0 did not log (a replicated component logs the same events on every rank; a sharded one
    logs each of its events on one rank, or the same one on several)."""
    seen = {(e.t, e.source, e.kind, e.message) for e in logs[0]}
    out = list(logs[0])
    for log in logs[1:]:
        for e in log:
            key = (e.t, e.source, e.kind, e.message)
            if key not in seen:
                seen.add(key)
                out.append(e)
    return sorted(out, key=lambda e: e.t)  # stable: rank 0's order within a time


def _worker(run: RankRun, comm: ShardComm) -> None:
    """A spawned rank: run, send rank 0 the metrics and events (rank 0 merges the events)."""
    try:
        metrics, events = run(comm)
        comm.conns[0].send(("done", metrics, events))
    except Exception as exc:  # a rank never dies silently: its peers raise with its message
        msg = _Failed(f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}")
        for conn in comm.conns.values():
            try:
                conn.send(msg)
            except OSError:
                pass
    finally:
        comm.close()


RankRun = Callable[[ShardComm], tuple[dict[str, Any], list[Event]]]


def run_sharded(rank0: RankRun, others: RankRun, size: int) -> tuple[dict[str, Any], list[Event], ShardComm]:
    """``rank0(comm)`` here and ``others(comm)`` on ranks 1..size-1 in spawned processes (``others``
    must be picklable: a module-level function or a ``functools.partial`` of one). Returns rank 0's
    metrics, the merged event log and rank 0's communicator (its diagnostics)."""
    if not 2 <= size <= MAX_SHARDS:
        raise ValueError(f"shards must be between 2 and {MAX_SHARDS} (1: no shards), got {size}")
    ctx = mp.get_context("spawn")  # no fork of a process that may hold libsumo, JSBSim or threads
    ends: dict[int, dict[int, Connection]] = {r: {} for r in range(size)}
    for a in range(size):
        for b in range(a + 1, size):
            ends[a][b], ends[b][a] = ctx.Pipe()
    procs = []
    for r in range(1, size):
        proc = ctx.Process(target=_worker, args=(others, ShardComm(r, size, ends[r])), daemon=True)
        proc.start()
        procs.append(proc)
    for r in range(1, size):  # the spawned ranks hold their own ends now
        for conn in ends[r].values():
            conn.close()
    comm = ShardComm(0, size, ends[0])
    try:
        metrics, events = rank0(comm)
        logs = [events]
        for r in range(1, size):
            msg = _checked(comm.conns[r].recv(), r)
            logs.append(msg[2])
        return metrics, merge_events(logs), comm
    except Exception:
        for conn in comm.conns.values():  # let waiting ranks fail rather than hang
            try:
                conn.send(_Failed("rank 0 failed"))
            except OSError:
                pass
        raise
    finally:
        comm.close()
        for proc in procs:
            proc.join(timeout=10.0)
            if proc.is_alive():
                proc.terminate()
