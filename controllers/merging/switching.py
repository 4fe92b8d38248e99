"""When a V2X-merging vehicle switches: its automaton and the named boundaries (issue 28).

Every vehicle holding an assignment of the roadside unit owns one ``HybridAutomaton``::

    ramp{ approach --merge_enter--> merge{ behind <--gap_accept / gap_reject--> ahead } }
    main{ free --yield_enter [ramp predecessor]--> yield{ open <--yield_hold / yield_pass--> pass } }
      yield --yield_exit, or a predecessor on its own road--> free
      free --open_ahead [mainline predecessor, a ramp vehicle ahead of it in the order]--> early
      early --yield_enter [ramp predecessor]--> yield;  early --[no ramp vehicle ahead]--> free

- ``ramp.approach``: on the ramp, the energy-optimal trajectory to the assigned crossing time.
- ``ramp.merge``: near the conflict point, cruise at the stream's speed; ``behind`` keeps the gap
  behind the predecessor from the mainline (virtual-vehicle following: the constant-time-gap rule
  and the safety layer), ``ahead`` has passed that predecessor and takes the gap in front of it.
  This is the ramp vehicle's **gap acceptance**; the lane change itself is SUMO's.
- ``main.free``: a mainline vehicle behind a mainline predecessor is not commanded (its driver
  follows its physical leader).  ``main.yield``: behind a ramp predecessor near the conflict point
  it is commanded and **yields** (``open``: opens the gap behind the ramp vehicle) unless the ramp
  vehicle has fallen behind it (``pass``: cruise).
- ``main.early``: behind a mainline predecessor, but with a ramp vehicle ahead of that predecessor
  in the crossing order (within the vehicle's listening depth): it opens the gap to that ramp
  vehicle early and comfortably (as it would behind a ramp predecessor), so that when its own
  predecessor leaves the order (crosses ahead of the ramp vehicle, or is a truck that never yields)
  it does not inherit the ramp vehicle a few metres ahead (docs/guide/merging-flagship.md: 67 of
  144 hard-brake onsets).  Not commanded when no braking is needed.

The boundaries (g >= 0 holds; strict ones g > 0), with their parameters under
``controllers.X.params.boundaries``:

    merge_enter, yield_enter(x; dist_m)  = dist_m - d                 d: distance to the conflict point [m]
    yield_exit(x; dist_m)                = d - dist_m          (strict)
    gap_reject, yield_pass(x; lag_lengths) = -(s + lag_lengths L)    s: virtual gap to the predecessor [m]
    gap_accept, yield_hold(x; lag_lengths) = s + lag_lengths L  (strict)    L: its length [m]
    open_ahead(x; dist_m)                = dist_m - d          (strict)

The defaults (``dist_m`` = ``virtual_leader_m``, 100 m; ``lag_lengths`` 1) are the constants the
controller had before the boundaries existed, so its rows are unchanged; ``open_ahead``'s default
``dist_m`` 0 never holds (a coordinated vehicle has d >= 0), so ``early`` is never entered.  ``s`` is not defined
without a tracked predecessor from the other road (g is NaN: no jump; the controller falls back).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.modes import Boundary, HybridAutomaton, Mode, SwitchingParams, Transition

RAMP_MODES = ("ramp", "approach", "merge", "behind", "ahead")
MAIN_MODES = ("main", "free", "early", "yield", "open", "pass")
DIST_BOUNDARIES = ("merge_enter", "yield_enter", "yield_exit")  # their dist_m defaults to virtual_leader_m


class DistTheta(BaseModel):
    """Parameters of a distance boundary (None: the controller's ``virtual_leader_m``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    dist_m: float | None = Field(None, gt=0.0)  # [m] distance to the conflict point


class LagTheta(BaseModel):
    """Parameters of a gap boundary."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    lag_lengths: float = Field(1.0, ge=0.0)  # [predecessor lengths] how far the predecessor may fall
    #   behind (bumper to bumper) before its gap is given up


class OpenTheta(BaseModel):
    """Parameters of the early-opening boundary (0: off, today's controller)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    dist_m: float = Field(0.0, ge=0.0)  # [m] within this distance of the conflict point a vehicle behind a
    #   predecessor on its own road opens the gap to the nearest other-road vehicle ahead in the order


class SlotTheta(BaseModel):
    """Parameters of the coordinator's slot-feasibility boundary (inf: off, every slot is feasible)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=True)

    decel_mps2: float = Field(math.inf, gt=0.0)  # [m/s^2] cps puts no vehicle directly behind one from the
    #   other road that would have to brake harder than this to open its gap (coordinator.SlotCheck)


class MergeBoundaries(BaseModel):
    """The named boundaries of the merging automaton (scenario: ``controllers.X.params.boundaries``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    merge_enter: DistTheta = Field(default_factory=DistTheta)  # ramp: trajectory -> virtual following
    gap_accept: LagTheta = Field(default_factory=LagTheta)  # ramp: ahead -> behind its predecessor
    gap_reject: LagTheta = Field(default_factory=LagTheta)  # ramp: behind -> ahead of it
    yield_enter: DistTheta = Field(default_factory=DistTheta)  # mainline: free -> yield to a ramp predecessor
    yield_exit: DistTheta = Field(default_factory=DistTheta)  # mainline: yield -> free
    yield_hold: LagTheta = Field(default_factory=LagTheta)  # mainline: pass -> open the gap again
    yield_pass: LagTheta = Field(default_factory=LagTheta)  # mainline: open -> pass (the ramp vehicle fell behind)
    open_ahead: OpenTheta = Field(default_factory=OpenTheta)  # mainline: free -> early (open to a ramp vehicle
    #   ahead of its mainline predecessor in the order)
    slot_feasible: SlotTheta = Field(default_factory=SlotTheta)  # the RSU (cps): which slots the search may use

    # hysteresis pairs, follower -> (anchor, +1: follower's theta >= anchor's, -1: <=); with the order
    # inverted both guards hold in a band and the vehicle switches at every update.  yield: enter at
    # d <= yield_enter, leave at d > yield_exit; gap: reject at s <= -lag_r L, accept at s > -lag_a L.
    # The pair shares its stochastic draw (corridor.modes.Boundary.draws_with); --learn keeps the order.
    hysteresis: ClassVar[dict[str, tuple[str, int]]] = {
        "yield_exit": ("yield_enter", 1), "gap_accept": ("gap_reject", -1), "yield_hold": ("yield_pass", -1)}


@dataclass
class VirtualGap:
    """The predecessor seen through the vehicle's V2X track, projected on the conflict point."""

    known: bool  # tracked and fresh (age <= stale_after_s)
    gap_m: float = math.nan  # bumper-to-bumper, > 0: the predecessor is ahead
    v_lead_mps: float = math.nan
    age_s: float = math.nan
    lead_len_m: float = 5.0


@dataclass
class MergeState:
    """What the guards read; the virtual gap is computed on first use (only near the conflict point)."""

    road: str  # "ramp" or "main": the vehicle's route (a ramp vehicle stays "ramp" on the acceleration lane)
    dist_m: float  # [m] to the conflict point along the vehicle's road
    cross_pred: bool  # the predecessor in the crossing order is on the other road
    probe: Callable[[], VirtualGap] | None = None
    # the predecessor is on the vehicle's own road, and a vehicle of the other road is ahead of it in
    # the order, within the vehicle's listening depth (the RSU's ``Assignment.cross_ahead``)
    cross_ahead: bool = False
    _gap: VirtualGap | None = field(default=None, repr=False)

    def gap(self) -> VirtualGap:
        if self._gap is None:
            self._gap = self.probe() if (self.cross_pred and self.probe is not None) else VirtualGap(False)
        return self._gap

    def features(self) -> dict[str, float]:
        """What the guards read, as numbers (a learning agent's observation, ``corridor.decision_env``):
        the distance [m], whether the predecessor is on the other road, and its virtual gap [m], speed
        [m/s], track age [s] and length [m] (0 when it is not known).  Reading them changes nothing."""
        g = self.gap()
        known = [g.gap_m, g.v_lead_mps, g.age_s, g.lead_len_m] if g.known else [0.0] * 4
        return dict(zip(("dist_m", "cross_pred", "gap_known", "gap_m", "v_lead_mps", "age_s", "lead_len_m"),
                        [self.dist_m, float(self.cross_pred), float(g.known), *known], strict=True))


def approach_margin(x: MergeState, theta: Mapping[str, float]) -> float:
    """dist_m - d [m]: >= 0 within ``dist_m`` of the conflict point."""
    return float(theta["dist_m"]) - x.dist_m


def leave_margin(x: MergeState, theta: Mapping[str, float]) -> float:
    """d - dist_m [m]: > 0 farther than ``dist_m`` from the conflict point."""
    return x.dist_m - float(theta["dist_m"])


def keep_margin(x: MergeState, theta: Mapping[str, float]) -> float:
    """s + lag_lengths x L [m]: > 0 while the predecessor is ahead, beside, or less than
    ``lag_lengths`` of its lengths behind (NaN without a fresh track of it)."""
    g = x.gap()
    if not g.known:
        return math.nan
    return g.gap_m + float(theta["lag_lengths"]) * g.lead_len_m


def give_up_margin(x: MergeState, theta: Mapping[str, float]) -> float:
    """-(s + lag_lengths x L) [m]: >= 0 once the predecessor fell ``lag_lengths`` lengths behind."""
    return -keep_margin(x, theta)


def resolved(b: MergeBoundaries, virtual_leader_m: float) -> dict[str, dict[str, float]]:
    """Every boundary's theta, ``dist_m`` None replaced by ``virtual_leader_m``."""
    out: dict[str, dict[str, float]] = {}
    for name in MergeBoundaries.model_fields:
        theta = getattr(b, name).model_dump()
        if "dist_m" in theta and theta["dist_m"] is None:
            theta["dist_m"] = virtual_leader_m
        out[name] = {k: float(v) for k, v in theta.items()}
    return out


def merge_automaton(name: str, vid: str, road: str, theta: Mapping[str, Mapping[str, float]],
                    switching: SwitchingParams | None = None,
                    rng: np.random.Generator | None = None) -> HybridAutomaton:
    """The automaton of vehicle ``vid`` on route ``road`` ("ramp" or "main": its top mode, for good)."""
    def bnd(key: str, fn: Callable[[MergeState, Mapping[str, float]], float], strict: bool = False) -> Boundary:
        anchor = MergeBoundaries.hysteresis.get(key, (key, 0))[0]
        return Boundary(key, fn, dict(theta[key]), strict=strict, draws_with=anchor)

    modes = [Mode("ramp", children=(Mode("approach"), Mode("merge", children=(Mode("behind"), Mode("ahead"))))),
             Mode("main", children=(Mode("free"), Mode("early"), Mode("yield", children=(Mode("open"), Mode("pass")))))]
    transitions = [
        Transition("approach", "merge", bnd("merge_enter", approach_margin), "near the conflict point"),
        Transition("behind", "ahead", bnd("gap_reject", give_up_margin), "predecessor fell behind"),
        Transition("ahead", "behind", bnd("gap_accept", keep_margin, strict=True), "gap behind predecessor"),
        Transition("free", "yield", bnd("yield_enter", approach_margin), "yield to ramp predecessor",
                   when=lambda x: x.cross_pred),
        Transition("free", "early", bnd("open_ahead", approach_margin, strict=True),
                   "open early to a ramp vehicle ahead", when=lambda x: x.cross_ahead and not x.cross_pred),
        Transition("early", "yield", bnd("yield_enter", approach_margin), "yield to ramp predecessor",
                   when=lambda x: x.cross_pred),
        Transition("early", "free", lambda x: not x.cross_ahead or x.cross_pred, "no ramp vehicle ahead"),
        Transition("yield", "free", bnd("yield_exit", leave_margin, strict=True), "far from the conflict point"),
        Transition("yield", "free", lambda x: not x.cross_pred, "predecessor on own road"),
        Transition("open", "pass", bnd("yield_pass", give_up_margin), "ramp predecessor fell behind"),
        Transition("pass", "open", bnd("yield_hold", keep_margin, strict=True), "ramp predecessor ahead"),
    ]
    return HybridAutomaton(name, modes, road, transitions, tag=vid, switching=switching, rng=rng, vehicle=vid)


def clone_automaton(template: HybridAutomaton, vid: str, rng: np.random.Generator | None = None) -> HybridAutomaton:
    """``merge_automaton(name, vid, road, theta, switching, rng)`` from ``template``, that call's automaton for
    another vehicle (never updated itself): the mode tree, the transitions and their boundaries (immutable)
    shared, the state new (``HybridAutomaton.reset``), ``vid`` as tag and event data (issue 27, the thirteenth
    CPU pass: ~180 us a new automaton in the run, ~140 a 300 s run)."""
    if template.switching is not None and rng is None:
        raise ValueError(f"{template.name}: stochastic switching needs a random generator")
    ha = copy.copy(template)
    ha.rng, ha.tag, ha.event_data, ha.decider = rng, vid, {"vehicle": vid}, None
    ha.reset(0.0)
    return ha


class QuietMerge:
    """``HybridAutomaton.quiet_update`` of a merge automaton (``merge_automaton`` on ``theta``) written out per
    leaf mode: the same g values (the boundary functions' arithmetic on the same floats, in the same order and
    with the same keys), the same guards in the same order (issue 27, the eleventh CPU pass: ~2 us a call
    against ~6.6 us through the general machinery).  Only for an automaton ``quiet_update`` would not decline
    for its switching, decider, decided outcomes or invariants (the caller checks ``usable``)."""

    def __init__(self, theta: Mapping[str, Mapping[str, float]]) -> None:
        self.merge_enter = float(theta["merge_enter"]["dist_m"])
        self.yield_enter = float(theta["yield_enter"]["dist_m"])
        self.yield_exit = float(theta["yield_exit"]["dist_m"])
        self.open_ahead = float(theta["open_ahead"]["dist_m"])
        self.gap_reject = float(theta["gap_reject"]["lag_lengths"])
        self.gap_accept = float(theta["gap_accept"]["lag_lengths"])
        self.yield_pass = float(theta["yield_pass"]["lag_lengths"])
        self.yield_hold = float(theta["yield_hold"]["lag_lengths"])

    @staticmethod
    def usable(ha: HybridAutomaton) -> bool:
        """Whether ``quiet_update`` would not decline ``ha`` for its configuration (merge automata have no
        invariants)."""
        return ha.switching is None and ha.decider is None and not ha.decided

    @staticmethod
    def _keep(x: MergeState, lag: float) -> float:
        """``keep_margin``'s value (NaN without a known gap)."""
        g = x.gap()
        if not g.known:
            return math.nan
        return g.gap_m + lag * g.lead_len_m

    def __call__(self, ha: HybridAutomaton, t: float, x: MergeState) -> bool:
        """``ha.quiet_update(t, x)``: True when no guard fires (g kept), False (nothing changed) otherwise."""
        mode, d = ha.mode, x.dist_m
        g_now: dict[str, float]
        if mode == "approach":
            g = self.merge_enter - d
            if g >= 0.0:
                return False
            g_now = {"merge_enter": g}
        elif mode == "free":
            g, g_oa = self.yield_enter - d, self.open_ahead - d
            if (g >= 0.0 and x.cross_pred) or (g_oa > 0.0 and x.cross_ahead and not x.cross_pred):
                return False
            g_now = {"yield_enter": g, "open_ahead": g_oa}
        elif mode == "behind":
            g = -self._keep(x, self.gap_reject)
            if g >= 0.0:
                return False
            g_now = {"gap_reject": g}
        elif mode == "ahead":
            g = self._keep(x, self.gap_accept)
            if g > 0.0:
                return False
            g_now = {"gap_accept": g}
        elif mode == "open":
            g, g_p = d - self.yield_exit, -self._keep(x, self.yield_pass)
            if g > 0.0 or not x.cross_pred or g_p >= 0.0:
                return False
            g_now = {"yield_exit": g, "yield_pass": g_p}
        elif mode == "pass":
            g, g_h = d - self.yield_exit, self._keep(x, self.yield_hold)
            if g > 0.0 or not x.cross_pred or g_h > 0.0:
                return False
            g_now = {"yield_exit": g, "yield_hold": g_h}
        elif mode == "early":
            g = self.yield_enter - d
            if (g >= 0.0 and x.cross_pred) or not x.cross_ahead or x.cross_pred:
                return False
            g_now = {"yield_enter": g}
        else:
            return ha.quiet_update(t, x)
        ha._g_prev, ha._t_prev = ha.g_now, ha._t_last  # HybridAutomaton._keep
        ha.g_now, ha._t_last = g_now, t
        if ha.pending_draws:
            ha.pending_draws = []
        return True
