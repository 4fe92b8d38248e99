"""Hand-computed values, parser, kernels and API of corridor.stl."""

from __future__ import annotations

import math

import numpy as np
import pytest

from corridor.stl import (
    Always,
    And,
    BinOp,
    Const,
    Eventually,
    Implies,
    Not,
    Or,
    Predicate,
    STLSignalError,
    STLSyntaxError,
    Until,
    Var,
    evaluate_spec,
    kernels,
    parse_formula,
    space_robustness,
    time_robustness,
    var,
)

X = np.array([3.0, 2.0, 0.5, 4.0, 5.0, 1.5])


# ---- space robustness by hand ----------------------------------------------------------------------
def test_always_on_small_vector() -> None:
    # rho(x > 1) = [2, 1, -0.5, 3, 4, 0.5]; min over k..k+2, truncated at the end
    np.testing.assert_array_equal(space_robustness("G[0,2](x > 1)", {"x": X}, 1.0), [-0.5, -0.5, -0.5, 0.5, 0.5, 0.5])


def test_eventually_with_offset_and_empty_window() -> None:
    np.testing.assert_array_equal(space_robustness("F[1,2](x > 1)", {"x": X}, 1.0), [1, 3, 4, 4, 0.5, -math.inf])


def test_interval_seconds_become_sample_offsets() -> None:
    fine = space_robustness("G[0,0.2](x > 1)", {"x": X}, 0.1)  # 0, 0.1, 0.2 s: three samples
    np.testing.assert_array_equal(fine, space_robustness("G[0,2](x > 1)", {"x": X}, 1.0))


def test_until_by_hand() -> None:
    signals = {"x": np.array([1.0, 1.0, -1.0, 1.0]), "y": np.array([-2.0, -1.0, 3.0, -1.0])}
    np.testing.assert_array_equal(space_robustness("(x > 0) U[0,2] (y > 0)", signals, 1.0), [1, 1, 3, -1])
    np.testing.assert_array_equal(space_robustness("(x > 0) U[1,2] (y > 0)", signals, 1.0), [1, 1, -1, -math.inf])


def test_nonlinear_and_linear_predicates() -> None:
    dx, dy = np.array([3.0, 6.0, 8.0]), np.array([4.0, 8.0, 6.0])
    np.testing.assert_allclose(space_robustness("sqrt(dx^2 + dy^2) > 10", {"dx": dx, "dy": dy}, 1.0), [-5, 0, 0])
    z = np.array([1.0, 0.0, -1.0])
    np.testing.assert_allclose(space_robustness("dx - dy >= 2*z + 1", {"dx": dx, "dy": dy, "z": z}, 1.0), [-4, -3, 3])
    np.testing.assert_allclose(space_robustness("max(abs(dx - 7), min(dy, 5)) < 4", {"dx": dx, "dy": dy}, 1.0),
                               [0, -1, -1])


# ---- time robustness by hand -----------------------------------------------------------------------
def test_predicate_time_robustness_counts_runs() -> None:
    theta = time_robustness("x > 1", {"x": X}, 0.5)  # chi = + + - + + +
    np.testing.assert_array_equal(theta.right, 0.5 * np.array([2, 1, -1, 3, 2, 1]))
    np.testing.assert_array_equal(theta.left, 0.5 * np.array([1, 2, -1, 1, 2, 3]))
    np.testing.assert_array_equal(theta.combined, 0.5 * np.array([1, 1, -1, 1, 2, 1]))


def test_time_robustness_of_temporal_operators() -> None:
    assert time_robustness("F[0,2](x > 1)", {"x": X}, 1.0).right[0] == 2.0  # max(2, 1, -1)
    assert time_robustness("G[0,2](x > 1)", {"x": X}, 1.0).left[0] == -1.0  # min(1, 2, -1)
    assert time_robustness("!G[3,5](x > 1)", {"x": X}, 1.0).right[0] == -1.0  # -min(3, 2, 1)


def test_evaluate_spec_on_brief_example() -> None:
    dt = 0.5
    t = dt * np.arange(80)  # 0 .. 39.5 s
    signals = {"gap_lead": 10 - 0.1 * t, "ahead_of_lead": t - 12.0, "unused": np.zeros(80)}
    result = evaluate_spec("G[0,30](gap_lead > 5) & F[0,20](ahead_of_lead > 0)", signals, dt)
    assert result.satisfied
    assert result.space == pytest.approx(2.0)  # gap 7 m at t = 30 s; ahead reaches 8 m at t = 20 s
    assert result.time_right == 10.0  # gap > 5 keeps holding for the 10 s recorded after t = 30 s
    assert result.time_left == 0.5  # at t = 0 only one sample of the past is recorded
    assert result.time == 0.5
    assert result.trace.shape == (80,) and result.trace[0] == result.space


def test_satisfaction_at_zero_robustness_follows_strictness() -> None:
    one = {"x": np.array([1.0, 2.0])}
    assert evaluate_spec("x >= 1", one, 1.0).satisfied and evaluate_spec("x >= 1", one, 1.0).space == 0.0
    assert not evaluate_spec("x > 1", one, 1.0).satisfied
    assert evaluate_spec("!(x > 1)", one, 1.0).satisfied


# ---- kernels ---------------------------------------------------------------------------------------
def test_window_min_matches_naive_for_all_window_shapes() -> None:
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 60))
        x = rng.normal(size=n)
        lo = int(rng.integers(0, 8))
        hi = math.inf if rng.random() < 0.2 else float(lo + rng.integers(0, 70))
        expected = [min(x[k + lo : (n if math.isinf(hi) else k + int(hi) + 1)], default=math.inf) for k in range(n)]
        np.testing.assert_array_equal(kernels.window_min(x, lo, hi), expected)


@pytest.mark.parametrize("n", [1, 63, 64, 65, 1000, 1001])
def test_unbounded_until_scan_matches_sequential_recursion(n: int) -> None:
    rng = np.random.default_rng(n)
    phi, psi = rng.normal(size=n), rng.normal(size=n)
    expected = np.empty(n)
    acc = -math.inf
    for k in range(n - 1, -1, -1):
        acc = max(psi[k], min(phi[k], acc))
        expected[k] = acc
    np.testing.assert_array_equal(kernels.unbounded_until(phi, psi), expected)


def test_bounded_until_on_long_signal_matches_definition() -> None:
    rng = np.random.default_rng(9)
    n, lo, hi = 500, 3, 11
    phi, psi = rng.normal(size=n), rng.normal(size=n)
    expected = [
        max((min([psi[j], *phi[k:j]]) for j in range(k + lo, min(k + hi, n - 1) + 1)), default=-math.inf)
        for k in range(n)
    ]
    np.testing.assert_array_equal(kernels.until(phi, psi, lo, float(hi)), expected)


# ---- parser ----------------------------------------------------------------------------------------
a, b, c = (Predicate(Var(n), ">", Const(0.0)) for n in "abc")


@pytest.mark.parametrize(
    ("text", "tree"),
    [
        ("a > 0 | b > 0 & c > 0", Or(a, And(b, c))),
        ("a > 0 -> b > 0 -> c > 0", Implies(a, Implies(b, c))),
        ("!a > 0 & b > 0", And(Not(a), b)),
        ("G[0,2] a > 0 & b > 0", And(Always(a, 0.0, 2.0), b)),
        ("a > 0 U[1,2.5] b > 0", Until(a, b, 1.0, 2.5)),
        ("a > 0 until b > 0 and c > 0", And(Until(a, b), c)),
        ("always[0, inf] (a > 0) implies not eventually[1,3] b > 0", Implies(Always(a), Not(Eventually(b, 1.0, 3.0)))),
        ("((a > 0)) or (b > 0)", Or(a, b)),
        ("(a - 1) * 2 > 0", Predicate(BinOp("*", BinOp("-", Var("a"), Const(1.0)), Const(2.0)), ">", Const(0.0))),
    ],
)
def test_parser_precedence_and_aliases(text: str, tree) -> None:
    assert parse_formula(text) == tree


def test_python_composition_equals_parsed_text() -> None:
    x, y, z = var("x"), var("y"), var("z")
    built = ((x - y >= 2 * z + 1).always(0, 30) & (y < 0).eventually(0, 20)) >> ~(x > 1).until(z <= 2, 1, 3)
    parsed = parse_formula("(G[0,30](x - y >= 2*z + 1) & F[0,20](y < 0)) -> !((x > 1) U[1,3] (z <= 2))")
    assert built == parsed
    assert parse_formula(str(built)) == built
    assert built.signal_names() == frozenset({"x", "y", "z"})
    assert built.horizon() == 30.0


def test_horizon() -> None:
    f = parse_formula("G[0,10]((x > 0) -> F[0,5](y > 0.5)) & G[0,100](z < 3)")
    assert f.horizon() == 100.0  # max(10 + 5, 100)
    assert parse_formula("(x > 0) U[1,4] F[0,2](y > 0)").horizon() == 6.0
    assert parse_formula("x > 0").horizon() == 0.0
    assert math.isinf(parse_formula("G(x > 0)").horizon())


@pytest.mark.parametrize(
    ("text", "column", "fragment"),
    [
        ("G[0,30](gap_lead > 5) & F[0,20](ahead_of_lead > 0", 50, "expected ')'"),
        ("G[0,30](gap_lead > 5) & & x > 1", 25, "expected a signal"),
        ("x > 1 )", 7, "expected end of formula"),
        ("G[0,](x > 1)", 5, "expected a number for interval end"),
        ("G[3,1](x > 1)", 5, "bad interval"),
        ("min(x) > 0", 6, "min() takes 2"),
        ("x > 1 $ 2", 7, "unexpected character"),
        ("x 1", 3, "expected a comparison"),
    ],
)
def test_parse_errors_point_at_the_column(text: str, column: int, fragment: str) -> None:
    with pytest.raises(STLSyntaxError) as info:
        parse_formula(text)
    assert isinstance(info.value, ValueError)
    message = str(info.value)
    assert message.startswith(f"col {column}: ") and fragment in message and "\n" not in message


def test_missing_signal_names_it_and_the_known_ones() -> None:
    with pytest.raises(STLSignalError) as info:
        evaluate_spec("G(x > 0) & (speed < 3)", {"x": X, "gap": X}, 0.1)
    assert isinstance(info.value, KeyError)
    assert "'speed'" in str(info.value) and "gap, x" in str(info.value)


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(STLSignalError):
        space_robustness("x > y", {"x": X, "y": X[:3]}, 1.0)
    with pytest.raises(ValueError, match="dt"):
        space_robustness("x > 0", {"x": X}, 0.0)
    with pytest.raises(ValueError, match="no sample time"):
        space_robustness("G[0.2,0.3](x > 0)", {"x": X}, 0.5)
    with pytest.raises(ValueError):
        Always(a, 2.0, 1.0)
