"""Discrete-time quantitative (space) robustness of STL over uniformly sampled signals.

Standard min/max semantics (Fainekos & Pappas 2009; Donzé & Maler 2010), evaluated for every start
index at once: ``space_robustness`` returns ``rho[k]``, the robustness of the formula at ``t = k*dt``.

* ``lhs > rhs`` and ``lhs >= rhs`` give ``lhs - rhs``; ``<``/``<=`` give ``rhs - lhs``.
* ``!`` negates, ``&`` is min, ``|`` is max, ``a -> b`` is ``max(-a, b)``.
* ``G[a,b]`` is a sliding min, ``F[a,b]`` a sliding max over the samples whose times fall in
  ``t + [a, b]``, i.e. indices ``k + ceil(a/dt) .. k + floor(b/dt)``; ``U[a,b]`` takes
  ``max_{t'} min(rho_right[t'], min rho_left[k .. t'-1])`` over the same indices.
* **End of trace**: windows are truncated to the samples that exist; an empty window gives the
  operator's identity (``+inf`` for G, ``-inf`` for F and U). This is RTAMT's offline discrete-time
  convention (``StlDiscreteTimeSpecification.evaluate``), so values agree with RTAMT exactly; only
  indices whose whole horizon lies inside the trace are free of the convention.
* **NaN is unknown, and it propagates**: ``rho[k]`` is NaN exactly when the definition of the value at
  ``k`` reads a NaN (a NaN sample, or one an expression made, e.g. ``sqrt`` of a negative): a predicate
  at a NaN sample, ``!``/``&``/``|``/``->`` of a NaN, ``G``/``F`` whose window holds a NaN, ``U`` when
  ``right`` at a time of its window or ``left`` before it is NaN. Never otherwise: a NaN outside every
  window read leaves the value alone, so values do not depend on the trace length or on which kernel
  (short or long scan) ran. A missing sample never helps a formula: it is neither true nor false, and
  ``evaluate_spec`` reports a NaN robustness as not satisfied. (RTAMT does not define NaN; its Python
  ``min``/``max`` give order-dependent results, which is why we do not follow it here.)
* **Trace length** is the common length of the signals the formula reads; a formula that reads none
  (``G[0,2](1 > 0)``) takes it from the signals given.
* ``dt`` must be a finite number > 0 (``check_dt``).

All kernels are O(n) (see ``kernels``). ``evaluate_tree`` is shared with the time robustness, which
runs the same bottom-up evaluation with different leaf signals; it is iterative, so formulas of any
depth evaluate (a conjunction of hundreds of predicates is a flat, legitimate spec).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from corridor.stl import kernels
from corridor.stl.formula import (
    Always,
    And,
    BinOp,
    Call,
    Const,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Until,
    Var,
    fold,
)
from corridor.stl.parser import as_formula

_INDEX_EPS = 1e-9  # [samples] tolerance when turning interval bounds in seconds into indices


class STLSignalError(KeyError):
    """A formula reads a signal that was not supplied (or supplied with the wrong shape)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def check_dt(dt: float) -> float:
    """``dt`` as a float; ``ValueError`` unless it is a finite number > 0 [s]."""
    try:
        value = float(dt)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"dt must be a finite number > 0 [s], got {dt!r}")
    return value


def interval_indices(a: float, b: float, dt: float) -> tuple[int, float]:
    """Sample offsets ``(lo, hi)`` whose times lie in ``[a, b]``; ``hi`` is ``inf`` when ``b`` is."""
    dt = check_dt(dt)
    if not math.isfinite(a / dt) or not (math.isinf(b) or math.isfinite(b / dt)):
        raise ValueError(f"interval [{a}, {b}] has too many samples for dt = {dt}")
    lo = math.ceil(a / dt - _INDEX_EPS)
    hi = math.inf if math.isinf(b) else float(math.floor(b / dt + _INDEX_EPS))
    if hi < lo:
        raise ValueError(f"interval [{a}, {b}] contains no sample time for dt = {dt}")
    return lo, hi


def check_signals(formula: Formula, signals: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], int]:
    """Float arrays of the formula's signals and the trace length; raise ``STLSignalError``.

    The length is that of the signals the formula reads; a formula that reads none (``G(1 > 0)``)
    takes it from all the signals given (which must then agree), so it is evaluated on as many
    samples as the online monitor would have seen.
    """
    arrays: dict[str, np.ndarray] = {}
    for name in sorted(formula.signal_names()):
        if name not in signals:
            known = ", ".join(sorted(signals)) or "none"
            raise STLSignalError(f"signal '{name}' is not recorded (known signals: {known})")
        arrays[name] = np.asarray(signals[name], dtype=float)
    shaped = arrays or {name: np.asarray(value) for name, value in signals.items()}
    shapes = {a.shape for a in shaped.values()}
    if len(shapes) > 1 or any(a.ndim != 1 for a in shaped.values()):
        raise STLSignalError(f"signals must be 1-D of one length, got shapes {sorted(shapes)}")
    n = next(iter(shaped.values())).size if shaped else 0
    return arrays, n


# ---- expressions -----------------------------------------------------------------------------------
_BINARY: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "^": np.power,
}
_CALLS: dict[str, Callable[..., np.ndarray]] = {
    "abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "min": np.minimum, "max": np.maximum,
}


def evaluate_expr(expr: Expr, signals: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """The expression's value at every sample (length ``n``); NaN where it is undefined."""
    def one(node: Expr, args: list[np.ndarray]) -> np.ndarray:
        if isinstance(node, Var):
            return np.asarray(signals[node.name], dtype=float)
        if isinstance(node, Const):
            return np.full(n, node.value)
        if isinstance(node, Neg):
            return -args[0]
        if isinstance(node, BinOp):
            return _BINARY[node.op](*args)
        if isinstance(node, Call):
            return _CALLS[node.func](*args)
        raise TypeError(f"not an expression: {node!r}")

    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # NaN / inf are the answer
        return fold(expr, one)


def predicate_robustness(pred: Predicate, signals: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Signed distance to the predicate's boundary: ``lhs - rhs`` for ``>``/``>=``, else ``rhs - lhs``."""
    lhs = evaluate_expr(pred.lhs, signals, n)
    rhs = evaluate_expr(pred.rhs, signals, n)
    rho: np.ndarray = lhs - rhs if pred.op in (">", ">=") else rhs - lhs
    return rho


def predicate_holds(pred: Predicate, rho: np.ndarray) -> np.ndarray:
    """Boolean satisfaction from the predicate's robustness (strict ops need ``rho > 0``).

    False where ``rho`` is NaN: callers that must tell "unknown" apart test ``np.isnan(rho)``.
    """
    return rho > 0 if pred.op in (">", "<") else rho >= 0


# ---- formulas --------------------------------------------------------------------------------------
LeafFn = Callable[[Predicate], np.ndarray]


def apply_operator(formula: Formula, children: list[np.ndarray], dt: float) -> np.ndarray:
    """One operator's min/max semantics on its children's traces (all of one length)."""
    trace: np.ndarray
    if isinstance(formula, Not):
        trace = -children[0]
        return trace
    if isinstance(formula, And):
        trace = np.minimum(children[0], children[1])
        return trace
    if isinstance(formula, Or):
        trace = np.maximum(children[0], children[1])
        return trace
    if isinstance(formula, Implies):
        trace = np.maximum(-children[0], children[1])
        return trace
    if isinstance(formula, Always | Eventually | Until):
        lo, hi = interval_indices(formula.a, formula.b, dt)
        if isinstance(formula, Always):
            return kernels.window_min(children[0], lo, hi)
        if isinstance(formula, Eventually):
            return kernels.window_max(children[0], lo, hi)
        return kernels.until(children[0], children[1], lo, hi)
    raise TypeError(f"not an STL operator: {formula!r}")


def evaluate_tree(formula: Formula, leaf: LeafFn, dt: float) -> np.ndarray:
    """Bottom-up evaluation (iterative): ``leaf(predicate)`` gives the leaf traces, operators combine."""
    def one(node: Formula, children: list[np.ndarray]) -> np.ndarray:
        return leaf(node) if isinstance(node, Predicate) else apply_operator(node, children, dt)

    return fold(formula, one)


def space_robustness(spec: str | Formula, signals: Mapping[str, np.ndarray], dt: float) -> np.ndarray:
    """Space robustness trace ``rho[k]`` of the formula at every sample time ``k*dt`` [s]."""
    dt = check_dt(dt)
    formula = as_formula(spec)
    arrays, n = check_signals(formula, signals)
    return evaluate_tree(formula, lambda p: predicate_robustness(p, arrays, n), dt)
