"""Hybrid-automaton modes (after CHARON): hierarchical modes, guarded transitions, named boundaries.

A controller that switches behaviour owns a ``HybridAutomaton``; each ``update`` evaluates the guards
of the current mode (and of the modes that hold it, outermost first) in declaration order and takes
the first that holds.  Every transition is an event in the run's event log, so reports and the Rerun
timeline show *why* behaviour changed.

Guards are either plain predicates ``guard(x) -> bool`` or **boundaries**: a named function
``g(x; theta)`` whose sign decides the switch (it holds when ``g >= 0``, or ``g > 0`` when strict),
with its parameters ``theta`` (a mapping of named floats) taken from the scenario YAML, so that
``--set``, ``randomize``, sweeps and learning reach them.  When a boundary changes sign between two
updates its crossing time is located by linear interpolation of ``g`` and logged with the event
(``t_cross``), as the collision check does for contacts.

Hierarchy: a ``Mode`` may hold sub-modes (entered at its ``initial`` child) with ``entry`` / ``exit``
actions; the active mode is always a leaf, and transitions may leave from or lead to any mode (a
composite target is entered at its initial leaf).  A mode's ``invariant`` must hold while it is
active: a violation is an ``invariant`` event (the model promised a jump before it).

    ha = HybridAutomaton("ego", ["follow", "pass"], initial="follow", transitions=[
        Transition("follow", "pass", guard=lambda x: x["gap_ok"], label="gap found"),
        Transition("pass", "follow", guard=lambda x: x["done"], label="passed"),
    ])
    mode, x = ha.update(t, x, events)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from corridor.events import EventLog

Guard = Callable[[Any], bool]
Reset = Callable[[Any], Any]
Action = Callable[[float], None]
BoundaryFn = Callable[[Any, Mapping[str, float]], float]
# a decision taken from outside at a boundary (a learning agent, corridor.decision_env):
# (automaton, boundary, t [s], g, x) -> whether the guard holds, or None to leave it to the automaton
Decider = Callable[["HybridAutomaton", "Boundary", float, float, Any], "bool | None"]


@dataclass(frozen=True)
class Boundary:
    """A named, parameterised guard ``g(x; theta)``: it holds when ``g >= 0`` (``g > 0`` if ``strict``)."""

    name: str
    fn: BoundaryFn
    theta: Mapping[str, float] = field(default_factory=dict)
    strict: bool = False
    # the boundary whose stochastic draw this one shares (an enter/exit pair: one perturbation e^eps
    # moves both, so a drawn pair keeps the order of its hysteresis); None: its own
    draws_with: str | None = None

    def value(self, x: Any) -> float:
        """g(x; theta) (dimensionless or in the unit its docstring names; only its sign and zero matter)."""
        return float(self.fn(x, self.theta))

    def holds(self, g: float) -> bool:
        """Whether the guard holds at the value ``g``."""
        return g > 0.0 if self.strict else g >= 0.0


@dataclass(frozen=True)
class Mode:
    """A mode; with ``children`` a composite entered at ``initial`` (default: the first child)."""

    name: str
    children: tuple[Mode, ...] = ()
    initial: str | None = None
    entry: Action | None = None  # called with t [s] when the mode is entered
    exit: Action | None = None  # called with t [s] when the mode is left
    invariant: Guard | Boundary | None = None  # must hold while the mode is active


@dataclass(frozen=True)
class Transition:
    """A jump ``src`` -> ``dst``, taken when ``guard`` holds (and ``when``, if given); ``reset`` maps the state."""

    src: str
    dst: str
    guard: Guard | Boundary
    label: str = ""
    reset: Reset | None = None  # maps the controller's continuous state on the jump
    when: Guard | None = None  # a discrete condition ANDed with a boundary guard (never located)


class SwitchingParams(BaseModel):
    """Boundary-localised stochastic switching (Grudic & Ungar's BLRL policy), off by default.

    The temperature T is measured in the boundary's own parameters, not in the units of g: a
    decision is taken as if the boundary's positive parameters were multiplied by e^eps, eps logistic
    with scale T (log units, the space ``--learn`` steps in), truncated to |eps| < ``band`` x T.  With
    c* the log-scale factor at which g(x; theta e^c*) = 0, the guard holds with probability about
    sigma(-c*/T) (sigma(c*/T) when g falls as theta grows) where |c*| < ``band`` x T; farther away (or
    where g is NaN, or the boundary has no positive parameter) its sign decides as usual.

    **One draw per band visit.**  eps is drawn when the automaton's state enters a boundary's band
    (the first update at which the boundary is evaluated there) and held until an evaluation finds
    the state outside the band: in between the guard is the sign of g(x; theta e^eps), a
    deterministic boundary moved by the draw.  An agent crossing the band meets one boundary and
    switches once, as under the deterministic policy, instead of a Bernoulli draw at every update
    (which switched back and forth tick by tick).  Boundaries with the same ``draws_with`` (an
    enter/exit pair) share the draw, so the drawn pair keeps its hysteresis.

    Each draw is one ``switch_draw`` event carrying the score-function gradient of its log density:
    d log f / d log theta = tanh(eps / 2T) / T for the shift of the boundary (its positive parameters
    together; split between them by their share of dg at the draw), for every boundary of the group,
    which the run sums into its row (``blrl.score.<component>.<boundary>.<param>``, per unit of the
    parameter) for the learner.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    temperature: float | None = Field(None, gt=0.0)  # T [log units of theta]; None: deterministic switching
    band: float = Field(4.0, gt=0.0)  # stochastic only where |c*| < band x T (sigma(4) = 0.982)


def crossing_time(t0: float, g0: float, t1: float, g1: float) -> float:
    """Linear interpolation of the zero of g between (t0, g0 < 0) and (t1, g1 >= 0) [s]."""
    if not (math.isfinite(g0) and math.isfinite(g1)) or g1 == g0:
        return t1
    return t0 + (t1 - t0) * (-g0) / (g1 - g0)


def in_band(b: Boundary, x: Any, g: float, switching: SwitchingParams | None) -> bool:
    """Whether a log-scale shift of b's positive parameters within ``band`` x T flips the guard at ``x``.

    That is where ``SwitchingParams`` draws; never with deterministic switching, a NaN g or no positive
    parameter.
    """
    pos = [k for k, v in b.theta.items() if float(v) > 0.0]
    if switching is None or switching.temperature is None or not math.isfinite(g) or not pos:
        return False
    span = switching.band * float(switching.temperature)
    lo, hi = _scaled_g(b, x, pos, -span), _scaled_g(b, x, pos, span)
    return math.isfinite(lo) and math.isfinite(hi) and lo * hi < 0.0


def _sigmoid(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-z))


def _scale(theta: Mapping[str, float], keys: Sequence[str], c: float) -> dict[str, float]:
    """The parameters ``theta`` with those named in ``keys`` multiplied by e^c."""
    return {k: float(v) * math.exp(c) if k in keys else float(v) for k, v in theta.items()}


def _scaled_g(b: Boundary, x: Any, keys: Sequence[str], c: float) -> float:
    """g(x; theta) with the parameters ``keys`` multiplied by e^c."""
    return float(b.fn(x, _scale(b.theta, keys, c)))


def _flatten(modes: Iterable[str | Mode], parent: str | None, out: dict[str, tuple[Mode, str | None]]) -> None:
    for m in modes:
        mode = Mode(m) if isinstance(m, str) else m
        if mode.name in out:
            raise ValueError(f"mode {mode.name!r} declared twice")
        out[mode.name] = (mode, parent)
        _flatten(mode.children, mode.name, out)


class HybridAutomaton:
    """Hierarchical modes with guarded transitions; records each jump (and located crossing) as an event."""

    def __init__(self, name: str, modes: Iterable[str | Mode], initial: str,
                 transitions: Sequence[Transition], tag: str = "", switching: SwitchingParams | None = None,
                 rng: np.random.Generator | None = None, **event_data: Any) -> None:
        self.name = name
        self.switching = switching if switching is not None and switching.temperature is not None else None
        if self.switching is not None and rng is None:
            raise ValueError(f"{name}: stochastic switching needs a random generator")
        self.rng = rng
        self.tag = tag  # prefix of the event messages (e.g. the governed vehicle's id)
        self.event_data = event_data  # added to every event's data (e.g. uav="uav_0")
        self._tree: dict[str, tuple[Mode, str | None]] = {}
        _flatten(modes, None, self._tree)
        self.modes = tuple(self._tree)
        self._paths = {m: self._path_of(m) for m in self.modes}  # the tree is fixed: each chain built once
        if initial not in self._tree:
            raise ValueError(f"{name}: initial mode {initial!r} not in {self.modes}")
        for tr in transitions:
            for m in (tr.src, tr.dst):
                if m not in self._tree:
                    raise ValueError(f"{name}: transition {tr.src}->{tr.dst} names unknown mode {m!r}")
        self.initial = initial
        self._out: dict[str, list[Transition]] = {m: [] for m in self.modes}
        for tr in transitions:
            self._out[tr.src].append(tr)
        self.boundaries = {tr.guard.name: tr.guard for tr in transitions if isinstance(tr.guard, Boundary)}
        # per mode, along its path (outermost first; the tree is fixed): the transitions leaving it in the
        # order they are tried, the boundaries among their guards (the first of each name) and the invariants
        self._path_out = {m: tuple(tr for pm in self._paths[m] for tr in self._out[pm]) for m in self.modes}
        self._path_bounds: dict[str, tuple[Boundary, ...]] = {}
        for m, trs in self._path_out.items():
            seen: dict[str, Boundary] = {}
            for tr in trs:
                if isinstance(tr.guard, Boundary) and tr.guard.name not in seen:
                    seen[tr.guard.name] = tr.guard
            self._path_bounds[m] = tuple(seen.values())
        self._path_inv: dict[str, tuple[tuple[str, Guard | Boundary], ...]] = {
            m: tuple((pm, inv) for pm in self._paths[m] for inv in (self._tree[pm][0].invariant,) if inv is not None)
            for m in self.modes}
        # asked first at every boundary guard whose discrete ``when`` holds (None: the automaton decides)
        self.decider: Decider | None = None
        self.reset(0.0)

    # ---- the tree ----------------------------------------------------------------------------------
    def path(self, mode: str | None = None) -> tuple[str, ...]:
        """Outermost-first chain of modes holding ``mode`` (itself included; default the active leaf)."""
        return self._paths[mode or self.mode]

    def _path_of(self, mode: str) -> tuple[str, ...]:
        out: list[str] = []
        m: str | None = mode
        while m is not None:
            out.append(m)
            m = self._tree[m][1]
        return tuple(reversed(out))

    def _leaf(self, mode: str) -> str:
        spec = self._tree[mode][0]
        while spec.children:
            spec = self._tree[spec.initial or spec.children[0].name][0]
        return spec.name

    def in_mode(self, mode: str) -> bool:
        """True when ``mode`` is the active leaf or holds it."""
        return mode in self.path()

    # ---- state -------------------------------------------------------------------------------------
    def reset(self, t: float = 0.0) -> None:
        """Back to the initial mode at time ``t`` [s], with an empty history."""
        self.mode, self.entered_t = self._leaf(self.initial), t
        self.history: list[tuple[float, str, str, str]] = []  # (t, src, dst, label)
        self._g_prev: dict[str, float] = {}  # boundary name -> g at the previous update (at _t_prev [s])
        self._t_prev = t
        self.g_now: dict[str, float] = {}  # the boundaries evaluated at the last update
        self.invariant_violations = 0
        self._t_last = t
        # boundary name -> outcome decided from outside (a learning agent's action): the guard takes it
        # instead of the sign of g (g is still evaluated and logged)
        self.decided: dict[str, bool] = {}
        self._held: dict[str, float] = {}  # draw group -> eps [log units] held for the current band visit
        self.pending_draws: list[dict[str, Any]] = []

    def time_in_mode(self, t: float) -> float:
        """Seconds spent in the current mode at time ``t`` [s]."""
        return t - self.entered_t

    def _guard(self, tr: Transition, t: float, x: Any) -> tuple[bool, float | None]:
        """Whether ``tr`` fires, and the located crossing time of its boundary (None: a plain guard)."""
        if not isinstance(tr.guard, Boundary):
            return bool(tr.guard(x)), None
        g = self.g_now[tr.guard.name]
        holds = self.decided.get(tr.guard.name)
        if holds is None and self.decider is not None and (tr.when is None or bool(tr.when(x))):
            holds = self.decider(self, tr.guard, t, g, x)
        if holds is None:
            holds = self._draw(tr.guard, t, g, x) if self.switching is not None else tr.guard.holds(g)
        fires = holds and (tr.when is None or bool(tr.when(x)))
        if not fires:  # the crossing is located only for a jump
            return False, None
        g_prev = self._g_prev.get(tr.guard.name)
        t_prev, g_prev = (t, g) if g_prev is None else (self._t_prev, g_prev)
        crossed = tr.guard.holds(g) and not tr.guard.holds(g_prev)  # a stochastic switch may fire before g = 0
        t_cross = crossing_time(t_prev, g_prev, t, g) if crossed else t
        return fires, t_cross

    def _draw(self, b: Boundary, t: float, g: float, x: Any) -> bool:
        """The guard's outcome near boundary ``b``: the held draw's moved boundary, else g's sign."""
        group = b.draws_with or b.name
        pos = self._positive(b)
        if not in_band(b, x, g, self.switching):
            self._held.pop(group, None)  # the band visit ended (or never began): deterministic
            return b.holds(g)
        eps = self._held.get(group)
        if eps is None:
            eps = self._new_draw(b, group, g, x, pos)
        return b.holds(_scaled_g(b, x, pos, eps))

    @staticmethod
    def _positive(b: Boundary) -> list[str]:
        return [k for k, v in b.theta.items() if float(v) > 0.0]

    def _new_draw(self, b: Boundary, group: str, g: float, x: Any, pos: Sequence[str]) -> float:
        """Draw eps for ``group`` (held until the band is left) and queue its ``switch_draw`` event."""
        sw = self.switching
        temp, band = float(sw.temperature), sw.band  # type: ignore[union-attr,arg-type]
        lo, hi = _sigmoid(-band), _sigmoid(band)
        q = lo + (hi - lo) * float(self.rng.random())  # type: ignore[union-attr]
        eps = temp * math.log(q / (1.0 - q))  # truncated logistic, scale T
        self._held[group] = eps
        near = self._near(b, x, g)
        p = _sigmoid(near[0]) if near is not None else float(b.holds(g))
        shift = math.tanh(eps / (2.0 * temp)) / temp  # d log f(eps) / d log theta of the moved boundary
        score: dict[str, float] = {}
        for other in self.boundaries.values():
            if (other.draws_with or other.name) == group:
                for k, v in self._split(other, x).items():
                    score[f"{other.name}.{k}"] = shift * v
        self.pending_draws.append({"boundary": b.name, "a": b.holds(_scaled_g(b, x, pos, eps)), "p": p,
                                   "eps": eps, "g": g, "score": score})
        return eps

    def _split(self, b: Boundary, x: Any) -> dict[str, float]:
        """Per positive parameter k of ``b``: w_k / theta_k, the share of the boundary's log-scale shift.

        w_k is k's share of the log-scale derivative of g at ``x`` (equal shares where it is undefined).
        """
        pos = self._positive(b)
        if len(pos) > 1:
            dg = {k: self._dg(b, x, k) * float(b.theta[k]) for k in pos}
            tot = sum(dg.values())
            if math.isfinite(tot) and tot != 0.0:
                return {k: dg[k] / tot / float(b.theta[k]) for k in pos}
        return {k: 1.0 / len(pos) / float(b.theta[k]) for k in pos}

    def _near(self, b: Boundary, x: Any, g: float) -> tuple[float, dict[str, float]] | None:
        """(logit of p, d logit / d theta) near ``b``, else None (the switch is deterministic).

        p is the probability that the guard holds at ``x`` under a fresh draw (logged with each draw).
        """
        sw = self.switching
        pos = self._positive(b)
        if sw is None or not in_band(b, x, g, sw):
            return None
        temp, span = float(sw.temperature), sw.band * float(sw.temperature)  # type: ignore[arg-type]
        lo, hi = _scaled_g(b, x, pos, -span), _scaled_g(b, x, pos, span)
        from scipy.optimize import brentq

        c = float(brentq(lambda u: _scaled_g(b, x, pos, u), -span, span, xtol=1e-9))
        up = 1.0 if hi > lo else -1.0  # g rises (+1) or falls (-1) with the scale of theta
        shifted = Boundary(b.name, b.fn, _scale(b.theta, pos, c), b.strict)
        dg = {k: self._dg(shifted, x, k) for k in b.theta}  # at theta e^c*
        dg_dc = sum(dg[k] * float(shifted.theta[k]) for k in pos)
        if dg_dc == 0.0:
            return None
        # logit = -up c* / T; implicit function: dc*/d theta_k = -dg_k m_k / dg_dc (m_k = e^c* if scaled)
        dlogit = {k: up * dg[k] * (math.exp(c) if k in pos else 1.0) / (temp * dg_dc) for k in b.theta}
        return -up * c / temp, dlogit

    @staticmethod
    def _dg(b: Boundary, x: Any, key: str) -> float:
        """dg/d theta_key by a central difference (step 1e-4 of the parameter's size)."""
        h = 1e-4 * max(abs(float(b.theta[key])), 1.0)
        up, down = dict(b.theta), dict(b.theta)
        up[key], down[key] = float(b.theta[key]) + h, float(b.theta[key]) - h
        return (float(b.fn(x, up)) - float(b.fn(x, down))) / (2.0 * h)

    def _evaluate(self, t: float, x: Any) -> None:
        """Evaluate g of every boundary leaving the active path, remembered for the next crossing location."""
        self._keep(t, {b.name: b.value(x) for b in self._path_bounds[self.mode]})

    def _keep(self, t: float, g_now: dict[str, float]) -> None:
        """``g_now`` becomes this update's g of the active path's boundaries; the previous update's is kept."""
        self._g_prev, self._t_prev = self.g_now, self._t_last  # only the previous update's
        self.g_now, self._t_last = g_now, t

    def update(self, t: float, x: Any, events: EventLog | None = None, settle: int = 1) -> tuple[str, Any]:
        """Take at most ``settle`` transitions whose guards hold; return (mode, possibly reset state).

        One transition per pass; after a jump the new mode's guards are tried on the same ``x``.
        ``settle`` > 1 lets a memoryless controller land, within one update, in the mode its state
        decides (e.g. entering a composite and at once switching sub-mode).
        """
        self._evaluate(t, x)
        self.pending_draws = []
        try:
            for _ in range(max(settle, 1)):
                jumped, x = self._update(t, x, events)
                if not jumped:
                    break
                self._evaluate_new(x)
            return self.mode, x
        finally:
            if events is not None:
                for d in self.pending_draws:
                    events.emit(t, self.name, "switch_draw", f"{d['boundary']}: eps {d['eps']:+.3f} (p {d['p']:.3f})",
                                **self.event_data, **d)

    def quiet_update(self, t: float, x: Any) -> bool:
        """``update(t, x, ...)`` when it would not jump, without its general machinery.

        True when done (the boundaries' g evaluated and kept for the next crossing location, as ``update``
        keeps them; nothing to emit), False when the caller must call ``update`` (nothing changed here).
        Only for a deterministic automaton (no stochastic switching, no decider, no decided outcome)
        without invariants on its path; its guards, ``when`` conditions and boundary functions must be pure
        (on a jump they are evaluated again by ``update``).
        """
        mode = self.mode
        if self.switching is not None or self.decider is not None or self.decided or self._path_inv[mode]:
            return False
        g_now = {b.name: b.value(x) for b in self._path_bounds[mode]}
        for tr in self._path_out[mode]:
            guard = tr.guard
            if isinstance(guard, Boundary):
                if guard.holds(g_now[guard.name]) and (tr.when is None or bool(tr.when(x))):
                    return False
            elif bool(guard(x)):
                return False
        self._keep(t, g_now)
        self.pending_draws = []
        return True

    def _evaluate_new(self, x: Any) -> None:
        """After a jump: g of the boundaries leaving the new path not yet evaluated at this update."""
        for b in self._path_bounds[self.mode]:
            if b.name not in self.g_now:
                self.g_now[b.name] = b.value(x)

    def _update(self, t: float, x: Any, events: EventLog | None) -> tuple[bool, Any]:
        for tr in self._path_out[self.mode]:  # outermost first: a mode's own jump pre-empts its sub-modes'
            fires, t_cross = self._guard(tr, t, x)
            if fires:
                self._jump(t, tr, t_cross, events)
                return True, (tr.reset(x) if tr.reset else x)
        self._check_invariant(t, x, events)
        return False, x

    def _jump(self, t: float, tr: Transition, t_cross: float | None, events: EventLog | None) -> None:
        src_leaf, dst_leaf = self.mode, self._leaf(tr.dst)
        old, new = self.path(src_leaf), self.path(dst_leaf)
        common = 0
        while common < min(len(old), len(new)) and old[common] == new[common] and old[common] != tr.src:
            common += 1
        for m in reversed(old[common:]):
            on_exit = self._tree[m][0].exit
            if on_exit is not None:
                on_exit(t)
        self.history.append((t, src_leaf, dst_leaf, tr.label))
        if events is not None:
            data: dict[str, Any] = {**self.event_data, "src": src_leaf, "dst": dst_leaf}
            if isinstance(tr.guard, Boundary) and t_cross is not None:
                data.update(boundary=tr.guard.name, t_cross=t_cross, g=self.g_now[tr.guard.name],
                            located=t_cross != t)  # False: g was already past 0 (a `when` or a draw fired)
            prefix = f"{self.tag}: " if self.tag else ""
            text = f"{'.'.join(old)} -> {'.'.join(new)}: {tr.label}"  # dotted paths: avoid.clear
            events.emit(t, self.name, "mode", prefix + text, **data)
        self.mode, self.entered_t = dst_leaf, t
        for m in new[common:]:
            on_entry = self._tree[m][0].entry
            if on_entry is not None:
                on_entry(t)

    def _check_invariant(self, t: float, x: Any, events: EventLog | None) -> None:
        for m, inv in self._path_inv[self.mode]:
            ok = inv.holds(inv.value(x)) if isinstance(inv, Boundary) else bool(inv(x))
            if not ok:
                self.invariant_violations += 1
                if events is not None:
                    prefix = f"{self.tag}: " if self.tag else ""
                    events.emit(t, self.name, "invariant", f"{prefix}{m}: invariant violated",
                                **self.event_data, mode=m)

