"""The 6-DOF side of a multi-fidelity fleet in a sharded run (``corridor.shards``).

Every rank of a sharded run steps the same replicated fleet bookkeeping (the point masses, the
fidelity decisions, the commands), so every rank makes the same calls on its 6-DOF fleet. A
:class:`PeerJSBSimFleet` takes them all and flies only its rank's aircraft, in a local
:class:`~corridor.vehicles.air.jsbsim_switch.SwitchableJSBSimFleet`: a quadcopter of pool group g
flies on rank ``g % size`` (a group's FDM pool lives on one rank, so the FDMs an aircraft gets, and
its trajectory, are those of the one-process fleet: see ``jsbsim_switch``), the k-th aircraft added
with ``add`` (the piloted ones) on rank ``k % size``. After each step the ranks exchange their aircraft's states: one float array per rank (10
values per aircraft, in the rank's fleet order, which is the one-process order restricted to the
rank's aircraft), so every rank then holds the whole fleet's state in the one-process fleet's order.
A state read after a change and before the next step (the backend's fidelity check at the first
tick) exchanges once more; every rank sees the same calls, so every rank exchanges at the same
points.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from corridor.shards import ShardComm
from corridor.snapshot import Role
from corridor.vehicles.air.autopilot import Command
from corridor.vehicles.air.jsbsim_fleet import FleetState
from corridor.vehicles.air.jsbsim_switch import SwitchableJSBSimFleet

_COLS = 10  # position (3), velocity (3), yaw, roll, pitch, airspeed


def _pack(st: FleetState) -> np.ndarray:
    return np.column_stack([st.position, st.velocity, st.yaw, st.roll, st.pitch, st.airspeed]).reshape(-1, _COLS)


class PeerJSBSimFleet:
    """One rank's share of a sharded run's 6-DOF fleet, with the whole fleet's state after each step
    (the calls of :class:`SwitchableJSBSimFleet` that the multi-fidelity backend makes)."""

    def __init__(self, local: SwitchableJSBSimFleet, comm: ShardComm) -> None:
        self.local, self.comm = local, comm
        comm.idle = local.prefetch  # a rank waiting for its peers warms FDMs for its pools' next growth
        self.rate_hz = local.rate_hz
        self.t_s = 0.0  # [s]
        self._order: list[str] = []  # every rank's aircraft, in the one-process fleet's order
        self._owner: dict[str, int] = {}
        self._model: dict[str, str] = {}
        self._state = FleetState(ids=np.zeros(0, dtype=object), model=np.zeros(0, dtype=object),
                                 position=np.zeros((0, 3)), velocity=np.zeros((0, 3)), yaw=np.zeros(0),
                                 roll=np.zeros(0), pitch=np.zeros(0), airspeed=np.zeros(0))
        self._finite = True
        self._changed = True
        self._added = 0  # aircraft added with ``add`` so far
        self._rows_of: list[np.ndarray] = []  # per rank: its aircraft's rows in the fleet order (cached)

    # ---- calls every rank makes; the owner acts -------------------------------------------------------
    def add(self, id: str, model: str, *args: Any) -> None:
        self._track(id, model, self._added % self.comm.size)
        self._added += 1
        if self._mine(id):
            self.local.add(id, model, *args)

    def spawn_in_flight(self, id: str, p_enu: np.ndarray, v_enu: np.ndarray, yaw_rad: float, roll_rad: float,
                        pitch_rad: float, role: Role = Role.OTHER, integ_u_mps2: float = 0.0, group: int = 0) -> None:
        self._track(id, "F450", group % self.comm.size)
        if self._mine(id):
            self.local.spawn_in_flight(id, p_enu, v_enu, yaw_rad, roll_rad, pitch_rad, role, integ_u_mps2, group)

    def command(self, id: str, cmd: Command) -> None:
        if self._mine(id):
            self.local.command(id, cmd)

    def command_velocities(self, ids: list[str], v_enu: np.ndarray) -> None:
        sel = [k for k, i in enumerate(ids) if self._mine(i)]
        if sel:
            self.local.command_velocities([ids[k] for k in sel], v_enu[sel])

    def remove(self, id: str) -> None:
        if self._mine(id):
            self.local.remove(id)
        self._order.remove(id)
        del self._owner[id], self._model[id]
        self._changed, self._rows_of = True, []

    def _track(self, id: str, model: str, rank: int) -> None:
        if id in self._owner:
            raise ValueError(f"duplicate aircraft id {id!r}")
        self._order.append(id)
        self._owner[id], self._model[id] = rank, model
        self._changed, self._rows_of = True, []

    def count_by_rank(self) -> np.ndarray:
        """[aircraft] how many each rank flies."""
        return np.bincount(np.fromiter(self._owner.values(), dtype=int, count=len(self._owner)),
                           minlength=self.comm.size)

    def _mine(self, id: str) -> bool:
        try:
            return self._owner[id] == self.comm.rank
        except KeyError:
            raise ValueError(f"{id!r} is not in the fleet") from None

    # ---- the whole fleet --------------------------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """The local aircraft advance ``dt_s`` [s]; then the ranks exchange their states."""
        self.local.step(dt_s)
        self.t_s += round(dt_s * self.rate_hz) / self.rate_hz
        self._exchange()

    def state(self) -> FleetState:
        if self._changed:
            self._exchange()
        return self._state

    @property
    def ids(self) -> list[str]:
        return list(self._order)

    @property
    def loads(self) -> int:
        """[FDM] models loaded on this rank (``total_loads``: every rank's)."""
        return self.local.loads

    def total_loads(self) -> int:
        """[FDM] models loaded on every rank (a collective: every rank calls it)."""
        return round(self.comm.sum(self.local.loads))

    def all_finite(self) -> bool:
        self.state()
        return self._finite

    def _exchange(self) -> None:
        mine = _pack(self.local.state()) if self.local.ids else np.zeros((0, _COLS))
        parts = self.comm.allgather((mine, self.local.all_finite()))
        if not self._rows_of:  # the fleet changed: rebuild the per-rank rows and the fixed columns
            owner = np.array([self._owner[i] for i in self._order], dtype=int)
            self._rows_of = [np.flatnonzero(owner == r) for r in range(self.comm.size)]
            self._ids = np.array(self._order, dtype=object)
            self._models = np.array([self._model[i] for i in self._order], dtype=object)
        rows = np.zeros((len(self._order), _COLS))
        for r, (a, _) in enumerate(parts):
            if len(self._rows_of[r]) != len(a):
                raise RuntimeError(f"shard {r} flies {len(a)} aircraft, the fleet's bookkeeping says {len(self._rows_of[r])}")
            rows[self._rows_of[r]] = a
        self._finite = all(f for _, f in parts)
        self._state = FleetState(ids=self._ids, model=self._models, position=rows[:, 0:3], velocity=rows[:, 3:6],
                                 yaw=rows[:, 6], roll=rows[:, 7], pitch=rows[:, 8], airspeed=rows[:, 9])
        self._changed = False
