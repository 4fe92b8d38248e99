"""corridor.stl against peers: RTAMT, a naive evaluator of the definitions, and itself offline.

* Space robustness equals RTAMT 0.4.10's offline discrete-time semantics on hundreds of random
  formulas (depth <= 3, 2-3 signals, random intervals) at *every* index: both truncate windows at the
  end of the trace and use the identity for empty windows, so no index needs to be excluded.
* Left/right/combined time robustness equal a brute-force implementation of Donzé & Maler's
  definition: each predicate's value comes from literally shifting the signal sample by sample and
  re-checking its satisfaction; operators are evaluated index by index from their definitions.
* The online monitor equals the offline semantics on every prefix.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import rtamt

from corridor.stl import (
    Always,
    And,
    BinOp,
    Call,
    Const,
    Eventually,
    Formula,
    Implies,
    Neg,
    Not,
    OnlineMonitor,
    Or,
    Predicate,
    Until,
    Var,
    parse_formula,
    space_robustness,
    time_robustness,
)
from corridor.stl.online import _Stream, _UnboundedBoolean, _UnboundedTemporal
from corridor.stl.space import evaluate_expr, predicate_holds, predicate_robustness

INF = math.inf


# ---- random formulas and signals -------------------------------------------------------------------
def random_expr_predicate(rng: np.random.Generator, names: list[str]) -> Predicate:
    """Linear or |.| predicates with constants on a 0.5 grid (so ties happen on integer signals)."""
    x, y = (Var(n) for n in rng.choice(names, size=2, replace=False))
    c = Const(float(rng.integers(-4, 5)) / 2)
    lhs = [x, BinOp("-", x, y), Call("abs", (x,)), BinOp("+", BinOp("*", Const(2.0), x), y)][rng.integers(4)]
    return Predicate(lhs, str(rng.choice([">", ">=", "<", "<="])), c)


def random_interval(rng: np.random.Generator, allow_offset_inf: bool) -> tuple[float, float]:
    if rng.random() < 0.2:
        return (float(rng.integers(0, 3)) if allow_offset_inf else 0.0), INF
    a = int(rng.integers(0, 4))
    return float(a), float(a + rng.integers(0, 6))


def random_formula(rng: np.random.Generator, depth: int, names: list[str], offset_inf: bool = False) -> Formula:
    """A random STL tree of depth <= ``depth``."""
    if depth == 0 or rng.random() < 0.2:
        return random_expr_predicate(rng, names)
    kind = rng.integers(7)
    sub = [random_formula(rng, depth - 1, names, offset_inf) for _ in range(2)]
    if kind == 0:
        return Not(sub[0])
    if kind in (1, 2, 3):
        return (And, Or, Implies)[kind - 1](sub[0], sub[1])
    a, b = random_interval(rng, offset_inf)
    if kind == 4:
        return Always(sub[0], a, b)
    if kind == 5:
        return Eventually(sub[0], a, b)
    return Until(sub[0], sub[1], a, b)


def random_signals(rng: np.random.Generator, names: list[str], n: int) -> dict[str, np.ndarray]:
    values = {name: rng.normal(0.0, 2.0, n) for name in names}
    if rng.random() < 0.5:  # integer signals make ties and zero robustness common
        values = {name: np.round(v) for name, v in values.items()}
    return values


# ---- RTAMT -----------------------------------------------------------------------------------------
def rtamt_expr(expr) -> str:
    if isinstance(expr, Var):
        return expr.name
    if isinstance(expr, Const):
        return f"(0 - {-expr.value!r})" if expr.value < 0 else repr(expr.value)
    if isinstance(expr, BinOp):
        return f"({rtamt_expr(expr.left)} {expr.op} {rtamt_expr(expr.right)})"
    if isinstance(expr, Call):
        return f"{expr.func}({rtamt_expr(expr.args[0])})"
    raise TypeError(expr)


def rtamt_text(f: Formula, dt: float) -> str:
    """RTAMT syntax for our tree (interval bounds in seconds, fully parenthesised)."""
    def interval(a: float, b: float) -> str:
        return "" if b == INF else f"[{a:g}:{b:g}]"

    if isinstance(f, Predicate):
        return f"({rtamt_expr(f.lhs)} {f.op} {rtamt_expr(f.rhs)})"
    if isinstance(f, Not):
        return f"(not {rtamt_text(f.arg, dt)})"
    if isinstance(f, And | Or | Implies):
        word = {And: "and", Or: "or", Implies: "implies"}[type(f)]
        return f"({rtamt_text(f.left, dt)} {word} {rtamt_text(f.right, dt)})"
    if isinstance(f, Always | Eventually):
        word = "always" if isinstance(f, Always) else "eventually"
        return f"({word}{interval(f.a, f.b)}{rtamt_text(f.arg, dt)})"
    if isinstance(f, Until):
        return f"({rtamt_text(f.left, dt)} until{interval(f.a, f.b)} {rtamt_text(f.right, dt)})"
    raise TypeError(f)


def rtamt_robustness(f: Formula, signals: dict[str, np.ndarray], dt: float) -> np.ndarray:
    spec = rtamt.StlDiscreteTimeSpecification()
    spec.set_sampling_period(dt, "s", 0.1)
    for name in signals:
        spec.declare_var(name, "float")
    spec.declare_var("out", "float")
    spec.spec = f"out = {rtamt_text(f, dt)}"
    spec.parse()
    n = next(iter(signals.values())).size
    data = {"time": [k * dt for k in range(n)], **{k: v.tolist() for k, v in signals.items()}}
    return np.array([value for _, value in spec.evaluate(data)], dtype=float)


def test_space_robustness_equals_rtamt_on_random_formulas() -> None:
    rng = np.random.default_rng(20261122)
    for case in range(300):
        names = ["x", "y", "z"][: int(rng.integers(2, 4))]
        formula = random_formula(rng, 3, names)
        signals = random_signals(rng, names, int(rng.integers(2, 30)))  # RTAMT fails on 1 sample
        ours = space_robustness(formula, signals, 1.0)
        theirs = rtamt_robustness(formula, signals, 1.0)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9, err_msg=f"case {case}: {formula}")


def test_space_robustness_equals_rtamt_with_subsecond_period() -> None:
    rng = np.random.default_rng(7)
    for case in range(40):
        formula = random_formula(rng, 2, ["x", "y"])
        signals = random_signals(rng, ["x", "y"], 25)
        scaled = _scale_intervals(formula, 0.5)  # bounds in seconds on the 0.5 s sampling grid
        ours = space_robustness(scaled, signals, 0.5)
        theirs = rtamt_robustness(scaled, signals, 0.5)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9, err_msg=f"case {case}: {formula}")


def test_space_robustness_equals_rtamt_on_long_signals() -> None:
    """Long traces exercise the multi-block van Herk windows and the recursive until scan."""
    rng = np.random.default_rng(17)
    for case in range(12):
        formula = random_formula(rng, 2, ["x", "y"])
        signals = random_signals(rng, ["x", "y"], int(rng.integers(150, 400)))
        ours = space_robustness(formula, signals, 1.0)
        theirs = rtamt_robustness(formula, signals, 1.0)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9, err_msg=f"case {case}: {formula}")
    until = Until(random_expr_predicate(rng, ["x", "y"]), random_expr_predicate(rng, ["x", "y"]), 2.0, 9.0)
    signals = random_signals(rng, ["x", "y"], 700)
    np.testing.assert_allclose(space_robustness(until, signals, 1.0), rtamt_robustness(until, signals, 1.0),
                               rtol=0, atol=1e-9)


# ---- brute force of the definitions ----------------------------------------------------------------
def naive_tree(f: Formula, leaf, n: int, dt: float) -> np.ndarray:
    """Index-by-index evaluation of the min/max recursion straight from the definitions."""
    if isinstance(f, Predicate):
        return leaf(f)
    kids = [naive_tree(c, leaf, n, dt) for c in f.children()]
    out = np.empty(n)
    for k in range(n):
        if isinstance(f, Not):
            out[k] = -kids[0][k]
        elif isinstance(f, And | Or | Implies):
            left = -kids[0][k] if isinstance(f, Implies) else kids[0][k]
            out[k] = min(left, kids[1][k]) if isinstance(f, And) else max(left, kids[1][k])
        else:
            times = [j for j in range(k, n) if f.a - 1e-9 <= (j - k) * dt <= f.b + 1e-9]
            if isinstance(f, Always):
                out[k] = min((kids[0][j] for j in times), default=INF)
            elif isinstance(f, Eventually):
                out[k] = max((kids[0][j] for j in times), default=-INF)
            else:
                out[k] = max((min([kids[1][j], *kids[0][k:j]]) for j in times), default=-INF)
    return out


def shifted_holds(pred: Predicate, signals: dict[str, np.ndarray], shift: int, n: int) -> np.ndarray:
    """Satisfaction of ``pred`` on the signal shifted by ``shift`` samples (x_s[i] = x[i + shift])."""
    moved = {k: np.roll(v, -shift) for k, v in signals.items()}
    return predicate_holds(pred, predicate_robustness(pred, moved, n))


def brute_force_theta(pred: Predicate, signals: dict[str, np.ndarray], n: int, dt: float, side: int) -> np.ndarray:
    """theta+ (side=+1) or theta- (side=-1): shift the signal until satisfaction at k changes."""
    base = shifted_holds(pred, signals, 0, n)
    out = np.empty(n)
    for k in range(n):
        count = 0
        while 0 <= k + side * count < n and shifted_holds(pred, signals, side * count, n)[k] == base[k]:
            count += 1
        out[k] = (1.0 if base[k] else -1.0) * dt * count
    return out


def test_time_robustness_equals_brute_force_definition() -> None:
    rng = np.random.default_rng(11)
    for case in range(120):
        names = ["x", "y", "z"][: int(rng.integers(2, 4))]
        formula = random_formula(rng, 3, names, offset_inf=True)
        n = int(rng.integers(1, 20))
        signals = random_signals(rng, names, n)
        dt = float(rng.choice([1.0, 0.5]))
        right = {p: brute_force_theta(p, signals, n, dt, +1) for p in _predicates(formula)}
        left = {p: brute_force_theta(p, signals, n, dt, -1) for p in _predicates(formula)}
        ours = time_robustness(formula, signals, dt)
        msg = f"case {case}: {formula}"
        np.testing.assert_array_equal(ours.right, naive_tree(formula, right.__getitem__, n, dt), err_msg=msg)
        np.testing.assert_array_equal(ours.left, naive_tree(formula, left.__getitem__, n, dt), err_msg=msg)
        combined = {p: np.sign(right[p]) * np.minimum(np.abs(right[p]), np.abs(left[p])) for p in right}
        combined = naive_tree(formula, combined.__getitem__, n, dt)
        np.testing.assert_array_equal(ours.combined, combined, err_msg=msg)


def test_space_robustness_equals_naive_definition_with_offsets_and_unbounded() -> None:
    """Covers what RTAMT cannot express: G[a,inf] with a > 0, non-integer dt (0.25 s)."""
    rng = np.random.default_rng(5)
    for _ in range(150):
        formula = random_formula(rng, 3, ["x", "y"], offset_inf=True)
        n = int(rng.integers(1, 40))
        signals = random_signals(rng, ["x", "y"], n)
        leaf = {p: predicate_robustness(p, signals, n) for p in _predicates(formula)}.__getitem__
        expected = naive_tree(formula, leaf, n, 1.0)
        np.testing.assert_array_equal(space_robustness(formula, signals, 1.0), expected, err_msg=str(formula))
        scaled = _scale_intervals(formula, 0.25)
        np.testing.assert_array_equal(
            space_robustness(scaled, signals, 0.25), naive_tree(scaled, leaf, n, 0.25), err_msg=str(scaled)
        )


def _scale_intervals(f: Formula, factor: float) -> Formula:
    kids = [_scale_intervals(c, factor) for c in f.children()]
    if isinstance(f, Always | Eventually):
        return type(f)(kids[0], f.a * factor, f.b * factor)
    if isinstance(f, Until):
        return Until(kids[0], kids[1], f.a * factor, f.b * factor)
    if isinstance(f, Predicate):
        return f
    return type(f)(*kids)


def _predicates(f: Formula) -> set[Predicate]:
    if isinstance(f, Predicate):
        return {f}
    return set().union(*(_predicates(c) for c in f.children()))


# ---- online vs offline -----------------------------------------------------------------------------
def _online_supported(f: Formula) -> bool:
    if isinstance(f, Always | Eventually | Until):
        return all(math.isfinite(c.horizon()) for c in f.children())
    return all(_online_supported(c) for c in f.children())


def test_online_monitor_equals_offline_on_every_prefix() -> None:
    rng = np.random.default_rng(3)
    checked = 0
    while checked < 120:
        formula = random_formula(rng, 3, ["x", "y"], offset_inf=True)
        if not _online_supported(formula):
            with pytest.raises(ValueError, match="finite-horizon"):
                OnlineMonitor(formula, 0.5)
            continue
        checked += 1
        signals = random_signals(rng, ["x", "y"], int(rng.integers(1, 45)))
        monitor = OnlineMonitor(formula, 0.5)
        for m in range(1, signals["x"].size + 1):
            got = monitor.update({k: float(v[m - 1]) for k, v in signals.items()})
            prefix = {k: v[:m] for k, v in signals.items()}
            assert got == space_robustness(formula, prefix, 0.5)[0], (str(formula), m)


def _retained(node) -> int:
    own = len(node.finals) if isinstance(node, _Stream) else 0
    return own + sum(_retained(c) for c in node.children)


@pytest.mark.parametrize(
    "text",
    ["G((x > 0) -> F[0,5](y > 0.5))", "G[2,inf]((x > 0) U[0,3] (y > 0)) & F(x > 3)", "F[0,4](x > 0) | G(y < 9)"],
)
def test_online_monitor_memory_stays_bounded(text: str) -> None:
    """Incremental, not a recomputation: stored values stay O(horizon) over 3000 samples."""
    rng = np.random.default_rng(1)
    monitor = OnlineMonitor(text, 0.5)
    x, y = rng.normal(size=3000), rng.normal(size=3000)
    peak = 0
    for k in range(3000):
        monitor.update({"x": x[k], "y": y[k]})
        peak = max(peak, _retained(monitor._root))
    assert isinstance(monitor._root, _UnboundedTemporal | _UnboundedBoolean)
    assert peak <= 4 * 12 + 4  # a few horizons' worth of samples, never growing with the trace
    assert monitor.update({"x": 0.0, "y": 0.0}) == space_robustness(
        text, {"x": np.append(x, 0.0), "y": np.append(y, 0.0)}, 0.5
    )[0]


def test_online_monitor_is_final_after_horizon() -> None:
    monitor = OnlineMonitor("G[0,1](x > 0) & F[0,2](y > 1)", 0.5)
    values = [monitor.update({"x": 1.0 + k, "y": float(k)}) for k in range(12)]
    assert monitor.is_final
    assert values[-1] == values[5] == space_robustness(
        "G[0,1](x > 0) & F[0,2](y > 1)", {"x": 1.0 + np.arange(12.0), "y": np.arange(12.0)}, 0.5
    )[0]


def test_expression_evaluation_matches_numpy() -> None:
    dx, dy = np.array([3.0, 6.0]), np.array([4.0, 8.0])
    expr = parse_formula("sqrt(dx^2 + dy^2) > 10").lhs
    np.testing.assert_allclose(evaluate_expr(expr, {"dx": dx, "dy": dy}, 2), [5.0, 10.0])
    assert isinstance(parse_formula("-(x) > 1").lhs, Neg)


def test_printed_formulas_parse_back_to_equal_trees() -> None:
    rng = np.random.default_rng(23)
    for _ in range(300):
        formula = random_formula(rng, 3, ["x", "y", "z"], offset_inf=True)
        assert parse_formula(str(formula)) == formula, str(formula)
