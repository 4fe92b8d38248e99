"""UAV avoidance controllers for the engine: ``uav_none``, ``potential_field``, ``control_tube``.

Each controller governs the quadcopters of the air backend that have a goal (or the ``uavs`` listed
in its params). At every decision (default period 0.2 s) it builds, per governed UAV, an
``AvoidanceObservation`` from

- the UAV's *own* state (its row of the world snapshot: the aircraft knows where it is), and
- the other aircraft ONLY as the MAVLink link delivered and tracked them (``AirLink.picture``),

steps the method and puts ``AircraftCommand(id, autopilot.VelocityCommand)`` on the bus; the air
backend's quad cascade flies it. ``uav_none`` flies straight to the goal at cruise speed and never
looks at the others (the baseline that shows the encounters are real conflicts). Each UAV's speed
limit is its cruise speed, so an avoiding UAV never outruns its nominal plan.

Relevance range: each controller passes the link a range beyond which a reporting UAV cannot
matter to it within its horizon (``Relevance``, derived from the method's speed bound, horizon,
separation radius and ``relevance_margin_m``); the link neither fuses nor tracks UAVs outside it, as
a real ADS-B / Remote-ID consumer filters by range. The potential field's UAV term has bounded
support (zero beyond ``f >= uav_cutoff_m``) and the control tube keeps only intruders whose tube
can reach the ego within its horizon, so the aircraft left out are exactly ones the method would
have ignored (the margin covers the track's uncertainty radius and the report's age).

Modes: every UAV is ``cruise`` or ``avoid`` (the method's ``avoiding`` flag); each transition is a
``mode`` event, so the Rerun timeline shows when and why a UAV deviated. Two guards sit between a
method and the autopilot: a non-finite command becomes "hold position" (a ``fallback`` event), and a
vertical geofence (``min_alt_m`` .. ``max_alt_m``) limits the climb/descent the method may command.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.uav.control_tube import ControlTubeParams
from corridor.controllers.uav.models import AvoidanceObservation
from corridor.controllers.uav.models import VelocityCommand as MethodCommand
from corridor.controllers.uav.potential_field import PotentialFieldParams
from corridor.engine import Controller, Metric, Need, RunContext
from corridor.vehicles.air.autopilot import VelocityCommand
from corridor.vehicles.air.backend import AirBackend, AircraftCommand, air_rows
from corridor.vehicles.mavlink.air_link import AirLink, Relevance


class UavAvoidanceParams(BaseModel):
    """Shared by the three controllers so that a ``sweep`` can swap ``type`` alone."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    backend: str = "air"  # air backend (aircraft list, goals, cruise speeds)
    link: str = "link"  # MAVLink link component (the tracked picture)
    uavs: list[str] | None = None  # governed UAVs; None = every non-piloted aircraft with a goal
    goal_gain_per_s: float = Field(0.5, gt=0.0)  # [1/s] uav_none: v = sat(k (goal - x), cruise)
    min_alt_m: float = 15.0  # [m] vertical geofence: no descent command below it (ENU up)
    max_alt_m: float = 150.0  # [m] no climb command above it
    fence_gain_per_s: float = Field(0.5, gt=0.0)  # [1/s] vertical speed allowed = k x distance to fence
    # [m] slack of the relevance range (track sigma, report age, time to the next decision) on top of
    # the method's own reach; None: every reporting UAV may be tracked (nearest link max_tracks)
    relevance_margin_m: float | None = Field(15.0, ge=0.0)
    # sector patrol (the air backend's ``patrol`` fleet): the goal is a point this far ahead along the
    # UAV's sector arc, turning back at the sector ends; None: the fixed goal of each UAV
    patrol_lookahead_m: float | None = Field(None, gt=0.0)
    # [m] a patrolling UAV turns back this far (along the arc) before its sector end: a tracker that
    # converges to its goal without overshoot (the control tube) approaches the clipped goal at the
    # end asymptotically and would never reach the end itself (it hovered there for the rest of the run)
    patrol_turn_m: float = Field(10.0, gt=0.0)
    # the methods' own parameters, typed so that a misspelt one fails at scenario load (not in every run);
    # control_tube.period_s defaults to the controller's period (see ControlTubeController.build_methods)
    potential_field: PotentialFieldParams = Field(default_factory=PotentialFieldParams)
    control_tube: ControlTubeParams = Field(default_factory=ControlTubeParams)


def patrol_target(angle_rad: float, a0: float, a1: float, direction: float, lookahead_rad: float,
                  turn_rad: float) -> tuple[float, float]:
    """(goal angle [rad], patrol direction +-1) of a UAV at polar ``angle_rad`` patrolling the sector
    [a0, a1]: the direction reverses within ``turn_rad`` of the end it is heading for, and the goal is
    ``lookahead_rad`` ahead, clipped to the sector."""
    theta = a0 + float(np.mod(angle_rad - a0, 2.0 * np.pi))
    if theta > a1 + 0.5 * (2.0 * np.pi - (a1 - a0)):  # behind the start: unwrap backwards
        theta -= 2.0 * np.pi
    d = direction
    if (d > 0 and theta >= a1 - turn_rad) or (d < 0 and theta <= a0 + turn_rad):
        d = -d
    return float(np.clip(theta + d * lookahead_rad, a0, a1)), d


class _UavController(Controller):
    """Engine glue common to the three methods: observe via the link, step per UAV, emit commands."""

    metrics: ClassVar[tuple[Metric, ...]] = (
        Metric('avoid_share', '1',
               'Share of the UAV decisions that avoided (not straight to the goal).'),
        Metric('avoid_fallbacks', '1',
               'Decisions that fell back to the safe command.'),
    )
    Params = UavAvoidanceParams
    needs: ClassVar[dict[str, Need]] = {"backend": Need(role="air", name_at="params.backend"),
                                        "link": Need(role="air_link", name_at="params.link")}
    period = 0.2  # [s] (period_source None: this constant, unless the scenario gives `period:`)
    backend: AirBackend
    link: AirLink
    uses_link = True  # False: the method never looks at the others (uav_none)

    def __init__(self, name: str, params: UavAvoidanceParams, scenario: Any) -> None:
        super().__init__(name)
        self.params = params
        self.uav_ids: list[str] = []
        self.goal: dict[str, np.ndarray] = {}
        self.cruise: dict[str, float] = {}
        self.mode: dict[str, str] = {}
        self.avoid_decisions = 0
        self.decisions = 0
        self.fallbacks = 0

    def setup(self, ctx: RunContext) -> None:
        backend = self.backend
        specs = {a.id: a for a in backend.aircraft}
        ids = self.params.uavs or [a.id for a in backend.aircraft if a.goal_enu is not None and not a.is_piloted]
        for uid in ids:
            self.goal[uid] = np.asarray(specs[uid].goal_enu, float)
            self.cruise[uid] = float(specs[uid].cruise_speed_mps)
            self.mode[uid] = "cruise"
        self.uav_ids = list(ids)
        self.patrol = self._patrol_sectors()
        self.patrol_dir = {uid: 1.0 for uid in self.patrol}
        self.build_methods()
        super().setup(ctx)

    def _patrol_sectors(self) -> dict[str, tuple[float, float, float, float]]:
        """uid -> (ring radius [m], sector start, end [rad], altitude [m]) when patrolling."""
        spec = getattr(self.backend.params, "patrol", None)
        if self.params.patrol_lookahead_m is None or spec is None:
            return {}
        out = {}
        for j in range(spec.n):
            uid = f"patrol_{j}"
            if uid in self.goal:
                out[uid] = (spec.ring_radius_m, *spec.sector(j), spec.alt(j))
        return out

    def patrol_goal(self, uid: str, pos: np.ndarray) -> np.ndarray:
        """The point ``patrol_lookahead_m`` ahead of the UAV's projection on its sector arc, in its
        current patrol direction (reversed at a sector end, a ``patrol_turn`` event)."""
        r, a0, a1, alt = self.patrol[uid]
        target, self.patrol_dir[uid] = patrol_target(float(np.arctan2(pos[1], pos[0])), a0, a1, self.patrol_dir[uid],
                                                     self.params.patrol_lookahead_m / r, self.params.patrol_turn_m / r)
        return np.array([r * np.cos(target), r * np.sin(target), alt])

    def build_methods(self) -> None:
        """Create the per-UAV method objects (after goals and cruise speeds are known)."""

    def observe(self, ctx: RunContext) -> dict[str, AvoidanceObservation]:
        s = ctx.snapshot
        index = air_rows(s)
        uids = [u for u in self.uav_ids if u in index]
        rows = [index[u] for u in uids]
        pos, vel = s.position[rows], s.velocity[rows]
        if self.uses_link:  # every governed UAV's picture in one stacked pass of the link's trackers
            rel = [self.relevance(u, vel[k]) for k, u in enumerate(uids)]
            pictures = self.link.pictures(uids, ctx.t, pos, rel)
        else:
            pictures = [()] * len(uids)
        goals = [self.patrol_goal(u, pos[k]) if u in self.patrol else self.goal[u] for k, u in enumerate(uids)]
        return {u: AvoidanceObservation(ctx.t, pos[k].copy(), vel[k].copy(), goals[k], pictures[k])
                for k, u in enumerate(uids)}

    def relevance(self, uid: str, own_vel: np.ndarray) -> Relevance | None:
        """Range beyond which a reporting UAV cannot matter to ``uid``'s method (None: no range)."""
        return None

    def decide(self, uid: str, obs: AvoidanceObservation) -> MethodCommand:
        raise NotImplementedError

    def decide_all(self, obs: dict[str, AvoidanceObservation]) -> dict[str, MethodCommand]:
        """Every governed UAV's method command (a method may override this to work fleet-wide)."""
        return {uid: self.decide(uid, o) for uid, o in obs.items()}

    def step(self, obs: dict[str, AvoidanceObservation]) -> list[Any]:
        out: list[Any] = []
        cmds = self.decide_all(obs)
        for uid, o in obs.items():
            cmd = cmds[uid]
            self._track_mode(uid, o.t, cmd.avoiding)
            v = np.asarray(cmd.vel_mps, float)
            if not np.all(np.isfinite(v)):  # a method failure must never reach the autopilot
                self.fallbacks += 1
                self.events.emit(o.t, self.name, "fallback", f"{uid}: non-finite command, hold position", uav=uid)
                v = np.zeros(3)
            v = self.fence(o.own_pos, v)
            out.append(AircraftCommand(uid, VelocityCommand(tuple(float(x) for x in v))))
        return out

    def fence(self, pos: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Vertical geofence: climb/descent limited to k x the distance to the ceiling/floor, so the
        avoidance's vertical escape never flies a UAV into the ground (or above the ceiling)."""
        p = self.params
        lo = p.fence_gain_per_s * (p.min_alt_m - pos[2])
        hi = p.fence_gain_per_s * (p.max_alt_m - pos[2])
        out = v.copy()
        out[2] = float(np.clip(v[2], lo, hi))
        return out

    def _track_mode(self, uid: str, t: float, avoiding: bool) -> None:
        self.decisions += 1
        self.avoid_decisions += int(avoiding)
        new = "avoid" if avoiding else "cruise"
        if new != self.mode[uid]:
            self.events.emit(t, self.name, "mode", f"{uid}: {self.mode[uid]} -> {new}", uav=uid, mode=new)
            self.mode[uid] = new

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        return {"avoid_share": self.avoid_decisions / max(self.decisions, 1), "avoid_fallbacks": self.fallbacks}


def _saturated_goal_velocity(obs: AvoidanceObservation, gain: float, speed: float) -> np.ndarray:
    """v = k (goal - x), horizontal norm clipped to ``speed``, vertical to 2 m/s."""
    v = gain * (obs.goal - obs.own_pos)
    h = float(np.linalg.norm(v[:2]))
    if h > speed:
        v[:2] *= speed / h
    v[2] = float(np.clip(v[2], -2.0, 2.0))
    return v


class UavNone(_UavController):
    """No avoidance: straight to the goal at cruise speed (the others are never looked at)."""

    uses_link = False

    def decide(self, uid: str, obs: AvoidanceObservation) -> MethodCommand:
        v = _saturated_goal_velocity(obs, self.params.goal_gain_per_s, self.cruise[uid])
        return MethodCommand(obs.t, v, False)


class PotentialFieldController(_UavController):
    """``controllers.potential_field.PotentialFieldAvoidance`` per UAV (speed limit = its cruise)."""

    def build_methods(self) -> None:
        from corridor.controllers.uav.potential_field import PotentialFieldAvoidance

        base = self.params.potential_field
        self.methods = {uid: PotentialFieldAvoidance(base.model_copy(update={"max_speed_h_mps": self.cruise[uid]}))
                        for uid in self.uav_ids}

    def relevance(self, uid: str, own_vel: np.ndarray) -> Relevance | None:
        """The UAV term is zero once f = d - r_safe - sigma - tau * closing >= f0, and the closing
        speed is at most |v_own| + |v_other|: beyond r_safe + f0 + tau |v_own| + margin + tau |v_other|
        a UAV exerts no force (the margin covers sigma and the report's age)."""
        p, margin = self.methods[uid].params, self.params.relevance_margin_m
        if margin is None:
            return None
        if p.uav_cutoff_m is None:  # 1/f tail: everything within the influence radius counts
            return Relevance(p.influence_m + margin, 0.0)
        v_own = max(float(np.linalg.norm(own_vel)), float(np.hypot(p.max_speed_h_mps, p.max_climb_mps)))
        base = p.uav_safety_radius_m + p.uav_cutoff_m + p.uav_lookahead_s * v_own + margin
        return Relevance(min(base, p.influence_m + margin), p.uav_lookahead_s)

    def decide(self, uid: str, obs: AvoidanceObservation) -> MethodCommand:
        return self.methods[uid].step(obs)


class ControlTubeController(_UavController):
    """``controllers.control_tube.ControlTubeAvoidance`` per UAV (one CasADi QP each, warm plans)."""

    metrics: ClassVar[tuple[Metric, ...]] = _UavController.metrics + (
        Metric('tube_infeasible_steps', '1',
               'Steps whose QP had no feasible solution.'),
        Metric('tube_solver_failures', '1',
               'Steps whose QP solver failed.'),
        Metric('tube_unconstrained_share', '1',
               'Share of the steps whose unconstrained optimum was feasible (no solver call).'),
        Metric('tube_solve_ms_mean', 'ms',
               'Mean QP solve time (wall clock).'),
    )

    def build_methods(self) -> None:
        from corridor.controllers.uav.control_tube import ControlTubeAvoidance
        from corridor.vehicles.air.jsbsim_fleet import quiet_fds

        base = ControlTubeParams(**{"period_s": self.period, **self.params.control_tube.model_dump(exclude_unset=True)})
        self._quiet = quiet_fds
        self.methods = {uid: ControlTubeAvoidance(base.model_copy(update={"max_speed_h_mps": self.cruise[uid]}))
                        for uid in self.uav_ids}
        self._first = True

    def relevance(self, uid: str, own_vel: np.ndarray) -> Relevance | None:
        """The tube's own reachability test (``ControlTubeAvoidance._relevant``): an intruder
        matters when its tube can reach the ego within the horizon T, i.e. closer than
        r0 + r_safe + a_max T^2 / 2 + (v_ego + |v|) T + 10 m; the margin covers sigma and the age."""
        m, margin = self.methods[uid], self.params.relevance_margin_m
        if margin is None:
            return None
        p = m.params
        horizon = p.n_steps * p.step_s  # [s]
        base = (p.uav_size_m + p.uav_safety_radius_m + 0.5 * p.uav_accel_mps2 * horizon**2
                + m._ego_speed_bound(np.asarray(own_vel, float)) * horizon + 10.0 + margin)
        return Relevance(base, horizon)

    def decide(self, uid: str, obs: AvoidanceObservation) -> MethodCommand:
        return self.decide_all({uid: obs})[uid]

    def decide_all(self, obs: dict[str, AvoidanceObservation]) -> dict[str, MethodCommand]:
        """One ``step_many`` over the fleet: each UAV keeps its own plan and QP, the tube rows of all
        of them are built in one vectorised pass."""
        from corridor.controllers.uav.control_tube import step_many

        uids = list(obs)
        methods, observations = [self.methods[u] for u in uids], [obs[u] for u in uids]
        if self._first and uids:  # qpOASES prints a licence banner on its first solve in a process
            self._first = False
            with self._quiet():
                return dict(zip(uids, step_many(methods, observations), strict=True))
        return dict(zip(uids, step_many(methods, observations), strict=True))

    def finish(self, ctx: RunContext) -> dict[str, Any]:
        ms = list(self.methods.values())
        times = [t for m in ms for t in m.solve_times_s]
        return {**super().finish(ctx),
                "tube_infeasible_steps": sum(m.infeasible_steps for m in ms),
                "tube_solver_failures": sum(m.solver_failures for m in ms),
                # steps whose unconstrained optimum was feasible (no solver call, see control_tube)
                "tube_unconstrained_share": sum(m.unconstrained_steps for m in ms) / max(sum(m.steps for m in ms), 1),
                "tube_solve_ms_mean": 1e3 * float(np.mean(times)) if times else float("nan")}
