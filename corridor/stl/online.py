"""Incremental (online) monitoring of space robustness.

``OnlineMonitor(formula, dt).update(sample)`` takes one sample of every signal and returns the
robustness of the formula **at time 0** given the samples so far, with the same end-of-trace
convention as the offline semantics: the unknown future is left out of every window (windows are
truncated to the samples received; empty windows give the operator's identity). So after ``m``
updates the value equals ``space_robustness(formula, first_m_samples, dt)[0]`` exactly; for a formula
with finite horizon ``H`` it is final once ``m*dt > H``, and for ``G[a,inf] phi`` it is the running
minimum over everything seen so far.

How it stays incremental: every node of finite horizon ``h`` streams its robustness; the value at
index ``k`` is *final* once ``h`` seconds of samples after ``k`` are in, and final values are computed
once, in batches, by the same O(n) kernels as the offline semantics. Only the not-yet-final tail
(at most ``h`` plus one batch) is recomputed per query, so the cost per sample depends on the horizon,
never on the number of samples. Nodes store only the final values their parent still needs.

Unbounded operators (``G[a,inf]``, ``F[a,inf]``, ``U[a,inf]``) keep a running aggregate of their
operand's final values and are supported where their value is needed only at time 0: anywhere outside
another temporal operator (``G(safe) & F(goal)``, ``G[0,inf](x -> F[0,5] y)``). A temporal operator
whose operand has an infinite horizon (``F[0,10] G[0,inf] p``) is refused with ``ValueError``.

NaN samples follow the offline semantics (``space``): the value is NaN exactly when it reads one, on
every prefix. The monitor walks the tree recursively, so it balances chains of ``&`` / ``|`` first
(a conjunction of hundreds of predicates has depth ``log2 n``; same values, min/max are associative)
and refuses formulas still nested deeper than ``MAX_NESTING`` (100) levels with ``ValueError``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from corridor.stl.formula import Always, Eventually, Formula, Predicate, Until, rebalance
from corridor.stl.parser import MAX_NESTING, as_formula
from corridor.stl.space import (
    STLSignalError,
    apply_operator,
    check_dt,
    interval_indices,
    predicate_robustness,
)


def _max(a: float, b: float) -> float:
    """``max`` that propagates NaN (Python's ``max`` keeps its first argument against a NaN)."""
    return float(np.maximum(a, b))


def _min(a: float, b: float) -> float:
    return float(np.minimum(a, b))


class _Stream:
    """Robustness of a finite-horizon sub-formula, streamed: final values plus a recomputed tail."""

    def __init__(self, formula: Formula, dt: float) -> None:
        self.formula = formula
        self.dt = dt
        self.children = [_Stream(c, dt) for c in formula.children()]
        self.window = 0  # [samples] how far ahead of k the node reads its children
        if isinstance(formula, Always | Eventually | Until):
            self.window = int(interval_indices(formula.a, formula.b, dt)[1])
        self.finals: list[float] = []  # final values for indices start, start+1, ...
        self.start = 0
        self.n_final = 0
        self.first: float | None = None  # final value at index 0

    def advance(self, sample: Mapping[str, np.ndarray]) -> None:
        """Take one more sample and extend the final values where they are now decided."""
        if isinstance(self.formula, Predicate):
            self._extend(predicate_robustness(self.formula, sample, 1))
            return
        for child in self.children:
            child.advance(sample)
        decided = min(c.n_final for c in self.children)
        ready = decided - self.window  # indices below are final
        if ready - self.n_final >= max(1, self.window):  # batch: O(window) work per window samples
            segment = apply_operator(self.formula, [c.values(self.n_final, decided) for c in self.children],
                                     self.dt)
            self._extend(segment[: ready - self.n_final])
            for child in self.children:
                child.trim(self.n_final)

    def _extend(self, values: np.ndarray) -> None:
        if self.first is None and values.size:
            self.first = float(values[0])
        self.finals.extend(values.tolist())
        self.n_final += values.size

    def trim(self, lo: int) -> None:
        """Forget final values below index ``lo`` (the parent no longer reads them)."""
        drop = lo - self.start
        if drop > 0:
            del self.finals[:drop]
            self.start = lo

    def values(self, lo: int, m: int) -> np.ndarray:
        """Robustness at indices ``lo .. m-1`` of the ``m``-sample prefix (finals, then the tail)."""
        final_part = np.asarray(self.finals[lo - self.start : m - self.start], dtype=float)
        return np.concatenate((final_part, self.tentative(m)))

    def tentative(self, m: int) -> np.ndarray:
        """Not-yet-final values at indices ``n_final .. m-1``, by the truncated-window convention."""
        if self.n_final >= m:
            return np.empty(0)
        return apply_operator(self.formula, [c.values(self.n_final, m) for c in self.children], self.dt)

    def value0(self, m: int) -> float:
        return self.first if self.first is not None else float(self.values(0, m)[0])


class _UnboundedTemporal:
    """``G[a,inf]``, ``F[a,inf]`` or ``U[a,inf]`` at time 0 only, from running aggregates."""

    def __init__(self, formula: Always | Eventually | Until, dt: float) -> None:
        if any(math.isinf(c.horizon()) for c in formula.children()):
            raise ValueError(f"online monitoring needs finite-horizon operands of temporal operators: {formula}")
        self.formula = formula
        self.children = [_Stream(c, dt) for c in formula.children()]
        self.lo = interval_indices(formula.a, formula.b, dt)[0]
        self.consumed = 0  # operand indices folded into the aggregates
        self.acc = -math.inf if isinstance(formula, Eventually | Until) else math.inf
        self.left_min = math.inf  # Until: min of the left operand over [0, consumed)

    def advance(self, sample: Mapping[str, np.ndarray]) -> None:
        for child in self.children:
            child.advance(sample)
        decided = min(c.n_final for c in self.children)
        if decided > self.consumed:
            segments = [c.values(self.consumed, decided)[: decided - self.consumed] for c in self.children]
            self.acc, self.left_min = self._fold(segments, self.consumed)
            self.consumed = decided
            for child in self.children:
                child.trim(decided)

    def _fold(self, segments: list[np.ndarray], offset: int) -> tuple[float, float]:
        """Aggregates after adding operand values at indices ``offset, offset+1, ...``."""
        keep = np.arange(offset, offset + segments[0].size) >= self.lo
        if isinstance(self.formula, Until):
            left, right = segments
            before = np.minimum(self.left_min, np.concatenate(([np.inf], np.minimum.accumulate(left)[:-1])))
            candidates = np.minimum(right, before)[keep]
            best = _max(self.acc, float(candidates.max())) if candidates.size else self.acc
            return best, _min(self.left_min, float(left.min()))
        picked = segments[0][keep]
        if picked.size == 0:
            return self.acc, self.left_min
        if isinstance(self.formula, Always):
            return _min(self.acc, float(picked.min())), self.left_min
        return _max(self.acc, float(picked.max())), self.left_min

    def value0(self, m: int) -> float:
        tails = [c.values(self.consumed, m) for c in self.children]
        return self._fold(tails, self.consumed)[0] if tails[0].size else self.acc


class _UnboundedBoolean:
    """A Boolean connective above an unbounded operator: combines its children's values at time 0."""

    def __init__(self, formula: Formula, dt: float) -> None:
        self.formula = formula
        self.dt = dt
        self.children = [_build(c, dt) for c in formula.children()]

    def advance(self, sample: Mapping[str, np.ndarray]) -> None:
        for child in self.children:
            if isinstance(child, _Stream):
                if child.first is not None:
                    continue  # decided: only its value at time 0 is read
                child.advance(sample)
                child.trim(child.n_final)
            else:
                child.advance(sample)

    def value0(self, m: int) -> float:
        values = [np.array([c.value0(m)]) for c in self.children]
        return float(apply_operator(self.formula, values, self.dt)[0])


_Node = _Stream | _UnboundedTemporal | _UnboundedBoolean


def _build(formula: Formula, dt: float) -> _Node:
    if not math.isinf(formula.horizon()):
        return _Stream(formula, dt)
    if isinstance(formula, Always | Eventually | Until):
        return _UnboundedTemporal(formula, dt)
    return _UnboundedBoolean(formula, dt)


class OnlineMonitor:
    """Robustness at time 0 of a formula, updated one sample at a time (see the module docstring)."""

    def __init__(self, formula: str | Formula, dt: float) -> None:
        dt = check_dt(dt)
        self.formula = as_formula(formula)
        self.dt = dt  # [s]
        self.names = sorted(self.formula.signal_names())
        tree = rebalance(self.formula)
        if tree.depth() > MAX_NESTING:
            raise ValueError(f"formula nests deeper than {MAX_NESTING} levels (after balancing & and | "
                             f"chains): too deep for online monitoring (offline evaluation has no limit)")
        self._root = _build(tree, dt)
        self.n_samples = 0
        self._final: float | None = None

    @property
    def is_final(self) -> bool:
        """True once no future sample can change the returned robustness."""
        return self._final is not None

    def update(self, sample: Mapping[str, float]) -> float:
        """Add the sample at time ``n_samples * dt`` and return the robustness at time 0."""
        missing = [name for name in self.names if name not in sample]
        if missing:
            raise STLSignalError(f"signal '{missing[0]}' missing from sample (got: {', '.join(sorted(sample))})")
        self.n_samples += 1
        if self._final is not None:
            return self._final
        self._root.advance({name: np.array([float(sample[name])]) for name in self.names})
        value = self._root.value0(self.n_samples)
        if isinstance(self._root, _Stream) and self._root.first is not None:
            self._final = self._root.first
        return value
