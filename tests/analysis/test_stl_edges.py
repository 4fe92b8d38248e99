"""STL edge semantics found by an independent oracle (issue 18).

* A formula that reads no signal takes its trace length from the signals given (offline = online).
* NaN means "unknown" and propagates: a robustness value is NaN exactly when its definition reads a
  NaN sample; time robustness caps runs at NaN samples (as at the ends of the trace), so it is NaN at
  the same indices as space robustness; ``evaluate_spec`` never reports a NaN as satisfied. The same
  samples give the same values whatever the trace length (the kernels switch algorithms at 64).
* ``dt`` must be a finite number > 0 in every public entry point.
* Flat specs of hundreds of predicates work (parse, str, ==, offline, online); nesting deeper than
  the documented limit is a clean error naming the limit.
"""

from __future__ import annotations

import functools
import math
import operator

import numpy as np
import pytest

from corridor.stl import (
    Always,
    And,
    Const,
    Eventually,
    Formula,
    Implies,
    Not,
    OnlineMonitor,
    Or,
    Predicate,
    STLSignalError,
    STLSyntaxError,
    Until,
    Var,
    evaluate_spec,
    parse_formula,
    space_robustness,
    time_robustness,
    var,
)
from corridor.stl.space import interval_indices

INF = math.inf
LENGTHS = (5, 63, 64, 65, 100, 1000)


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal arrays, NaN where the other is NaN."""
    return bool(np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True))


# ---- 1. formulas that read no signal ------------------------------------------------------------------
def test_formula_without_signals_takes_its_length_from_the_given_signals() -> None:
    signals = {"x": np.arange(5.0)}
    trace = space_robustness("G[0,2](1 > 0)", signals, 1.0)
    assert same(trace, np.ones(5))
    result = evaluate_spec("G[0,2](1 > 0)", signals, 1.0)
    assert result.satisfied and result.space == 1.0 and result.time > 0
    monitor = OnlineMonitor("G[0,2](1 > 0)", 1.0)
    online = [monitor.update({"x": v}) for v in signals["x"]]
    assert online[-1] == trace[0] == 1.0
    assert same(time_robustness("F[0,1](0 > 1)", signals, 1.0).right, [-4.0, -3.0, -2.0, -1.0, -1.0])


def test_formula_without_signals_refuses_signals_of_different_lengths() -> None:
    with pytest.raises(STLSignalError, match="one length"):
        space_robustness("2 > 1", {"x": np.zeros(3), "y": np.zeros(4)}, 1.0)
    with pytest.raises(ValueError, match="empty"):
        evaluate_spec("2 > 1", {}, 1.0)


# ---- 2. NaN ------------------------------------------------------------------------------------------
def nan_min(values: list[float], empty: float) -> float:
    """Min that propagates NaN (the reference semantics)."""
    if any(math.isnan(v) for v in values):
        return math.nan
    return min(values, default=empty)


def nan_max(values: list[float], empty: float) -> float:
    return -nan_min([-v for v in values], -empty)


def naive(f: Formula, x: dict[str, np.ndarray], dt: float) -> np.ndarray:
    """Index-by-index evaluation of the definitions with NaN propagation."""
    n = next(iter(x.values())).size
    if isinstance(f, Predicate):
        lhs, rhs = (np.array([_expr(e, x, k) for k in range(n)]) for e in (f.lhs, f.rhs))
        return lhs - rhs if f.op in (">", ">=") else rhs - lhs
    kids = [naive(c, x, dt) for c in f.children()]
    if isinstance(f, Not):
        return -kids[0]
    if isinstance(f, And | Or | Implies):
        left = -kids[0] if isinstance(f, Implies) else kids[0]
        pick = nan_min if isinstance(f, And) else nan_max
        return np.array([pick([left[k], kids[1][k]], 0.0) for k in range(n)])
    lo, hi = interval_indices(f.a, f.b, dt)
    out = np.empty(n)
    for k in range(n):
        window = range(k + lo, n if math.isinf(hi) else min(k + int(hi), n - 1) + 1)
        if isinstance(f, Always):
            out[k] = nan_min([kids[0][t] for t in window], INF)
        elif isinstance(f, Eventually):
            out[k] = nan_max([kids[0][t] for t in window], -INF)
        else:
            out[k] = nan_max([nan_min([kids[1][t], *kids[0][k:t]], INF) for t in window], -INF)
    return out


def _expr(e, x: dict[str, np.ndarray], k: int) -> float:
    return float(x[e.name][k]) if isinstance(e, Var) else float(e.value)


def random_formula(rng: np.random.Generator, depth: int) -> Formula:
    if depth == 0 or rng.random() < 0.25:
        name = str(rng.choice(["x", "y"]))
        return Predicate(Var(name), str(rng.choice([">", "<="])), Const(float(rng.integers(-2, 3))))
    kind = int(rng.integers(7))
    sub = [random_formula(rng, depth - 1) for _ in range(2)]
    if kind == 0:
        return Not(sub[0])
    if kind in (1, 2, 3):
        return (And, Or, Implies)[kind - 1](sub[0], sub[1])
    a = float(rng.integers(0, 3))
    b = INF if rng.random() < 0.3 else a + float(rng.integers(0, 5))
    return (Always, Eventually, Until)[kind - 4](*sub[: 1 if kind < 6 else 2], a, b)


def nan_signals(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    out = {}
    for name in ("x", "y"):
        v = np.round(rng.normal(0.0, 2.0, n))
        v[rng.random(n) < 0.08] = np.nan
        out[name] = v
    return out


@pytest.mark.parametrize("n", [5, 63, 64, 65, 100])
def test_space_robustness_with_nan_equals_propagating_definition(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(60):
        f = random_formula(rng, 3)
        x = nan_signals(rng, n)
        assert same(space_robustness(f, x, 1.0), naive(f, x, 1.0)), str(f)


PATTERN = np.array([1.0, np.nan, 3.0, -1.0, 2.0])
PATTERN_FORMULAS = [
    "(x > 0) U (x > 2.5)", "(x > 0) U[0,2] (x > 2.5)", "(x > 0) U[1,3] (x > 2.5)", "(x > -2) U (x > 2.5)",
    "G(x > 0)", "F(x > 2.5)", "G[0,1](x > 0)", "F[2,3](x > 2.5)", "x <= 0", "!(x > 0)",
    "G[0,inf](x > -5) & F[0,2](x > 0)", "(x > 0) -> F[0,1](x > 2)",
]


@pytest.mark.parametrize("text", PATTERN_FORMULAS)
def test_same_samples_give_same_values_at_every_trace_length(text: str) -> None:
    """The pattern at the end of a longer trace: every window is truncated where the pattern's own
    trace ends, so its five values must equal those of the bare pattern (NaN included)."""
    bare = space_robustness(text, {"x": PATTERN}, 1.0)
    bare_time = time_robustness(text, {"x": PATTERN}, 1.0).right
    for n in LENGTHS:
        padding = np.where(np.arange(n - 5) % 3 == 0, 4.0, -3.0)
        at_end = np.concatenate((padding, PATTERN))
        assert same(space_robustness(text, {"x": at_end}, 1.0)[-5:], bare), (text, n)
        time_trace = time_robustness(text, {"x": at_end}, 1.0).right  # reads forward only
        assert same(time_trace[-5:], bare_time), (text, n)
        assert same(np.isnan(time_trace), np.isnan(space_robustness(text, {"x": at_end}, 1.0)))
        at_start = np.concatenate((PATTERN, padding))  # windows that fit in the pattern agree
        start_trace = space_robustness(text, {"x": at_start}, 1.0)
        horizon = parse_formula(text).horizon()
        fit = 2 if math.isinf(horizon) else 5 - int(horizon)  # unbounded ones read the NaN at 0 and 1
        assert same(start_trace[:fit], bare[:fit]), (text, n)


def test_until_at_zero_with_nan_does_not_depend_on_trace_length() -> None:
    for n in LENGTHS:
        x = np.concatenate((PATTERN, np.full(n - 5, -1.0)))
        assert np.isnan(space_robustness("(x > 0) U (x > 2.5)", {"x": x}, 1.0)[0]), n
        x_end = np.concatenate((np.full(n - 5, 1.0), PATTERN))
        assert np.isnan(space_robustness("(x > 0) U (x > 2.5)", {"x": x_end}, 1.0)[n - 5]), n


def test_nan_is_nan_under_negation_and_flipped_comparison() -> None:
    x = {"x": np.array([1.0, np.nan, -1.0])}
    for text in ("x <= 0", "!(x > 0)", "x > 0", "!(x <= 0)"):
        rho = space_robustness(text, x, 1.0)
        assert np.isnan(rho[1]) and not np.isnan(rho[0]) and not np.isnan(rho[2]), text
    assert same(space_robustness("x <= 0", x, 1.0), space_robustness("!(x > 0)", x, 1.0))


def test_time_robustness_is_nan_on_nan_samples_and_caps_runs_there() -> None:
    theta = time_robustness("x > 0", {"x": np.array([1.0, 1.0, np.nan, 1.0, -1.0])}, 0.5)
    assert same(theta.right, [1.0, 0.5, np.nan, 0.5, -0.5])
    assert same(theta.left, [0.5, 1.0, np.nan, 0.5, -0.5])
    assert same(theta.combined, [0.5, 0.5, np.nan, 0.5, -0.5])
    rng = np.random.default_rng(7)
    for _ in range(100):
        f = random_formula(rng, 3)
        x = nan_signals(rng, 40)
        space = space_robustness(f, x, 1.0)
        theta = time_robustness(f, x, 1.0)
        for trace in (theta.left, theta.right, theta.combined):
            assert same(np.isnan(trace), np.isnan(space)), str(f)
        known = ~np.isnan(space) & (space != 0)
        assert same(np.sign(theta.right[known]), np.sign(space[known])), str(f)


def test_evaluate_spec_never_counts_nan_as_satisfied() -> None:
    x = {"x": np.array([1.0, 2.0, np.nan, 3.0, 4.0, 5.0])}
    for text in ("G(x > 0)", "F(x > 0)", "!(x <= 0) U (x > 4)", "x > 0 -> G(x > 0)", "G(x <= 0) | G(x > 0)"):
        r = evaluate_spec(text, x, 0.1)
        assert not r.satisfied and math.isnan(r.space) and math.isnan(r.time), text
    r = evaluate_spec("G[0,0.1](x > 0)", x, 0.1)  # does not read the NaN sample
    assert r.satisfied and r.space == 1.0


def test_online_monitor_with_nan_equals_offline_on_every_prefix() -> None:
    rng = np.random.default_rng(3)
    for _ in range(40):
        f = random_formula(rng, 3)
        if any(math.isinf(c.horizon()) for node in _temporal_nodes(f) for c in node.children()):
            continue  # refused online (unbounded operand of a temporal operator)
        x = nan_signals(rng, 30)
        monitor = OnlineMonitor(f, 1.0)
        for m in range(1, 31):
            got = monitor.update({"x": x["x"][m - 1], "y": x["y"][m - 1]})
            want = space_robustness(f, {k: v[:m] for k, v in x.items()}, 1.0)[0]
            assert same([got], [want]), (str(f), m)


def _temporal_nodes(f: Formula) -> list[Formula]:
    out, stack = [], [f]
    while stack:
        node = stack.pop()
        if isinstance(node, Always | Eventually | Until):
            out.append(node)
        stack.extend(node.children())
    return out


# ---- 3. dt -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dt", [math.inf, math.nan, 0.0, -0.1, -math.inf])
def test_bad_dt_is_refused_with_a_clear_message(dt: float) -> None:
    x = {"x": np.array([1.0, 2.0, 3.0])}
    calls = [lambda: space_robustness("G[0,1](x > 0)", x, dt), lambda: time_robustness("x > 0", x, dt),
             lambda: evaluate_spec("F(x > 0)", x, dt), lambda: OnlineMonitor("G[0,1](x > 0)", dt)]
    for call in calls:
        with pytest.raises(ValueError, match=r"dt must be a finite number > 0 \[s\]"):
            call()


# ---- 4. deep and long formulas -----------------------------------------------------------------------
def test_conjunction_of_400_predicates_parses_prints_and_evaluates() -> None:
    n_pred, n = 400, 30
    rng = np.random.default_rng(0)
    x = {f"x{i}": rng.normal(5.0, 1.0, n) for i in range(n_pred)}
    text = " & ".join(f"(x{i} > {i % 3})" for i in range(n_pred))
    f = parse_formula(text)
    assert parse_formula(str(f)) == f and hash(parse_formula(str(f))) == hash(f)
    want = np.min([x[f"x{i}"] - i % 3 for i in range(n_pred)], axis=0)
    assert same(space_robustness(f, x, 0.1), want)
    assert evaluate_spec(f, x, 0.1).space == want[0]
    monitor = OnlineMonitor(f, 0.1)
    assert monitor.update({k: v[0] for k, v in x.items()}) == want[0]
    disj = parse_formula(" | ".join(f"(x{i} > {i % 3})" for i in range(n_pred)))
    assert same(space_robustness(disj, x, 0.1), np.max([x[f"x{i}"] - i % 3 for i in range(n_pred)], axis=0))


def test_python_built_chain_of_1000_predicates_works_everywhere() -> None:
    n_pred = 1000
    preds = [var(f"x{i}") > float(i) for i in range(n_pred)]
    f = functools.reduce(operator.and_, preds)  # left-deep: depth 1000
    g = functools.reduce(operator.and_, [var(f"x{i}") > float(i) for i in range(n_pred)])
    assert f == g and hash(f) == hash(g) and f != functools.reduce(operator.or_, preds)
    assert parse_formula(str(f)) == f  # printed flat: "((x0 > 0.0) & (x1 > 1.0) & ...)"
    assert str(f).count("(") == n_pred + 1
    assert parse_formula(str(functools.reduce(operator.or_, preds))) == functools.reduce(operator.or_, preds)
    assert len(repr(f)) > 0 and f.horizon() == 0.0 and len(f.signal_names()) == n_pred
    x = {f"x{i}": np.array([i + 1.0, i + 2.0, i - 0.5]) for i in range(n_pred)}
    assert same(space_robustness(f, x, 1.0), [1.0, 2.0, -0.5])
    assert same(time_robustness(f, x, 1.0).right, [2.0, 1.0, -1.0])
    monitor = OnlineMonitor(f, 1.0)
    assert [monitor.update({k: v[m] for k, v in x.items()}) for m in range(3)] == [1.0, 1.0, 1.0]
    deep_g = OnlineMonitor(functools.reduce(operator.or_, preds).always(0, 1), 1.0)
    assert [deep_g.update({k: v[m] for k, v in x.items()}) for m in range(3)] == [1.0, 1.0, 1.0]


def test_long_implication_and_until_chains_parse_without_recursion() -> None:
    text = " -> ".join(f"(x > {i})" for i in range(500))
    f = parse_formula(text)
    assert isinstance(f, Implies) and isinstance(f.right, Implies)
    assert space_robustness(f, {"x": np.array([0.5])}, 1.0)[0] == 497.5  # max(i - 0.5 for i < 499, 0.5 - 499)
    assert parse_formula(str(f)) == f
    until = parse_formula(" U[0,1] ".join(f"(x > {-i})" for i in range(300)))
    assert isinstance(until, Until) and until.horizon() == 299.0 and parse_formula(str(until)) == until
    assert not math.isnan(space_robustness(until, {"x": np.zeros(5)}, 1.0)[0])
    assert parse_formula("!" * 2000 + "(x > 0)") == functools.reduce(lambda g, _: Not(g), range(2000),
                                                                     parse_formula("x > 0"))


def test_deep_nesting_is_a_clean_error_naming_the_limit() -> None:
    for depth in (101, 200, 5000):
        with pytest.raises(STLSyntaxError, match="nests deeper than 100 levels"):
            parse_formula("(" * depth + "x > 0" + ")" * depth)
        with pytest.raises(STLSyntaxError, match="nests deeper than 100 levels"):
            parse_formula("(" * depth + "x" + ")" * depth + " > 0")
        with pytest.raises(STLSyntaxError, match="nests deeper than 100 levels"):
            parse_formula("-" * depth + "x > 0")
    assert parse_formula("(" * 100 + "x > 0" + ")" * 100) == parse_formula("x > 0")
    assert parse_formula("(" * 100 + "x" + ")" * 100 + " > 0") == parse_formula("x > 0")
    deep = functools.reduce(lambda g, _: Not(g.always(0, 1)), range(150), parse_formula("x > 0"))
    assert space_robustness(deep, {"x": np.ones(4)}, 1.0).shape == (4,)  # offline: any depth
    with pytest.raises(ValueError, match="nests deeper than 100 levels"):
        OnlineMonitor(deep, 1.0)  # online: the documented limit
