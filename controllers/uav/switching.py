"""When a UAV avoids: the mission <-> avoid <-> return automaton and its named boundaries.

Every governed UAV owns one ``HybridAutomaton``::

    mission --avoid_enter--> avoid{clear, deflect} --avoid_exit--> return --return_done--> mission
                                                                   return --avoid_enter--> avoid

- ``mission``: the method flies the UAV to its goal and is shown *no* intruder.
- ``avoid``: the method sees the tracked picture; its sub-modes follow the method's own flag
  (``deflect`` when its command departs from the goal-seeking one, ``clear`` otherwise).
- ``return``: the threat is over; the method (again shown no intruder) turns the UAV back onto its
  goal course, until the velocity points at the goal within ``return_done.heading_deg``.

The boundaries are conflict probes on the tracked picture (straight-line relative motion, as
BlueSky's state-based conflict detection):

    d_min,i(T) = min_{0 <= t <= T} |r_i + v_i t|          (r, v: intruder relative to the UAV)
    g_enter(x; ttc_s, dist_m) = max_i (dist_m - d_min,i(ttc_s)) / dist_m      (-1 with no intruder)
    g_exit(x; ttc_s, dist_m)  = -g_enter(x; ttc_s, dist_m)
    g_return(x; heading_deg)  = cos(angle(v_h, goal - x)_h) - cos(heading_deg)

so ``avoid`` starts when an intruder is, or will be within ``ttc_s``, closer than ``dist_m``, and
ends when none is (the exit parameters may differ: hysteresis).  The defaults (``dist_m`` 10 km,
beyond the MAVLink range) make every tracked aircraft a threat: the method always sees the whole
picture, which is the behaviour before the boundaries existed (same rows).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.controllers.uav.models import AvoidanceObservation
from corridor.modes import Boundary, HybridAutomaton, Mode, SwitchingParams, Transition

MODES = ("mission", "avoid", "clear", "deflect", "return")


class ProbeTheta(BaseModel):
    """Parameters of a conflict probe boundary."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    ttc_s: float = Field(60.0, ge=0.0)  # [s] look-ahead of the straight-line prediction
    dist_m: float = Field(10000.0, gt=0.0)  # [m] predicted range below which an intruder is a threat


class ReturnTheta(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    heading_deg: float = Field(10.0, gt=0.0, le=180.0)  # [deg] back on course when within this of the goal


class UavBoundaries(BaseModel):
    """The named boundaries of the UAV automaton (scenario: ``controllers.X.params.boundaries``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    avoid_enter: ProbeTheta = Field(default_factory=ProbeTheta)
    avoid_exit: ProbeTheta = Field(default_factory=ProbeTheta)
    return_done: ReturnTheta = Field(default_factory=ReturnTheta)

    # hysteresis pair, follower -> (anchor, +1: follower's theta >= anchor's): avoid at d_min(ttc_e) <=
    # dist_e, stop at d_min(ttc_x) >= dist_x; with dist_x < dist_e (or ttc_x < ttc_e) both hold in a band.
    # The pair shares its stochastic draw (corridor.modes.Boundary.draws_with); --learn keeps the order.
    hysteresis: ClassVar[dict[str, tuple[str, int]]] = {"avoid_exit": ("avoid_enter", 1)}


class SwitchState:
    """What the guards read: the observation and the method's last deflection flag."""

    def __init__(self, obs: AvoidanceObservation, deflecting: bool) -> None:
        self.obs = obs
        self.deflecting = deflecting


def min_predicted_range(obs: AvoidanceObservation, horizon_s: float) -> np.ndarray:
    """d_min,i over [0, horizon_s] [m] of every tracked intruder (straight-line relative motion)."""
    if not obs.others:
        return np.zeros(0)
    r = np.array([o.pos for o in obs.others], float).reshape(-1, 3) - obs.own_pos
    v = np.array([o.vel for o in obs.others], float).reshape(-1, 3) - obs.own_vel
    vv = np.einsum("kd,kd->k", v, v)
    t = np.clip(-np.einsum("kd,kd->k", r, v) / np.maximum(vv, 1e-12), 0.0, horizon_s)
    closest = r + v * t[:, None]
    return np.sqrt(np.einsum("kd,kd->k", closest, closest))


def threat_margin(x: SwitchState, theta: dict[str, float]) -> float:
    """g_enter: > 0 when some intruder is predicted within ``dist_m`` inside ``ttc_s`` (-1: nobody)."""
    d = min_predicted_range(x.obs, theta["ttc_s"])
    if d.size == 0:
        return -1.0
    return float(np.max((theta["dist_m"] - d) / theta["dist_m"]))


def clear_margin(x: SwitchState, theta: dict[str, float]) -> float:
    """g_exit = -g_enter (with the exit's own parameters)."""
    return -threat_margin(x, theta)


def course_margin(x: SwitchState, theta: dict[str, float]) -> float:
    """g_return: cosine of the horizontal angle between velocity and goal direction minus cos(heading)."""
    v, e = x.obs.own_vel[:2], (x.obs.goal - x.obs.own_pos)[:2]
    nv, ne = float(np.linalg.norm(v)), float(np.linalg.norm(e))
    if nv < 0.5 or ne < 1.0:  # hovering or at the goal: on course
        return 1.0
    return float(v @ e / (nv * ne)) - float(np.cos(np.radians(theta["heading_deg"])))


def uav_automaton(name: str, uid: str, b: UavBoundaries, switching: SwitchingParams | None = None,
                  rng: np.random.Generator | None = None) -> HybridAutomaton:
    """The mission/avoid/return automaton of UAV ``uid`` with boundaries ``b``."""
    enter = Boundary("avoid_enter", threat_margin, b.avoid_enter.model_dump(), draws_with="avoid_enter")
    modes = [Mode("mission"), Mode("avoid", children=(Mode("clear"), Mode("deflect"))), Mode("return")]
    transitions = [
        Transition("mission", "avoid", enter, "threat predicted"),
        Transition("avoid", "return", Boundary("avoid_exit", clear_margin, b.avoid_exit.model_dump(),
                                                      draws_with="avoid_enter"), "clear"),
        Transition("return", "avoid", enter, "threat predicted"),
        Transition("return", "mission", Boundary("return_done", course_margin, b.return_done.model_dump()),
                   "back on course"),
        Transition("clear", "deflect", lambda x: x.deflecting, "method deflects"),
        Transition("deflect", "clear", lambda x: not x.deflecting, "method on goal course"),
    ]
    return HybridAutomaton(name, modes, "mission", transitions, tag=uid, switching=switching, rng=rng, uav=uid)
