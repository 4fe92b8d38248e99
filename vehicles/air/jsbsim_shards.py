"""The 6-DOF side of a multi-fidelity fleet split into shards that run in separate processes.

:class:`ShardedJSBSimFleet` offers the calls the multi-fidelity backend makes on its
:class:`~corridor.vehicles.air.jsbsim_switch.SwitchableJSBSimFleet` (add, command,
command_velocities, spawn_in_flight, remove, step, state, all_finite, loads) and forwards them to
``shards`` worker processes (plain ``multiprocessing``, spawned), each holding a
``SwitchableJSBSimFleet`` with the JSBSim aircraft of its pool groups: a quadcopter of pool group g
flies in shard ``g % shards`` (see ``jsbsim_switch``: a group's FDM pool lives in one process, so the
rows equal the one-process fleet's); piloted aircraft fly in shard 0.

Calls that change a shard's fleet are queued per shard and sent with the next call that needs an
answer: ``step`` sends every shard its queue and the step at once, the shards step in parallel, and
each answers with its fleet's state (ENU, computed in the shard), its FDM loads and its process CPU
time. ``state`` between steps flushes the queues the same way without stepping. So a tick costs one
round trip per shard, plus one for each state read after a change (the backend's fidelity check).
"""

from __future__ import annotations

import multiprocessing as mp
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from corridor.snapshot import Role
from corridor.vehicles.air.autopilot import Command, QuadGains
from corridor.vehicles.air.jsbsim_fleet import FleetState
from corridor.vehicles.air.jsbsim_switch import POOL_GROUPS, SwitchableJSBSimFleet

_FLEET_OPS = frozenset({"add", "command", "command_velocities", "spawn_in_flight", "remove"})


@dataclass(frozen=True)
class _Reply:
    state: FleetState
    loads: int  # [FDM] models loaded in the shard
    cpu_s: float  # [s] the shard process's CPU time
    finite: bool
    work_s: float  # [s] wall time the shard spent on this message's calls and step


def _shard_main(conn: Connection, origin: tuple[float, float, float], rate_hz: float, root: str | None,
                gains: QuadGains | None) -> None:
    """A shard process: apply each message's queued calls, step if asked, answer with the state."""
    fleet = SwitchableJSBSimFleet(origin, rate_hz, root, gains)
    while True:
        msg = conn.recv()
        if msg is None:
            return
        ops, dt_s = msg
        t0 = time.perf_counter()
        try:
            for name, args in ops:
                if name not in _FLEET_OPS:
                    raise ValueError(f"unknown shard call {name!r}")
                getattr(fleet, name)(*args)
            if dt_s:
                fleet.step(dt_s)
            state = fleet.state()
            conn.send(_Reply(state, fleet.loads, time.process_time(), fleet.all_finite(), time.perf_counter() - t0))
        except Exception as exc:  # the parent raises it: a shard never dies silently
            conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))


def _empty_state() -> FleetState:
    z = np.zeros(0)
    return FleetState(ids=np.zeros(0, dtype=object), model=np.zeros(0, dtype=object), position=np.zeros((0, 3)),
                      velocity=np.zeros((0, 3)), yaw=z, roll=z, pitch=z, airspeed=z)


def _concat(states: list[FleetState]) -> FleetState:
    """The shards' states one after the other (the backend finds rows by id)."""
    if not states:
        return _empty_state()
    return FleetState(**{f: np.concatenate([getattr(s, f) for s in states])
                         for f in ("ids", "model", "position", "velocity", "yaw", "roll", "pitch", "airspeed")})


class ShardedJSBSimFleet:
    """A ``SwitchableJSBSimFleet`` whose aircraft live in ``shards`` worker processes."""

    def __init__(self, origin: tuple[float, float, float], shards: int, rate_hz: float = 120.0,
                 root: str | None = None, quad_gains: QuadGains | None = None) -> None:
        if not 2 <= shards <= POOL_GROUPS:
            raise ValueError(f"shards must be between 2 and {POOL_GROUPS} (one process: the plain fleet), got {shards}")
        self.rate_hz = float(rate_hz)
        self.t_s = 0.0  # [s]
        self._shard_of: dict[str, int] = {}
        self._queue: list[list[tuple[str, tuple[Any, ...]]]] = [[] for _ in range(shards)]
        self._replies: list[_Reply] = []
        self._state = _empty_state()
        # the exchange's cost (diagnostics, read by benchmarks/uav_city.py --shards): round trips, their
        # wall time, and the wall time of the slowest shard's work in each (the rest is the exchange)
        self.rounds, self.round_wall_s, self.slowest_work_s = 0, 0.0, 0.0
        ctx = mp.get_context("spawn")  # no fork of a process that may hold libsumo or threads
        self._conns: list[Connection] = []
        self._procs: list[Any] = []
        for _ in range(shards):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_shard_main, args=(child, origin, rate_hz, root, quad_gains), daemon=True)
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)
        self._sync(0.0)  # every shard up (its imports done) before the run's first tick

    # ---- calls forwarded to one shard -----------------------------------------------------------------
    def add(self, id: str, model: str, *args: Any) -> None:
        self._to(0, id, "add", id, model, *args)

    def spawn_in_flight(self, id: str, p_enu: np.ndarray, v_enu: np.ndarray, yaw_rad: float, roll_rad: float,
                        pitch_rad: float, role: Role = Role.OTHER, integ_u_mps2: float = 0.0, group: int = 0) -> None:
        self._to(group % len(self._conns), id, "spawn_in_flight", id, p_enu, v_enu, yaw_rad, roll_rad, pitch_rad, role,
                 integ_u_mps2, group)

    def command(self, id: str, cmd: Command) -> None:
        self._queue[self._shard(id)].append(("command", (id, cmd)))

    def command_velocities(self, ids: list[str], v_enu: np.ndarray) -> None:
        shard = np.array([self._shard(i) for i in ids], dtype=int)
        for k in np.unique(shard).tolist():
            sel = np.flatnonzero(shard == k)
            self._queue[k].append(("command_velocities", ([ids[j] for j in sel.tolist()], v_enu[sel])))

    def remove(self, id: str) -> None:
        self._queue[self._shard(id)].append(("remove", (id,)))
        del self._shard_of[id]

    def _to(self, shard: int, id: str, name: str, *args: Any) -> None:
        if id in self._shard_of:
            raise ValueError(f"duplicate aircraft id {id!r}")
        self._shard_of[id] = shard
        self._queue[shard].append((name, args))

    def _shard(self, id: str) -> int:
        try:
            return self._shard_of[id]
        except KeyError:
            raise ValueError(f"{id!r} is not in the fleet") from None

    # ---- calls answered by every shard ----------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """Every shard applies its queue and advances ``dt_s`` [s], in parallel."""
        self._sync(dt_s)
        self.t_s += round(dt_s * self.rate_hz) / self.rate_hz

    def state(self) -> FleetState:
        if any(self._queue):
            self._sync(0.0)
        return self._state

    @property
    def ids(self) -> list[str]:
        return [str(i) for i in self.state().ids]

    @property
    def loads(self) -> int:
        self.state()
        return sum(r.loads for r in self._replies)

    def all_finite(self) -> bool:
        self.state()
        return all(r.finite for r in self._replies)

    def shard_cpu_s(self) -> float:
        """[s] CPU time of the shard processes so far (at their last answer)."""
        return sum(r.cpu_s for r in self._replies)

    def _sync(self, dt_s: float) -> None:
        t0 = time.perf_counter()
        for conn, ops in zip(self._conns, self._queue, strict=True):
            conn.send((ops, dt_s))
        self._queue = [[] for _ in self._conns]
        replies = []
        for k, conn in enumerate(self._conns):
            reply = conn.recv()
            if not isinstance(reply, _Reply):
                raise RuntimeError(f"JSBSim shard {k}: {reply[1]}")
            replies.append(reply)
        self._replies = replies
        self._state = _concat([r.state for r in replies])
        self.rounds += 1
        self.round_wall_s += time.perf_counter() - t0
        self.slowest_work_s += max(r.work_s for r in replies)

    def close(self) -> None:
        """Stop the shard processes (idempotent)."""
        for conn in self._conns:
            try:
                conn.send(None)
                conn.close()
            except OSError:
                pass
        for proc in self._procs:
            proc.join(timeout=5.0)
            if proc.is_alive():
                proc.terminate()
        self._conns, self._procs = [], []
