"""A pure-Python overtaking world for tests and benchmarks (no SUMO): the controller's null backend.

One ego (the shared kinematic bicycle, RK4), one slow lead in the own lane (constant speed plus an
Ornstein-Uhlenbeck speed noise; optionally a driver who speeds up when being overtaken) and a stream
of oncoming vehicles at random gaps and speeds, all in the road frame of ``overtaking_mpc``.  Sensing
is range-limited with Gaussian noise.  The run records everything the metrics of issue 5 need:
collisions (box overlap with vehicle lengths), outcome, gaps, the safety spec's space and time
robustness, re-plans and solve times.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.overtaking.controller import (
    OvertakingController,
    OvertakingObservation,
    OvertakingParams,
    VehicleObs,
    safety_signals,
    safety_spec,
)
from corridor.events import EventLog
from corridor.stl import evaluate_spec
from corridor.vehicles.ground.bicycle import rk4_step


class OvertakingWorldParams(BaseModel):
    """Randomised traffic of one run."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    duration_s: float = Field(40.0, gt=0.0)
    dt_s: float = Field(0.1, gt=0.0)  # [s] integration step (the controller runs every period_s)
    lead_speed_mps: tuple[float, float] = (13.0, 19.0)  # uniform range of the lead's mean speed
    lead_speed_noise_mps: float = Field(0.5, ge=0.0)  # [m/s] stationary std of the OU noise
    lead_noise_tau_s: float = Field(4.0, gt=0.0)  # [s] OU correlation time
    lead_gap_m: tuple[float, float] = (25.0, 45.0)  # [m] initial bumper gap ego -> lead
    lead_reacts_prob: float = Field(0.3, ge=0.0, le=1.0)  # lead speeds up when overtaken
    lead_reaction_mps: float = Field(4.0, ge=0.0)  # [m/s] by this much
    oncoming_count: int = Field(10, ge=0, le=200)
    oncoming_first_m: tuple[float, float] = (150.0, 700.0)  # [m] ahead of the ego at t = 0
    oncoming_gap_m: tuple[float, float] = (100.0, 700.0)  # [m] between consecutive oncoming vehicles
    oncoming_speed_mps: tuple[float, float] = (18.0, 26.0)  # magnitude, travelling towards -x
    sensor_range_m: float = Field(500.0, gt=0.0)
    sensor_pos_noise_m: float = Field(0.3, ge=0.0)
    sensor_speed_noise_mps: float = Field(0.2, ge=0.0)


@dataclass
class OvertakingRun:
    """Outcome and metrics of one run."""

    seed: int
    outcome: str  # "passed" | "aborted" | "stayed"
    final_mode: str
    collided: bool
    completion_time_s: float  # commit -> back in lane ahead of the lead (nan unless passed)
    min_gap_lead_m: float  # [m] smallest bumper gap to the lead while sharing its lane
    min_gap_oncoming_m: float  # [m] smallest bumper gap to an oncoming car while sharing its lane
    space_robustness_m: float  # of the physical safety spec on the whole run
    time_robustness_s: float
    replans: int
    steps: int
    solve_times_s: list[float]
    decision_solves: list[bool]
    replan_reasons: dict[str, int]
    fallbacks: int
    events: EventLog
    ego_states: np.ndarray = field(repr=False)


@dataclass
class _Traffic:
    lead_x: float
    lead_v: float
    lead_mean_v: float
    lead_base_v: float
    lead_noise: float
    lead_reacts: bool
    onc_x: np.ndarray
    onc_v: np.ndarray  # signed (< 0)


def _spawn(wp: OvertakingWorldParams, rng: np.random.Generator, ego_x: float) -> _Traffic:
    v_lead = rng.uniform(*wp.lead_speed_mps)
    gaps = rng.uniform(*wp.oncoming_gap_m, size=max(wp.oncoming_count - 1, 0))
    first = ego_x + rng.uniform(*wp.oncoming_first_m)
    onc_x = first + np.concatenate([[0.0], np.cumsum(gaps)])[: wp.oncoming_count]
    onc_v = -rng.uniform(*wp.oncoming_speed_mps, size=wp.oncoming_count)
    return _Traffic(ego_x + 4.5 + rng.uniform(*wp.lead_gap_m), v_lead, v_lead, v_lead, 0.0,
                    bool(rng.random() < wp.lead_reacts_prob), onc_x, onc_v)


def _sense(wp: OvertakingWorldParams, rng: np.random.Generator, tr: _Traffic, t: float, ego: np.ndarray,
           lead_id: str | None) -> OvertakingObservation:
    def obs(vid: str, x: float, v: float) -> VehicleObs:
        return VehicleObs(vid, x + rng.normal(0.0, wp.sensor_pos_noise_m),
                          v + rng.normal(0.0, wp.sensor_speed_noise_mps))

    in_range = np.abs(tr.onc_x - ego[0]) < wp.sensor_range_m
    oncoming = tuple(obs(f"onc{j}", tr.onc_x[j], tr.onc_v[j]) for j in np.flatnonzero(in_range))
    lead_ahead = tr.lead_x > ego[0] + 1.35
    lead = obs("lead", tr.lead_x, tr.lead_v) if lead_ahead else None
    followers = () if lead_ahead else (obs("lead", tr.lead_x, tr.lead_v),)
    return OvertakingObservation(t, ego.copy(), lead, oncoming, followers)


def _advance_traffic(wp: OvertakingWorldParams, rng: np.random.Generator, tr: _Traffic, ego: np.ndarray,
                     dt: float) -> None:
    sigma = wp.lead_speed_noise_mps * np.sqrt(2.0 * dt / wp.lead_noise_tau_s)
    tr.lead_noise += -tr.lead_noise * dt / wp.lead_noise_tau_s + sigma * rng.standard_normal()
    target = tr.lead_mean_v + tr.lead_noise
    if tr.lead_reacts and ego[1] > 1.0 and abs(ego[0] - tr.lead_x) < 30.0:
        tr.lead_mean_v = min(tr.lead_mean_v + 1.0 * dt, tr.lead_base_v + wp.lead_reaction_mps)
    tr.lead_v += float(np.clip(target - tr.lead_v, -2.0 * dt, 2.0 * dt))
    tr.lead_x += tr.lead_v * dt
    tr.onc_x = tr.onc_x + tr.onc_v * dt


def boxes_overlap(ego: np.ndarray, wheelbase_m: float, ego_len_m: float, ego_wid_m: float,
                  other_x: np.ndarray, other_y: float, other_len_m: float, other_wid_m: float) -> np.ndarray:
    """Exact overlap (separating axis test) of the ego's oriented box with road-aligned boxes."""
    c, s = np.cos(ego[2]), np.sin(ego[2])
    dx = np.asarray(other_x, dtype=float) - (ego[0] + 0.5 * wheelbase_m * c)
    dy = other_y - (ego[1] + 0.5 * wheelbase_m * s)
    hl, hw, a, b = 0.5 * ego_len_m, 0.5 * ego_wid_m, 0.5 * other_len_m, 0.5 * other_wid_m
    sep_x = np.abs(dx) > a + hl * abs(c) + hw * abs(s)
    sep_y = np.abs(dy) > b + hl * abs(s) + hw * abs(c)
    sep_u = np.abs(dx * c + dy * s) > hl + a * abs(c) + b * abs(s)
    sep_w = np.abs(-dx * s + dy * c) > hw + a * abs(s) + b * abs(c)
    return ~(sep_x | sep_y | sep_u | sep_w)

def run_overtaking(seed: int, params: OvertakingParams | None = None,
                   world: OvertakingWorldParams | None = None) -> OvertakingRun:
    """Simulate one randomised run with the overtaking controller; deterministic given ``seed``."""
    params, wp = params or OvertakingParams(), world or OvertakingWorldParams()
    ss = np.random.SeedSequence(seed)
    rng_traffic, rng_sensor, rng_ctrl = (np.random.default_rng(s) for s in ss.spawn(3))
    events = EventLog()
    ctrl = OvertakingController(params, events)
    ctrl.reset(rng_ctrl)
    tr = _spawn(wp, rng_traffic, 0.0)
    ego = np.array([0.0, 0.0, 0.0, tr.lead_v])
    every = max(int(round(params.period_s / wp.dt_s)), 1)
    steps = int(round(wp.duration_s / wp.dt_s))
    log_ego, log_lead, log_onc = [ego.copy()], [tr.lead_x], [tr.onc_x.copy()]
    collided, u = False, np.zeros(2)
    for i in range(steps):
        if i % every == 0:
            cmd = ctrl.step(_sense(wp, rng_sensor, tr, i * wp.dt_s, ego, "lead"))
            u = np.array([cmd.accel_mps2, cmd.steer_rad])
        ego = rk4_step(ego, u, wp.dt_s, params.ego)
        ego[3] = max(ego[3], 0.0)
        _advance_traffic(wp, rng_traffic, tr, ego, wp.dt_s)
        collided |= _collides(ego, tr, params)
        log_ego.append(ego.copy())
        log_lead.append(tr.lead_x)
        log_onc.append(tr.onc_x.copy())
    return _summarise(seed, ctrl, events, params, wp, np.array(log_ego), np.array(log_lead),
                      np.array(log_onc).T, tr.onc_v, collided)


def _collides(ego: np.ndarray, tr: _Traffic, p: OvertakingParams) -> bool:
    e, r = p.ego, p.road
    hit_lead = boxes_overlap(ego, e.wheelbase_m, e.length_m, e.width_m, np.array([tr.lead_x]), 0.0,
                             r.other_length_m, r.other_width_m)
    hit_onc = boxes_overlap(ego, e.wheelbase_m, e.length_m, e.width_m, tr.onc_x, r.lane_width_m,
                            r.other_length_m, r.other_width_m)
    return bool(hit_lead.any() or hit_onc.any())


def _summarise(seed: int, ctrl: OvertakingController, events: EventLog, p: OvertakingParams,
               wp: OvertakingWorldParams, ego: np.ndarray, lead_x: np.ndarray, onc_x: np.ndarray,
               onc_v: np.ndarray, collided: bool) -> OvertakingRun:
    sig = safety_signals(ego, lead_x, onc_x, onc_v, p.ego, p.road)
    spec = evaluate_spec(safety_spec(), sig, wp.dt_s)
    shared_lead = sig["lat_lead"] <= 0.0
    shared_onc = sig["lat_onc"] <= 0.0
    gap_lead = np.maximum(sig["gap_lead"], sig["ahead_lead"])
    jumps = [(e.t, e.data["src"], e.data["dst"]) for e in events.of_kind("mode")]
    commit = [t for t, s, d in jumps if d == "pass"]
    done = [t for t, s, d in jumps if s == "return" and d == "follow"]
    aborted = any(d == "abort" for _, _, d in jumps)
    outcome = "passed" if done else ("aborted" if aborted else "stayed")
    completion = done[0] - commit[-1] if done and commit else float("nan")
    return OvertakingRun(
        seed=seed, outcome=outcome, final_mode=ctrl.mode, collided=collided, completion_time_s=completion,
        min_gap_lead_m=float(gap_lead[shared_lead].min()) if shared_lead.any() else float("inf"),
        min_gap_oncoming_m=float(sig["gap_onc"][shared_onc].min()) if shared_onc.any() else float("inf"),
        space_robustness_m=spec.space, time_robustness_s=spec.time, replans=ctrl.replans,
        steps=int(round(wp.duration_s / p.period_s)), solve_times_s=list(ctrl.solve_times), decision_solves=list(ctrl.decision_solves),
        replan_reasons=dict(ctrl.replan_reasons),
        fallbacks=ctrl.fallbacks, events=events, ego_states=ego)
