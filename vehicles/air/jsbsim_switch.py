"""A JSBSim fleet whose quadcopters come and go: the 6-DOF side of a multi-fidelity fleet.

:class:`SwitchableJSBSimFleet` adds to ``JSBSimFleet`` a spawn *in flight* (position, velocity and
attitude given, the state a point-mass aircraft hands over) and the removal of a quadcopter (its
state handed back). JSBSim starts an F450's propellers at rest, and a quad spawned in flight sinks
while they spool up (0.7 m/s within 0.1 s, measured); ``run_ic`` keeps their speed. So promotions
take their FDM from a pool of *warm* FDMs: loaded in batches of ``WARM_BATCH``, hovered for
``WARM_S`` off the scene, then re-initialised (``run_ic``) at the hand-over state; a removed FDM goes
back to the pool still spinning. A promotion costs an initial-condition run, not a model load.

A pooled FDM keeps what ``run_ic`` does not reset (the propellers' speed) from its last flight, so
which FDM an aircraft gets shows in its trajectory. The pool is therefore split into
``POOL_GROUPS`` pools: each quadcopter takes its FDM from its own group's pool (the multi-fidelity
backend's group: point-mass row mod ``POOL_GROUPS``). A group's FDMs then see the same promotions and
demotions whichever process flies the group, and a fleet split into shards of whole groups
(``jsbsim_shards``) gives the rows of the one-process fleet.

Every warmed batch is the same, so a rank of a sharded run warms one ahead while it waits for its
peers (:meth:`SwitchableJSBSimFleet.prefetch`, in chunks of a model load: ``ShardComm.idle``); the
next pool that grows takes it instead of warming one then (a 50 ms stall that held up every other
rank). Its model loads count when a pool takes it, so ``jsbsim_loads`` does not change.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from corridor.snapshot import Role
from corridor.vehicles.air.jsbsim_fleet import _QUAD_CMD, _STATE_PROPS, JSBSimFleet, quiet_fds
from corridor.vehicles.geodesy import FT_PER_M, heading_from_enu_yaw

_INTEG = ("corridor/integ-e-mps2", "corridor/integ-n-mps2", "corridor/integ-u-mps2")
WARM_BATCH = 8  # [FDM] loaded and spun up together when the pool is empty
WARM_S = 1.0  # [s] hover that spins the propellers up to their hover speed
POOL_GROUPS = 8  # FDM pools (the most shards a fleet can be split into)
RESERVE = 1  # [batch] warmed batches a sharded rank prefetches while it waits for its peers


class SwitchableJSBSimFleet(JSBSimFleet):
    """``JSBSimFleet`` + :meth:`spawn_in_flight` and :meth:`remove` for F450 rows."""

    def __init__(self, *args: object, **kw: object) -> None:
        super().__init__(*args, **kw)
        self._pools: dict[int, list[Any]] = {}  # group -> warm FDMs
        self._group_of: dict[str, int] = {}  # quadcopter id -> its pool group
        self._spawn_group = 0  # the group the next pooled FDM comes from
        self.loads = 0  # [FDM] models loaded (the pool reuses removed ones)
        self._warming = False  # True in the helper fleet that spins FDMs up for the pool
        self.warm_cpu_s = 0.0  # [s] CPU spent growing the pools (model loads + spin-up; diagnostics)
        self.spawn_cpu_s = 0.0  # [s] CPU spent on in-flight spawns (pool growth excluded; diagnostics)
        self._reserve: list[tuple[list[Any], int]] = []  # warmed batches (FDMs, loads) not yet in a pool
        self._prefetch: Iterator[None] | None = None  # the batch being warmed in idle time
        self.prefetched = 0  # batches a pool took from the reserve (diagnostics)
        self.prefetch_cpu_s = 0.0  # [s] CPU spent prefetching (in idle time; diagnostics)

    def _new_fdm(self, model: str) -> Any:
        if model != "F450" or self._warming:
            self.loads += 1
            return super()._new_fdm(model)
        pool = self._pools.setdefault(self._spawn_group, [])
        if not pool:
            self._warm_up(pool)
        return pool.pop()

    def _warm_up(self, pool: list[Any]) -> None:
        """A warmed batch's FDMs into the pool: the reserve's first (a batch prefetched in idle time,
        the one in progress finished first), else one warmed now. Every batch is the same (WARM_BATCH
        F450s far from the scene, flown WARM_S), so where and when it was warmed does not show in
        a trajectory; its model loads count when a pool takes it."""
        t0 = time.process_time()
        if not self._reserve and self._prefetch is not None:
            for _ in self._prefetch:
                pass
            self._prefetch = None
        if self._reserve:
            self.prefetched += 1
        else:
            for _ in self._warm_batch():
                pass
        fdms, loads = self._reserve.pop(0)
        self.loads += loads
        pool.extend(reversed(fdms))
        self.warm_cpu_s += time.process_time() - t0

    def _warm_batch(self) -> Iterator[None]:
        """Warm a batch into the reserve, in chunks: a yield after each model load (~5 ms of CPU) and
        before the spin-up (~10 ms)."""
        warm = SwitchableJSBSimFleet((self.origin.lat_deg, self.origin.lon_deg, self.origin.h_m), self.rate_hz,
                                     self.root, self.quad_gains)
        warm._warming = True
        for k in range(WARM_BATCH):
            warm.add(f"warm{k}", "F450", (0.0, 50.0 * k, 100.0))
            yield
        warm.step(WARM_S)
        self._reserve.append((list(warm._fdms), warm.loads))

    def prefetch(self) -> bool:
        """One chunk of work towards a reserve of RESERVE batches (for a rank waiting for its peers:
        ``corridor.shards.ShardComm.idle``); False when the reserve is full."""
        if self._prefetch is None:
            if len(self._reserve) >= RESERVE:
                return False
            self._prefetch = self._warm_batch()
        t0 = time.process_time()
        if next(self._prefetch, StopIteration) is StopIteration:
            self._prefetch = None
        self.prefetch_cpu_s += time.process_time() - t0
        return True

    def spawn_in_flight(self, id: str, p_enu: np.ndarray, v_enu: np.ndarray, yaw_rad: float,
                        roll_rad: float, pitch_rad: float, role: Role = Role.OTHER, integ_u_mps2: float = 0.0,
                        group: int = 0) -> None:
        """An F450 at ``p_enu`` [m] flying ``v_enu`` [m/s] with attitude (roll, pitch, ENU yaw) [rad]
        and the cascade's vertical integrator at ``integ_u_mps2``, its FDM from pool ``group``; its
        cascade holds the position until it is given a command."""
        t0, warm0 = time.process_time(), self.warm_cpu_s
        self._spawn_group = group
        self.add(id, "F450", p_enu, yaw_rad, 0.0, role)
        self._group_of[id] = group
        row = self._row_of[id]
        fdm = self._fdms[row]
        ve, vn, vu = (float(x) * FT_PER_M for x in v_enu)
        fdm["ic/vn-fps"], fdm["ic/ve-fps"], fdm["ic/vd-fps"] = vn, ve, -vu
        fdm["ic/phi-deg"] = float(np.degrees(roll_rad))
        fdm["ic/theta-deg"] = float(np.degrees(pitch_rad))
        fdm["ic/psi-true-deg"] = float(np.degrees(heading_from_enu_yaw(yaw_rad)))
        with quiet_fds():
            if not fdm.run_ic():
                raise RuntimeError(f"JSBSim initial conditions failed for {id!r} (in-flight spawn)")
        fdm["fcs/ScasEngage"] = 1.0
        for prop, value in zip(_INTEG, (0.0, 0.0, integ_u_mps2), strict=True):
            fdm[prop] = value
        self._raw[row] = self._read_row(row)
        self.spawn_cpu_s += time.process_time() - t0 - (self.warm_cpu_s - warm0)

    def remove(self, id: str) -> None:
        """Take quadcopter ``id`` out of the fleet (its FDM goes to the pool)."""
        row = self._row(id)
        if self.models[row] != "F450":
            raise ValueError(f"only quadcopters leave the 6-DOF fleet, {id!r} is a {self.models[row]}")
        q = self._quad_of[row]
        self._raw = np.delete(self._raw, row, axis=0)
        self._pools.setdefault(self._group_of.pop(id, 0), []).append(self._fdms[row])
        for seq in (self.ids, self.models, self.roles, self._fdms, self._nodes, self._runs):
            del seq[row]
        p = len(_STATE_PROPS)
        del self._getters[row * p:(row + 1) * p]  # row-major: the row's getters are one slice
        del self._row_of[id]
        for i in self.ids[row:]:
            self._row_of[i] -= 1
        del self._quad_rows[q]
        self._quad_rows[q:] = [r - 1 for r in self._quad_rows[q:]]  # sorted: the rows after q follow row
        self._quad_of = {r: k for k, r in enumerate(self._quad_rows)}
        self._fw_rows = [r - (r > row) for r in self._fw_rows]
        k = len(_QUAD_CMD)
        del self._cmd_setters[q * k:(q + 1) * k]
        if self._quad_wp:
            self._quad_wp = {(i - (i > q)): v for i, v in self._quad_wp.items() if i != q}
        self.quad_targets.delete(q)

    def all_finite(self) -> bool:
        """Every state value of every aircraft is finite."""
        return bool(np.all(np.isfinite(self._raw)))
