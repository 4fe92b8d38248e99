"""A multi-fidelity air backend: point-mass quadcopters that fly JSBSim 6-DOF where it matters.

Registered as ``multi_fidelity_fleet``; it takes every parameter of the ``jsbsim_fleet`` backend
(explicit aircraft, ``encounter``, ``swarm``, ``patrol``) plus

- ``fidelity`` (:class:`~corridor.vehicles.air.fidelity.FidelityParams`): ``mode`` point_mass / jsbsim /
  multi and the promotion / demotion boundaries;
- ``point_mass_period_s``: the point-mass step (a whole multiple of the scenario's ``dt``);
- ``city`` (:class:`~corridor.vehicles.air.city.CitySpec`): a city's delivery fleet drawn per run.

Every quadcopter has a row in a :class:`PointMassFleet`; the ones flying 6-DOF (and every c172x)
are in a :class:`SwitchableJSBSimFleet`. Each tick (the scenario's ``dt``):

1. every ``point_mass_period_s`` (time T): the fidelity check on the exact states at T, the
   promotions (the point-mass state -- position, velocity, yaw, the attitude of its acceleration --
   becomes the JSBSim initial condition, and its active command the cascade's) and demotions (the
   JSBSim state goes back into the point-mass row), each an event (``promote`` / ``demote``); then
   the point-mass rows advance to T + period at once (slowest first);
2. the JSBSim fleet advances one ``dt`` (120 Hz inside);
3. the snapshot: 6-DOF rows as JSBSim has them, point-mass rows interpolated linearly between T and
   T + period (the 6-DOF side's and the monitors' view, every ``dt``).

Commands reach the point-mass row always (its targets stay current) and the JSBSim aircraft while it
flies 6-DOF. :class:`FleetVelocityCommand` commands many aircraft in one bus item.

``shards: K`` splits the run over K processes (``corridor.shards``): every rank runs the fidelity
check and the missions of the whole fleet (the same on every rank), steps an equal share of the
point masses (their stepped states travel with the 6-DOF state exchange), and flies the JSBSim aircraft of its pool
groups (:class:`~corridor.vehicles.air.jsbsim_shards.PeerJSBSimFleet`). The backend owns the run's
split of the city into strips (``ShardComm.strips``, which the monitors and the avoidance divide
their work by) and moves its edges every point-mass period toward the split that evens out the
ranks' work (:class:`ShardBalance`). ``cpu_per_sim_s`` sums the ranks' CPU.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.engine import Metric, RunContext
from corridor.shards import Strips
from corridor.snapshot import Kind, Role, WorldSnapshot
from corridor.vehicles.air.autopilot import VelocityCommand
from corridor.vehicles.air.backend import AirBackend, AircraftCommand
from corridor.vehicles.air.city import CitySpec, Missions, city_fleet
from corridor.vehicles.air.fidelity import FidelityParams, FidelityPolicy
from corridor.vehicles.air.jsbsim_fleet import SIZE_M
from corridor.vehicles.air.jsbsim_shards import PeerJSBSimFleet
from corridor.vehicles.air.jsbsim_switch import POOL_GROUPS, SwitchableJSBSimFleet
from corridor.vehicles.air.point_mass_fleet import PointMassFleet


class ShardBalance(BaseModel):
    """How a sharded run splits the city into strips (``corridor.shards.Strips``): every
    point-mass period the edges move toward the split that evens out the ranks' work, counting each
    aircraft in a strip as one unit (its separation, collision and avoidance work) and each JSBSim
    aircraft a rank flies as ``six_dof_weight`` units more (its pool group's rank flies it wherever it
    is), by at most ``edge_step_m``. The rows do not depend on the split, nor on ``prefetch``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    six_dof_weight: float = Field(80.0, ge=0.0)  # [units] per JSBSim aircraft: its steps and its share of the spawns
    edge_step_m: float = Field(100.0, ge=0.0)  # [m] per point-mass period (0: the first split stays)
    prefetch: bool = True  # a rank that waits for its peers warms the next FDM batch (jsbsim_switch)


@dataclass(frozen=True)
class FleetVelocityCommand:
    """Velocity commands [m/s] (k, 3) for the aircraft at snapshot rows ``rows`` of this backend."""

    rows: np.ndarray
    v_enu: np.ndarray


class MultiFidelityAirBackend(AirBackend):
    """Point-mass + JSBSim fleet with per-aircraft fidelity (registered as ``multi_fidelity_fleet``)."""

    metrics: ClassVar[tuple[Metric, ...]] = AirBackend.metrics + (
        Metric('six_dof_share', '1', 'Share of the quadcopters\' flight time flown in JSBSim 6-DOF.'),
        Metric('promotions', '1', 'Point-mass -> 6-DOF switches.'),
        Metric('demotions', '1', '6-DOF -> point-mass switches.'),
        Metric('jsbsim_loads', '1', 'JSBSim models loaded (promotions reuse pooled ones).'),
        Metric('cpu_per_sim_s', 's', 'Process CPU time per simulated second from the first tick (a measure of the machine).'),
        Metric('flight_hours', 'h', 'Quadcopter flight time.'),
    )

    class Params(AirBackend.Params):
        fidelity: FidelityParams = Field(default_factory=FidelityParams)
        point_mass_period_s: float = Field(0.5, gt=0.0)  # [s]
        city: CitySpec | None = None
        shards: int = Field(1, ge=1, le=POOL_GROUPS)  # processes the run is split into (corridor.shards)
        shard_balance: ShardBalance = Field(default_factory=ShardBalance)

    def __init__(self, name: str, params: Params, scenario: Any) -> None:
        super().__init__(name, params, scenario)
        every = params.point_mass_period_s / scenario.dt
        if abs(every - round(every)) > 1e-9 or round(every) < 1:
            raise ValueError(f"{name}.params.point_mass_period_s: {params.point_mass_period_s} s must be a whole "
                             f"multiple of dt = {scenario.dt} s")
        self.pm_every = round(every)
        self.shard_count = params.shards
        self.policy = FidelityPolicy(params.fidelity)
        self.missions: Missions | None = None

    # ---- setup ----------------------------------------------------------------------------------
    def setup(self, ctx: RunContext) -> None:
        p = self.params
        if p.city is not None:
            city, self.missions = city_fleet(p.city, ctx.rng(f"{self.name}/city"), ctx.rng(f"{self.name}/missions"))
            self.aircraft = self.aircraft + city
        self.ids = np.array([a.id for a in self.aircraft], dtype=object)
        self.row = {a.id: k for k, a in enumerate(self.aircraft)}
        self.is_quad = np.array([a.model == "F450" for a in self.aircraft], dtype=bool)
        self.quad_rows = np.flatnonzero(self.is_quad)
        self.q_of = np.full(len(self.aircraft), -1)
        self.q_of[self.quad_rows] = np.arange(len(self.quad_rows))
        self.roles = np.array([Role.CONTROLLED if a.role == "controlled" else Role.OTHER for a in self.aircraft],
                              dtype=np.int8)
        self.kind = np.where(self.is_quad, Kind.UAV, Kind.AIRCRAFT).astype(np.int8)
        self.size = np.array([SIZE_M[a.model] for a in self.aircraft], dtype=float).reshape(-1, 3)
        self.pm = PointMassFleet()
        self.js: SwitchableJSBSimFleet | PeerJSBSimFleet = SwitchableJSBSimFleet(self.origin, rate_hz=p.rate_hz)
        if ctx.shard is not None:  # this rank flies its pool groups' aircraft, every rank sees all states
            self.js = PeerJSBSimFleet(self.js, ctx.shard)
            if not p.shard_balance.prefetch:
                ctx.shard.idle = None
            ctx.shard.strips = Strips(np.array([a.start_enu[0] for a in self.aircraft]), ctx.shard.size)
        self.fleet = self.js
        for a in self.aircraft:
            if a.model == "F450":
                self.pm.add(a.id, a.start_enu, np.radians(a.yaw_deg), _start_velocity(a), Role(self.roles[self.row[a.id]]))
                self.pm.command(a.id, a.initial_command())
            else:
                self.js.add(a.id, a.model, a.start_enu, np.radians(a.yaw_deg), a.speed_mps, Role.OTHER)
                self.js.command(a.id, a.initial_command())
        self.six = ~self.is_quad
        self.since = np.zeros(len(self.aircraft))
        self.promotions = self.demotions = 0
        self.six_dof_quad_s = 0.0  # [s] quadcopter-seconds flown 6-DOF
        self.tick_count = 0
        self.pm_prev_pos, self.pm_prev_vel = self.pm.pos.copy(), self.pm.vel.copy()
        self._pm_shares: list[np.ndarray] = []  # a sharded run: each rank's point-mass rows stepped this tick
        self.t_s = 0.0
        if p.fidelity.mode == "jsbsim":
            for r in self.quad_rows:
                self._promote(int(r), ctx, log=False)
        self._wall_t0 = None
        self._cpu_t0: float | None = None

    # ---- commands -------------------------------------------------------------------------------
    def apply(self, commands: list[Any], ctx: RunContext) -> None:
        for c in commands:
            if isinstance(c, AircraftCommand) and c.aircraft_id in self.row:
                r = self.row[c.aircraft_id]
                if self.is_quad[r]:
                    self.pm.command(c.aircraft_id, c.command)
                if self.six[r]:
                    self.js.command(c.aircraft_id, c.command)
                self.commands_applied += 1
            elif isinstance(c, FleetVelocityCommand):
                self._apply_fleet(c)

    def _apply_fleet(self, c: FleetVelocityCommand) -> None:
        rows = np.asarray(c.rows)
        quad = self.is_quad[rows]
        self.pm.command_velocities(self.q_of[rows[quad]], c.v_enu[quad])
        six = self.six[rows]
        for k in np.flatnonzero(six & ~quad):  # piloted aircraft: their own guidance
            self.js.command(str(self.ids[rows[k]]), VelocityCommand(tuple(map(float, c.v_enu[k]))))
        six_quad = np.flatnonzero(six & quad)
        self.js.command_velocities([str(i) for i in self.ids[rows[six_quad]]], c.v_enu[six_quad])
        self.commands_applied += len(rows)

    # ---- fidelity switches ----------------------------------------------------------------------
    def _promote(self, r: int, ctx: RunContext, log: bool = True) -> None:
        q, aid = int(self.q_of[r]), str(self.ids[r])
        roll, pitch = self.pm.attitude(np.array([q]))
        self.js.spawn_in_flight(aid, self.pm.pos[q], self.pm.vel[q], float(self.pm.yaw[q]), float(roll[0]),
                                float(pitch[0]), Role(self.roles[r]), float(self.pm.integ_u(np.array([q]))[0]),
                                group=q % POOL_GROUPS)
        self.js.command(aid, self.pm.current_command(q))
        self.six[r], self.since[r] = True, self.t_s
        if log:
            self.promotions += 1
            ctx.events.emit(self.t_s, self.name, "promote", f"{aid}: point_mass -> jsbsim", uav=aid, fidelity="jsbsim")

    def _demote(self, r: int, ctx: RunContext, st: Any, k_of: dict[str, int]) -> None:
        """Row ``r`` back to its point mass; ``st`` is the 6-DOF fleet's state before this check's
        demotions and ``k_of`` its row per id (a removal does not change the others' states)."""
        q, aid = int(self.q_of[r]), str(self.ids[r])
        k = k_of[aid]
        self.pm.set_state(q, st.position[k], st.velocity[k], float(st.yaw[k]), float(st.roll[k]), float(st.pitch[k]))
        self.js.remove(aid)
        self.six[r], self.since[r] = False, self.t_s
        self.demotions += 1
        ctx.events.emit(self.t_s, self.name, "demote", f"{aid}: jsbsim -> point_mass", uav=aid, fidelity="point_mass")

    def _switch(self, ctx: RunContext) -> None:
        with ctx.part(f"{self.name}.fidelity_check"):
            pos, vel = self._exact_state()
            if self.missions is not None:  # deliveries end and start at the exact states of T
                self.missions.arrivals(self.t_s, pos[self.quad_rows])
            promote, demote = self.policy.decide(pos, vel, ~self.is_quad, self.six, self.since, self.t_s)
        if len(demote):
            st = self.js.state()
            k_of = {str(i): k for k, i in enumerate(st.ids)}
            for r in demote.tolist():
                self._demote(r, ctx, st, k_of)
        for r in promote.tolist():
            self._promote(r, ctx)
        if ctx.shard is not None and self.params.shard_balance.edge_step_m > 0.0:
            b = self.params.shard_balance
            ctx.shard.strips.rebalance(pos[:, 0], b.six_dof_weight * self.js.count_by_rank(), b.edge_step_m)

    # ---- stepping -------------------------------------------------------------------------------
    def tick(self, ctx: RunContext) -> None:
        if self._cpu_t0 is None:
            self._wall_t0, self._cpu_t0 = time.perf_counter(), time.process_time()
        if self.tick_count % self.pm_every == 0:
            with ctx.part(f"{self.name}.switch"):
                self._switch(ctx)
            with ctx.part(f"{self.name}.point_mass"):
                self.pm_prev_pos, self.pm_prev_vel = self.pm.pos.copy(), self.pm.vel.copy()
                pm_q = self.q_of[self.quad_rows[~self.six[self.quad_rows]]]
                if len(pm_q):
                    self._step_point_masses(ctx, pm_q)
        with ctx.part(f"{self.name}.jsbsim"):
            self.js.step(self.period)
        if self._pm_shares:
            self._take_point_masses(ctx.shard)
        self._check_finite()
        self.tick_count += 1
        self.t_s = self.tick_count * self.period
        self.six_dof_quad_s += float(np.count_nonzero(self.six[self.quad_rows])) * self.period

    def _step_point_masses(self, ctx: RunContext, pm_q: np.ndarray) -> None:
        """The point masses ``pm_q`` advance a point-mass period. A sharded run: each rank steps an
        equal share of them and posts the stepped states; they travel with the 6-DOF fleet's state
        exchange of this tick (``_take_point_masses``: nothing reads the point masses before). A
        row's step depends on its own state and targets only, and every rank holds every row's
        targets: the one-process values."""
        dt_s = self.pm_every * self.period
        if ctx.shard is None:
            self.pm.step(dt_s, pm_q)
            return
        comm = ctx.shard
        self._pm_shares = np.array_split(pm_q, comm.size)
        mine = self._pm_shares[comm.rank]
        self.pm.step(dt_s, mine, waypoints=False)
        comm.post(self.pm.state_rows(mine))

    def _take_point_masses(self, comm: Any) -> None:
        """The other ranks' stepped point masses (posted in ``_step_point_masses``), then the waypoints."""
        for r, rows in enumerate(self._pm_shares):
            if r != comm.rank:
                (st,) = comm.carried[r]
                self.pm.set_state_rows(rows, st)
        self._pm_shares = []
        self.pm.advance_waypoints()

    def _check_finite(self) -> None:
        if len(self.js.ids) and not self.js.all_finite():
            super()._check_finite()

    def _exact_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity of every row at a point-mass step boundary (no interpolation)."""
        pos, vel = np.zeros((len(self.ids), 3)), np.zeros((len(self.ids), 3))
        pos[self.quad_rows], vel[self.quad_rows] = self.pm.pos, self.pm.vel
        self._overlay_6dof(pos, vel)
        return pos, vel

    def _overlay_6dof(self, pos: np.ndarray, vel: np.ndarray, heading: np.ndarray | None = None) -> None:
        if not self.js.ids:
            return
        st = self.js.state()
        rows = [self.row[i] for i in self.js.ids]
        pos[rows], vel[rows] = st.position, st.velocity
        if heading is not None:
            heading[rows] = st.yaw

    def snapshot_part(self) -> WorldSnapshot:
        if not hasattr(self, "pm"):
            return WorldSnapshot()
        w = (self.tick_count % self.pm_every) / self.pm_every
        w = 1.0 if w == 0.0 else w  # at a step boundary the point masses are exactly at T + period
        n = len(self.ids)
        pos, vel, heading = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
        pos[self.quad_rows] = self.pm_prev_pos + w * (self.pm.pos - self.pm_prev_pos)
        vel[self.quad_rows] = self.pm_prev_vel + w * (self.pm.vel - self.pm_prev_vel)
        heading[self.quad_rows] = self.pm.yaw
        self._overlay_6dof(pos, vel, heading)
        return WorldSnapshot(t=self.t_s, ids=self.ids, kind=self.kind, role=self.roles, position=pos, velocity=vel,
                             heading=heading, size=self.size)

    def attitudes(self) -> dict[str, tuple[float, float]]:
        roll, pitch = self.pm.attitude()
        out = {str(self.ids[r]): (float(roll[q]), float(pitch[q])) for q, r in enumerate(self.quad_rows)}
        st = self.js.state()
        out.update({str(i): (float(a), float(b)) for i, a, b in zip(st.ids, st.roll, st.pitch, strict=True)})
        return out

    def six_dof_rows(self) -> np.ndarray:
        """Boolean per snapshot row: flying JSBSim 6-DOF now (for recorders: drawn differently)."""
        return self.six.copy()

    def overlays(self) -> dict[str, tuple[str, Any]]:
        """For the Rerun recorder: the aircraft flying 6-DOF now, marked on the ground below them
        (the point masses have no mark); the switches are the ``promote`` / ``demote`` events."""
        s = self.snapshot_part()
        return {"six_dof": ("points", s.position[self.six & self.is_quad, :2])}

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        sim_s = self.t_s
        cpu = time.process_time() - self._cpu_t0 if self._cpu_t0 is not None else float("nan")
        loads = self.js.loads
        if isinstance(self.js, PeerJSBSimFleet):  # every rank's CPU and loads (collectives)
            self.rank_cpu_s = ctx.shard.allgather(cpu)  # [s] per rank, from its first tick (diagnostics)
            cpu, loads = float(sum(self.rank_cpu_s)), self.js.total_loads()
        wall = time.perf_counter() - self._wall_t0 if self._wall_t0 is not None else float("nan")
        quad_s = len(self.quad_rows) * sim_s
        out = {"aircraft": len(self.aircraft), "air_commands": self.commands_applied,
               "rtf": sim_s / wall if wall > 0 else float("nan"),
               "six_dof_share": self.six_dof_quad_s / quad_s if quad_s > 0 else float("nan"),
               "promotions": self.promotions, "demotions": self.demotions, "jsbsim_loads": loads,
               "cpu_per_sim_s": cpu / sim_s if sim_s > 0 else float("nan"), "flight_hours": quad_s / 3600.0}
        return out


def _start_velocity(a: Any) -> tuple[float, float, float]:
    """A quad's initial ENU velocity: ``speed_mps`` along its yaw."""
    y = np.radians(a.yaw_deg)
    return (a.speed_mps * float(np.cos(y)), a.speed_mps * float(np.sin(y)), 0.0)
