"""STL-constrained overtaking on a two-lane, two-way road: modes, prediction and event-triggered MPC.

Road frame (see ``overtaking_mpc``): straight road along +x, own lane centre y = 0, oncoming lane centre
y = +lane_width; other vehicles are given by the x of their body centre and a signed speed along +x.

Modes (a ``HybridAutomaton``; every jump is an event in the run's ``EventLog``)::

    follow --(lead slow, cooldown over)--> decide --(a complete, safe pass plan exists)--> pass
    decide --(no safe plan)--> follow
    pass --(ahead of the lead by the front gap)--> return --(back in lane)--> follow
    pass --(re-plan infeasible while still behind the lead, i.e. the gap closed)--> abort
    abort --(back in lane behind the lead)--> follow
    abort --(ended up ahead of the lead after all)--> return

Event-triggered re-planning: after each solve the plan is kept and the inputs are played from it.
Each period the *remaining* plan is re-checked against the safety specification with fresh predictions
of the other vehicles (filterpy tracks); the STL library gives its space robustness [m] and right time
robustness [s].  The MPC re-solves only when either falls below its threshold, the ego left the plan,
the mode changed, or ``replan_max_interval_s`` elapsed.  ``replan="every_step"`` is the baseline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from corridor.controllers.overtaking.mpc import (
    FAR_M,
    MpcProblem,
    MpcSolution,
    OvertakingMpcParams,
    RoadGeometry,
    body_centre,
    cached_mpc,
    hull_half_extents,
    pass_guess,
    rollout_guess,
)
from corridor.events import EventLog
from corridor.modes import HybridAutomaton, Transition
from corridor.stl import as_formula, evaluate_spec
from corridor.vehicles.ground.bicycle import BicycleParams, clip_input
from corridor.vehicles.tracks.predictor import PredictorParams, RoadVehiclePredictor

MODES = ("follow", "decide", "pass", "return", "abort")
# (plan mode, new mode) pairs whose old plan is a good warm start (same homotopy class)
_WARM_COMPATIBLE = {(m, m) for m in MODES} | {("pass", "return"), ("abort", "return"), ("return", "follow"),
                                               ("abort", "follow")}


class OvertakingParams(BaseModel):
    """Everything the overtaking controller needs, with defaults; a scenario overrides what differs."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    desired_speed_mps: float = Field(26.0, gt=0.0)  # [m/s] cruise speed when the road is free
    pass_speed_margin_mps: float = Field(3.0, ge=0.0)  # [m/s] overtake only leads slower by this
    decide_range_m: float = Field(60.0, gt=0.0)  # [m] consider passing when the lead is this close
    decide_cooldown_s: float = Field(1.0, ge=0.0)  # [s] wait in follow between two decisions
    deadline_s: float = Field(12.0, gt=0.0)  # [s] the pass must be complete this long after commit
    replan: Literal["event", "every_step"] = "event"
    replan_max_interval_s: float = Field(1.0, gt=0.0)  # [s] time trigger of the event-triggered scheme
    space_threshold_m: float = -0.3  # [m] re-plan when the remaining plan's space robustness drops below
    time_loss_threshold_s: float = Field(0.6, gt=0.0)  # [s] ... or its right time robustness shrank by this
    track_tol_m: float = Field(0.3, gt=0.0)  # [m] ... or the ego left the plan by more than this
    decide_screen_m: float = Field(15.0, ge=0.0)  # [m] refuse without solving if the pass guess misses by more
    monitor_relax_m: float = Field(2.0, ge=0.0)  # [m] monitored spec = planning margins minus this
    prediction_sigmas: float = Field(1.0, ge=0.0)  # gaps are tightened by this many predicted std
    mpc: OvertakingMpcParams = OvertakingMpcParams()
    ego: BicycleParams = BicycleParams()
    road: RoadGeometry = RoadGeometry()
    predictor: PredictorParams = PredictorParams()

    @property
    def period_s(self) -> float:
        return self.mpc.dt_s

    @model_validator(mode="after")
    def _check(self) -> OvertakingParams:
        if self.replan_max_interval_s < self.mpc.dt_s:
            raise ValueError("replan_max_interval_s must be >= mpc.dt_s")
        return self


@dataclass(frozen=True)
class VehicleObs:
    """A sensed vehicle: id, body-centre x [m] and signed speed along +x [m/s]."""

    id: str
    x_m: float
    v_mps: float
    sensed: bool = True


@dataclass(frozen=True)
class OvertakingObservation:
    """What the controller sees each period (road frame)."""

    t_s: float
    ego: np.ndarray  # [4] (x rear axle [m], y [m], psi [rad], v [m/s])
    lead: VehicleObs | None  # nearest own-lane vehicle ahead
    oncoming: tuple[VehicleObs, ...] = ()
    followers: tuple[VehicleObs, ...] = ()  # own-lane vehicles behind (incl. a passed lead)


@dataclass(frozen=True)
class EgoCommand:
    accel_mps2: float
    steer_rad: float


@dataclass
class _Plan:
    t_s: float
    mode: str
    sol: MpcSolution
    problem: MpcProblem


@dataclass
class _Context:
    """What the mode guards read."""

    want_pass: bool = False
    plan_ok: bool = False
    passed: bool = False
    in_lane: bool = False
    behind_target: bool = True
    pass_failed: bool = False
    cooldown_over: bool = False
    extra: dict = field(default_factory=dict)


def safety_signals(states: np.ndarray, lead_x: np.ndarray, onc_x: np.ndarray, onc_v: np.ndarray,
                   ego: BicycleParams, road: RoadGeometry, lead_time_gap_s: float = 0.0,
                   oncoming_time_gap_s: float = 0.0) -> dict[str, np.ndarray]:
    """Signals [m] of the overtaking safety specification for an ego trajectory and others' positions.

    ``gap_lead``: bumper gap behind the lead minus ``lead_time_gap_s`` x ego speed; ``ahead_lead``:
    bumper gap ahead of it; ``lat_lead`` / ``lat_onc``: lateral clearance between the ego's box and a
    box centred in the own / oncoming lane (the ego's box is taken as its axis-aligned hull, so positive
    signals are conservative); ``gap_onc``: over the oncoming vehicles, the smallest of
    max(bumper gap before meeting minus ``oncoming_time_gap_s`` x closing speed, bumper gap after).
    With zero time gaps, the spec built by ``safety_spec`` with zero margins is box non-overlap.
    """
    xc, yc = body_centre(states, ego.wheelbase_m)
    v = states[:, 3]
    hx, hy = hull_half_extents(states[:, 2], ego)
    half_len, half_wid = hx + 0.5 * road.other_length_m, hy + 0.5 * road.other_width_m
    gap_onc = np.full_like(xc, 1.0e3)
    for xj, vj in zip(np.atleast_2d(onc_x), np.atleast_1d(onc_v)):
        before = xj - xc - half_len - oncoming_time_gap_s * np.maximum(v - vj, 0.0)
        gap_onc = np.minimum(gap_onc, np.maximum(before, xc - xj - half_len))
    clip = 1.0e3  # [m] absent vehicles sit at FAR_M; keep the signals finite and readable
    return {
        "gap_lead": np.minimum(lead_x - xc - half_len - lead_time_gap_s * v, clip),
        "ahead_lead": np.minimum(xc - lead_x - half_len, clip),
        "lat_lead": yc - half_wid,
        "lat_onc": road.lane_width_m - yc - half_wid,
        "gap_onc": np.minimum(gap_onc, clip),
    }


def box_clearance(states: np.ndarray, ego: BicycleParams, others_xy: np.ndarray, others_heading: np.ndarray,
                  others_size: np.ndarray) -> np.ndarray:
    """Smallest clearance [m] between the ego (each state) and any other vehicle, whoever it is.

    Boxes are taken as their axis-aligned hulls in the road frame (the ego's from ``hull_half_extents``,
    the others' from their heading and (length, width)); the clearance of a pair is the larger of the
    longitudinal and the lateral gap between the hulls, so it is > 0 iff an axis-aligned line separates
    them and <= 0 whenever the boxes touch (conservative: hulls contain the boxes). ``others_xy`` are
    body centres [M, 2] in the road frame; 1e3 when there is nobody.
    """
    xc, yc = body_centre(states, ego.wheelbase_m)
    hx, hy = hull_half_extents(states[:, 2], ego)
    if len(others_xy) == 0:
        return np.full_like(xc, 1.0e3)
    c, s = np.abs(np.cos(others_heading)), np.abs(np.sin(others_heading))
    ox = 0.5 * (others_size[:, 0] * c + others_size[:, 1] * s)  # [M] half extents of the others' hulls
    oy = 0.5 * (others_size[:, 0] * s + others_size[:, 1] * c)
    gap_x = np.abs(others_xy[None, :, 0] - xc[:, None]) - (hx[:, None] + ox[None, :])
    gap_y = np.abs(others_xy[None, :, 1] - yc[:, None]) - (hy[:, None] + oy[None, :])
    return np.minimum(np.maximum(gap_x, gap_y).min(axis=1), 1.0e3)


def safety_spec(lead_m: float = 0.0, ahead_m: float = 0.0, lat_m: float = 0.0, onc_m: float = 0.0,
                always: bool = True) -> str:
    """STL text of the safety specification over ``safety_signals`` (margins in metres)."""
    body = (f"((gap_lead > {lead_m:g} | ahead_lead > {ahead_m:g} | lat_lead > {lat_m:g}) & "
            f"(lat_onc > {lat_m:g} | gap_onc > {onc_m:g}))")
    return f"G{body}" if always else body


def _transitions() -> list[Transition]:
    return [
        Transition("follow", "decide", lambda c: c.want_pass and c.cooldown_over, "lead slow and close"),
        Transition("decide", "pass", lambda c: c.plan_ok, "safe complete pass plan"),
        Transition("decide", "follow", lambda c: not c.plan_ok, "no safe gap"),
        Transition("pass", "abort", lambda c: c.pass_failed and c.behind_target, "gap closed"),
        Transition("pass", "return", lambda c: c.passed, "ahead of the lead"),
        Transition("return", "follow", lambda c: c.in_lane, "back in lane"),
        Transition("abort", "return", lambda c: c.passed, "ahead of the lead after all"),
        Transition("abort", "follow", lambda c: c.in_lane and c.behind_target, "back behind the lead"),
    ]


class OvertakingController:
    """Overtaking controller: ``reset(rng)`` then ``step(obs) -> EgoCommand`` every ``period_s``.

    Attributes read by the engine and the metrics: ``mode``, ``replans`` (MPC solves), ``solve_times``
    [s] (with ``decision_solves`` flagging the go/no-go solves), ``replan_reasons`` (trigger counts),
    ``fallbacks`` (periods without a valid plan), ``events`` (the ``EventLog`` given or its own).
    """

    def __init__(self, params: OvertakingParams | None = None, events: EventLog | None = None,
                 name: str = "ego") -> None:
        self.params = params or OvertakingParams()
        self.events = events if events is not None else EventLog()
        p = self.params
        self.mpc = cached_mpc(p.mpc, p.ego, p.road)
        self.predictor = RoadVehiclePredictor(p.predictor)
        self.ha = HybridAutomaton(name, MODES, "follow", _transitions())
        relax = p.monitor_relax_m
        self._monitor = as_formula(safety_spec(
            lead_m=max(p.mpc.lead_standstill_gap_m - relax, 0.0), ahead_m=max(p.mpc.front_gap_m - relax, 0.0),
            lat_m=0.0, onc_m=max(p.mpc.oncoming_gap_m - relax, 0.0), always=False))
        self._ts = np.arange(p.mpc.horizon_steps + 1) * p.mpc.dt_s  # [s] knot offsets
        self.reset(np.random.default_rng(0))

    @property
    def period_s(self) -> float:
        return self.params.period_s

    @property
    def mode(self) -> str:
        return self.ha.mode

    def reset(self, rng: np.random.Generator) -> None:
        """Forget tracks, plan and counters (the controller itself draws no random numbers)."""
        self.rng = rng
        self.predictor.reset()
        self.ha.reset(0.0)
        self.plan: _Plan | None = None
        self.target_id: str | None = None
        self.deadline_t_s: float | None = None
        self.replans = 0
        self.solve_times: list[float] = []
        self.decision_solves: list[bool] = []  # parallel to solve_times: True for go/no-go decisions
        self.fallbacks = 0
        self.replan_reasons: dict[str, int] = {}
        self._last_u = np.zeros(2)
        self._follow_since_s = 0.0

    # ---- the step -----------------------------------------------------------------------------------
    def step(self, obs: OvertakingObservation) -> EgoCommand:
        """Sense, switch modes, re-plan if triggered, and play the plan's input for this period."""
        self._sense(obs)
        ctx = self._context(obs)
        self._advance(obs, ctx)
        u = self._act(obs, ctx)
        self._last_u = u
        return EgoCommand(float(u[0]), float(u[1]))

    def _sense(self, obs: OvertakingObservation) -> None:
        for veh in (obs.lead, *obs.oncoming, *obs.followers):
            if veh is not None and veh.sensed:
                self.predictor.update(obs.t_s, veh.id, veh.x_m, veh.v_mps)
        self.predictor.forget_stale(obs.t_s)

    def _target(self, obs: OvertakingObservation) -> str | None:
        """The vehicle being followed or overtaken: the lead, or while passing the one we committed to."""
        if self.mode in ("pass", "return", "abort") and self.target_id in self.predictor.ids:
            return self.target_id
        if obs.lead is not None and obs.lead.id in self.predictor.ids:
            return obs.lead.id
        return None

    def _context(self, obs: OvertakingObservation) -> _Context:
        p, ego = self.params, obs.ego
        xc, yc = (float(z[0]) for z in body_centre(ego, p.ego.wheelbase_m))
        half_len = 0.5 * (p.ego.length_m + p.road.other_length_m)
        ctx = _Context(in_lane=abs(yc) < 0.3 and abs(ego[2]) < 0.05)
        ctx.cooldown_over = self.mode != "follow" or obs.t_s - self._follow_since_s >= p.decide_cooldown_s
        tid = self._target(obs)
        if tid is None:
            ctx.passed = self.mode == "pass"
            ctx.behind_target = False
            return ctx
        x_t, v_t, _ = self.predictor.state(tid)
        ctx.passed = xc - x_t - half_len >= p.mpc.front_gap_m - 1.0
        ctx.behind_target = xc < x_t
        ctx.want_pass = (ctx.in_lane and x_t - xc < p.decide_range_m
                         and v_t < p.desired_speed_mps - p.pass_speed_margin_mps)
        return ctx

    def _advance(self, obs: OvertakingObservation, ctx: _Context) -> None:
        """Take mode transitions; the decision solve runs inside ``decide`` (an instantaneous mode)."""
        jumps = len(self.ha.history)
        self.ha.update(obs.t_s, ctx, self.events)
        if self.mode == "decide":
            ctx.plan_ok = self._decide(obs)
            self.ha.update(obs.t_s, ctx, self.events)
        if self.mode == "follow" and len(self.ha.history) > jumps:
            self._follow_since_s = obs.t_s
            self.target_id, self.deadline_t_s = None, None

    def _decide(self, obs: OvertakingObservation) -> bool:
        tid = self._target(obs)
        if tid is None:
            return False
        deadline = obs.t_s + self.params.deadline_s
        prob = self._problem(obs, "pass", tid, deadline)
        guess = self._pass_guess(obs, prob)
        if self.mpc.exact_robustness(guess[0], prob) < -self.params.decide_screen_m:
            return False  # even the aggressive guess misses by far: no solve needed
        sol = self._solve(prob, *guess, decision=True)
        if not sol.ok:
            return False
        self.plan = _Plan(obs.t_s, "pass", sol, prob)
        self.target_id, self.deadline_t_s = tid, deadline
        return True

    # ---- the optimisation problem -------------------------------------------------------------------
    def _problem(self, obs: OvertakingObservation, mode: str, tid: str | None,
                 deadline_t_s: float | None) -> MpcProblem:
        p, ts = self.params, self._ts
        k = p.prediction_sigmas
        lead_x, lead_sig = np.full(len(ts), FAR_M), np.zeros(len(ts))
        if tid is not None:
            lead_x = self.predictor.predict(tid, obs.t_s, ts)[0]
            lead_sig = k * self.predictor.position_std(tid, obs.t_s, ts)
        onc_x, onc_v, onc_sig = self._oncoming(obs)
        mask = np.zeros(len(ts))
        v_ref, y_ref = p.desired_speed_mps, 0.0
        if mode in ("pass", "return"):
            v_ref = p.mpc.speed_limit_mps
            due = (deadline_t_s if deadline_t_s is not None else np.inf) - obs.t_s
            mask[ts >= min(due, ts[-1]) - 1e-9] = 1.0
        elif mode == "abort" and tid is not None:
            v_ref = max(self.predictor.state(tid)[1] - 5.0, 0.0)
        y_max = 0.5 * (p.road.lane_width_m - p.ego.width_m) if mode == "follow" else np.inf
        return MpcProblem(np.asarray(obs.ego, dtype=float), self._last_u.copy(), lead_x, onc_x, onc_v,
                          v_ref, y_ref, mask, y_max, lead_sig, onc_sig)

    def _oncoming(self, obs: OvertakingObservation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted positions [M, N+1], speeds [M] and scaled position std [M, N+1] of the nearest
        oncoming vehicles not yet met."""
        p = self.params
        m, ts = p.mpc.max_oncoming, self._ts
        xc = float(body_centre(obs.ego, p.ego.wheelbase_m)[0][0])
        ids = [v.id for v in obs.oncoming if v.id in self.predictor.ids]
        ahead = sorted((self.predictor.state(i)[0], i) for i in ids if self.predictor.state(i)[0] > xc - 10.0)
        onc_x, onc_v, onc_sig = np.full((m, len(ts)), FAR_M), np.zeros(m), np.zeros((m, len(ts)))
        for j, (_, vid) in enumerate(ahead[:m]):
            onc_x[j], _ = self.predictor.predict(vid, obs.t_s, ts)
            onc_v[j] = self.predictor.state(vid)[1]
            onc_sig[j] = p.prediction_sigmas * self.predictor.position_std(vid, obs.t_s, ts)
        return onc_x, onc_v, onc_sig

    def _solve(self, prob: MpcProblem, guess_x: np.ndarray, guess_u: np.ndarray,
               decision: bool = False) -> MpcSolution:
        sol = self.mpc.solve(prob, guess_x, guess_u, decision)
        self.replans += 1
        self.solve_times.append(sol.solve_time_s)
        self.decision_solves.append(decision)
        return sol

    def _half_len(self) -> float:
        return 0.5 * (self.params.ego.length_m + self.params.road.other_length_m)

    def _pass_guess(self, obs: OvertakingObservation, prob: MpcProblem) -> tuple[np.ndarray, np.ndarray]:
        """Move out, pass at the speed limit, cut in once ahead of the lead with a margin."""
        return pass_guess(prob, self.mpc)

    def _abort_guess(self, obs: OvertakingObservation, prob: MpcProblem) -> tuple[np.ndarray, np.ndarray]:
        """Slow down in the current lane until behind the lead with a gap, then move back in."""
        p = self.params
        wb, keep_y = p.ego.wheelbase_m, float(obs.ego[1])

        def lateral(k: int, x: np.ndarray) -> float:
            need = self._half_len() + p.mpc.lead_standstill_gap_m + p.mpc.lead_time_gap_s * x[3] + 2.0
            return 0.0 if prob.lead_x[k] - (x[0] + 0.5 * wb) > need else keep_y

        return rollout_guess(prob.x0, lateral, lambda k, x: prob.v_ref, p.mpc, p.ego)

    def _plain_guess(self, prob: MpcProblem) -> tuple[np.ndarray, np.ndarray]:
        """Keep the own lane at the reference speed, but no closer to the lead than the time gap."""
        p = self.params
        wb, dt = p.ego.wheelbase_m, p.mpc.dt_s

        def speed(k: int, x: np.ndarray) -> float:
            gap = prob.lead_x[k] - (x[0] + 0.5 * wb) - self._half_len()
            want = p.mpc.lead_standstill_gap_m + p.mpc.lead_time_gap_s * x[3] + 2.0
            v_lead = (prob.lead_x[k + 1] - prob.lead_x[k]) / dt
            return float(np.clip(min(prob.v_ref, v_lead + 0.5 * (gap - want)), 0.0, p.mpc.speed_limit_mps))

        return rollout_guess(prob.x0, lambda k, x: 0.0, speed, p.mpc, p.ego)

    def _shifted_guess(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The current plan advanced by ``k`` knots, padded by holding its last input."""
        assert self.plan is not None
        xs, us = self.plan.sol.states, self.plan.sol.inputs
        n = len(us)
        k = min(k, n)
        pad_u = np.tile(np.array([0.0, 0.0]), (k, 1))
        new_u = np.vstack([us[k:], pad_u])
        new_x = np.empty_like(xs)
        new_x[: n + 1 - k] = xs[k:]
        for i in range(n + 1 - k, n + 1):
            new_x[i] = new_x[i - 1] + np.array([new_x[i - 1, 3] * self.params.mpc.dt_s, 0.0, 0.0, 0.0])
        return new_x, new_u

    # ---- acting and event-triggered re-planning -----------------------------------------------------
    def _act(self, obs: OvertakingObservation, ctx: _Context) -> np.ndarray:
        tid = self._target(obs)
        prob = self._problem(obs, self.mode, tid, self.deadline_t_s)
        reason = self._replan_reason(obs, prob)
        if reason is not None:
            self.replan_reasons[reason] = self.replan_reasons.get(reason, 0) + 1
            if not self._replan(obs, prob) and self.mode == "pass":
                ctx.pass_failed = True
                self.ha.update(obs.t_s, ctx, self.events)
                if self.mode == "abort":
                    self._replan(obs, self._problem(obs, "abort", tid, None))
        return self._plan_input(obs)

    def _replan(self, obs: OvertakingObservation, prob: MpcProblem) -> bool:
        """Solve from the best warm start; keep the new plan only if it is valid."""
        mode = self.mode
        if self.plan is not None and (self.plan.mode, mode) in _WARM_COMPATIBLE:
            guess = self._shifted_guess(self._plan_index(obs.t_s))
        elif mode == "abort":
            guess = self._abort_guess(obs, prob)
        elif mode == "pass":
            guess = self._pass_guess(obs, prob)
        else:
            guess = self._plain_guess(prob)
        sol = self._solve(prob, *guess)
        if not sol.ok and mode in ("follow", "return", "abort"):  # one cold retry from the plain guess
            cold = self._abort_guess(obs, prob) if mode == "abort" else self._plain_guess(prob)
            sol = self._solve(prob, *cold)
        if sol.ok:
            self.plan = _Plan(obs.t_s, mode, sol, prob)
        return sol.ok

    def _plan_index(self, t_s: float) -> int:
        assert self.plan is not None
        return int(round((t_s - self.plan.t_s) / self.params.mpc.dt_s))

    def _replan_reason(self, obs: OvertakingObservation, prob: MpcProblem) -> str | None:
        """Why the MPC must re-solve now, or None to keep playing the current plan."""
        p = self.params
        if p.replan == "every_step":
            return "every_step"
        if self.plan is None or self.plan.mode != self.mode:
            return "mode"
        k = self._plan_index(obs.t_s)
        if k * p.mpc.dt_s >= p.replan_max_interval_s - 1e-9 or k >= p.mpc.horizon_steps - 1:
            return "interval"
        if np.hypot(*(obs.ego[:2] - self.plan.sol.states[k, :2])) > p.track_tol_m:
            return "tracking"
        space, time_right = self.plan_robustness(obs.t_s, prob)
        if not space >= p.space_threshold_m:  # NaN (a prediction reads a missing value) re-plans too
            return "space"
        _, time_nominal = self.plan_robustness(obs.t_s, self.plan.problem, shift=k)
        if not time_right >= time_nominal - p.time_loss_threshold_s:
            return "time"
        return None

    def plan_robustness(self, t_s: float, prob: MpcProblem, shift: int = 0) -> tuple[float, float]:
        """Space [m] and right time [s] robustness of the remaining plan under the predictions of ``prob``.

        Space robustness is the minimum of the monitored spec's trace over the remaining plan; time
        robustness is the right time robustness at now (Donze & Maler): how long the currently true
        safety reasons (behind / beside / ahead, in lane / before / after meeting) keep holding.
        ``shift`` drops that many leading knots of ``prob`` (the plan's own predictions, made earlier).
        """
        assert self.plan is not None
        p = self.params
        states = self.plan.sol.states[self._plan_index(t_s):]
        m = len(states)
        lead_x, onc_x = prob.lead_x[shift:shift + m], prob.oncoming_x[:, shift:shift + m]
        sig = safety_signals(states, lead_x, onc_x, prob.oncoming_v, p.ego, p.road,
                             p.mpc.lead_time_gap_s, p.mpc.oncoming_time_gap_s)
        res = evaluate_spec(self._monitor, sig, p.mpc.dt_s)
        return float(np.min(res.trace)), res.time_right

    def _plan_input(self, obs: OvertakingObservation) -> np.ndarray:
        """The plan's input for this period, or an emergency input when no valid plan covers now."""
        if self.plan is not None:
            k = self._plan_index(obs.t_s)
            if 0 <= k < len(self.plan.sol.inputs):
                return clip_input(self.plan.sol.inputs[k], self.params.ego)
        return self._emergency(obs)

    def _emergency(self, obs: OvertakingObservation) -> np.ndarray:
        """Brake and steer back to the own lane (or hold the lane while alongside): the last resort."""
        p, ego = self.params, obs.ego
        self.fallbacks += 1
        self.events.emit(obs.t_s, self.ha.name, "fallback", "no valid plan: emergency input", mode=self.mode)
        y_goal = 0.0
        tid = self._target(obs)
        if tid is not None and ego[1] > 0.5 * p.road.lane_width_m:
            xc = float(body_centre(ego, p.ego.wheelbase_m)[0][0])
            if abs(self.predictor.state(tid)[0] - xc) < self._half_len() + 1.0:
                y_goal = p.road.lane_width_m  # alongside the lead: do not squeeze it
        v = max(float(ego[3]), 1.0)
        psi_des = float(np.clip(0.4 * (y_goal - ego[1]) / v, -0.12, 0.12))
        steer = np.arctan(1.5 * (psi_des - ego[2]) * p.ego.wheelbase_m / v)
        return clip_input(np.array([0.5 * p.ego.accel_min_mps2, steer]), p.ego)
