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

All kernels are O(n) (see ``kernels``). ``evaluate_tree`` is shared with the time robustness, which
runs the same recursion with different leaf signals.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from corridor.analysis.stl import kernels
from corridor.analysis.stl.formula import (
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
)
from corridor.analysis.stl.parser import as_formula

_INDEX_EPS = 1e-9  # [samples] tolerance when turning interval bounds in seconds into indices


class STLSignalError(KeyError):
    """A formula reads a signal that was not supplied (or supplied with the wrong shape)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def interval_indices(a: float, b: float, dt: float) -> tuple[int, float]:
    """Sample offsets ``(lo, hi)`` whose times lie in ``[a, b]``; ``hi`` is ``inf`` when ``b`` is."""
    lo = math.ceil(a / dt - _INDEX_EPS)
    hi = math.inf if math.isinf(b) else float(math.floor(b / dt + _INDEX_EPS))
    if hi < lo:
        raise ValueError(f"interval [{a}, {b}] contains no sample time for dt = {dt}")
    return lo, hi


def check_signals(formula: Formula, signals: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], int]:
    """Float arrays of the formula's signals and their common length; raise ``STLSignalError``."""
    arrays: dict[str, np.ndarray] = {}
    for name in sorted(formula.signal_names()):
        if name not in signals:
            known = ", ".join(sorted(signals)) or "none"
            raise STLSignalError(f"signal '{name}' is not recorded (known signals: {known})")
        arrays[name] = np.asarray(signals[name], dtype=float)
    lengths = {a.shape for a in arrays.values()}
    if len(lengths) > 1 or any(a.ndim != 1 for a in arrays.values()):
        raise STLSignalError(f"signals must be 1-D of one length, got shapes {sorted(lengths)}")
    n = next(iter(arrays.values())).size if arrays else 0
    return arrays, n


# ---- expressions -----------------------------------------------------------------------------------
_BINARY: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "^": np.power,
}
_CALLS: dict[str, Callable[..., np.ndarray]] = {
    "abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "min": np.minimum, "max": np.maximum,
}


def evaluate_expr(expr: Expr, signals: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """The expression's value at every sample (length ``n``)."""
    if isinstance(expr, Var):
        return np.asarray(signals[expr.name], dtype=float)
    if isinstance(expr, Const):
        return np.full(n, expr.value)
    if isinstance(expr, Neg):
        return -evaluate_expr(expr.arg, signals, n)
    if isinstance(expr, BinOp):
        return _BINARY[expr.op](evaluate_expr(expr.left, signals, n), evaluate_expr(expr.right, signals, n))
    if isinstance(expr, Call):
        return _CALLS[expr.func](*(evaluate_expr(a, signals, n) for a in expr.args))
    raise TypeError(f"not an expression: {expr!r}")


def predicate_robustness(pred: Predicate, signals: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Signed distance to the predicate's boundary: ``lhs - rhs`` for ``>``/``>=``, else ``rhs - lhs``."""
    lhs = evaluate_expr(pred.lhs, signals, n)
    rhs = evaluate_expr(pred.rhs, signals, n)
    return lhs - rhs if pred.op in (">", ">=") else rhs - lhs


def predicate_holds(pred: Predicate, rho: np.ndarray) -> np.ndarray:
    """Boolean satisfaction from the predicate's robustness (strict ops need ``rho > 0``)."""
    return rho > 0 if pred.op in (">", "<") else rho >= 0


# ---- formulas --------------------------------------------------------------------------------------
LeafFn = Callable[[Predicate], np.ndarray]


def apply_operator(formula: Formula, children: list[np.ndarray], dt: float) -> np.ndarray:
    """One operator's min/max semantics on its children's traces (all of one length)."""
    if isinstance(formula, Not):
        return -children[0]
    if isinstance(formula, And):
        return np.minimum(children[0], children[1])
    if isinstance(formula, Or):
        return np.maximum(children[0], children[1])
    if isinstance(formula, Implies):
        return np.maximum(-children[0], children[1])
    if isinstance(formula, Always | Eventually | Until):
        lo, hi = interval_indices(formula.a, formula.b, dt)
        if isinstance(formula, Always):
            return kernels.window_min(children[0], lo, hi)
        if isinstance(formula, Eventually):
            return kernels.window_max(children[0], lo, hi)
        return kernels.until(children[0], children[1], lo, hi)
    raise TypeError(f"not an STL operator: {formula!r}")


def evaluate_tree(formula: Formula, leaf: LeafFn, dt: float) -> np.ndarray:
    """Bottom-up evaluation: ``leaf(predicate)`` gives the leaf traces, operators combine them."""
    if isinstance(formula, Predicate):
        return leaf(formula)
    return apply_operator(formula, [evaluate_tree(c, leaf, dt) for c in formula.children()], dt)


def space_robustness(spec: str | Formula, signals: Mapping[str, np.ndarray], dt: float) -> np.ndarray:
    """Space robustness trace ``rho[k]`` of the formula at every sample time ``k*dt`` [s]."""
    if dt <= 0:
        raise ValueError(f"dt must be > 0, got {dt}")
    formula = as_formula(spec)
    arrays, n = check_signals(formula, signals)
    return evaluate_tree(formula, lambda p: predicate_robustness(p, arrays, n), dt)
