"""Distributions with densities, the failure-event parser and the --estimate/--falsify command line."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from corridor.batch import draw_seed, draws_for
from corridor.cli import main
from corridor.distributions import from_normal, logpdf, to_normal
from corridor.errors import CorridorError
from corridor.rare_event import parse_event, parse_level
from corridor.scenario import Distribution, load
from tests.corridor.rare_data import GAUSS


def test_existing_kinds_draw_the_same_numbers() -> None:
    """The nominal sampler of the four original kinds is the generator call it always was."""
    for dist, call in [(Distribution(uniform=(2, 5)), lambda g: float(g.uniform(2, 5))),
                       (Distribution(normal=(1, 3)), lambda g: float(g.normal(1, 3))),
                       (Distribution(integers=(0, 2)), lambda g: int(g.integers(0, 3))),
                       (Distribution(choice=["a", "b", "c"]), lambda g: ["a", "b", "c"][int(g.integers(3))])]:
        for seed in range(5):
            ss = draw_seed(seed, "x.y")
            assert dist.draw(np.random.default_rng(ss)) == call(np.random.default_rng(draw_seed(seed, "x.y")))


@pytest.mark.parametrize("dist,frozen", [
    (Distribution(truncnormal=(1, 2, 0, 4)), stats.truncnorm(-0.5, 1.5, loc=1, scale=2)),
    (Distribution(lognormal=(0.5, 0.3)), stats.lognorm(s=0.3, scale=math.exp(0.5))),
    (Distribution(beta=(2, 5, 10, 20)), stats.beta(2, 5, loc=10, scale=10)),
    (Distribution(uniform=(-1, 3)), stats.uniform(-1, 4)),
    (Distribution(normal=(5, 2)), stats.norm(5, 2)),
])
def test_densities_and_the_normal_map(dist: Distribution, frozen: object) -> None:
    z = np.random.default_rng(1).standard_normal(4000)
    x = np.array([from_normal(dist, zi) for zi in z])
    assert stats.kstest(x, frozen.cdf).pvalue > 1e-3  # z ~ N(0, 1) gives the distribution's law
    for xi in x[:20]:
        assert logpdf(dist, xi) == pytest.approx(frozen.logpdf(xi))
    for zi in (-4.0, -0.3, 0.0, 2.5, 6.0):  # to_normal inverts from_normal, in the tails too
        assert to_normal(dist, from_normal(dist, zi)) == pytest.approx(zi, abs=1e-6)
    drawn = [dist.draw(np.random.default_rng(s)) for s in range(2000)]
    assert stats.kstest(drawn, frozen.cdf).pvalue > 1e-3


def test_discrete_kinds_and_tails() -> None:
    d = Distribution(integers=(0, 2))
    assert [from_normal(d, z) for z in (-3, 0, 3)] == [0, 1, 2]
    assert logpdf(d, 1) == pytest.approx(math.log(1 / 3)) and logpdf(d, 3) == -math.inf
    c = Distribution(choice=["x", "y", "y", "z"])
    assert logpdf(c, "y") == pytest.approx(math.log(0.5)) and from_normal(c, to_normal(c, "z")) == "z"
    assert from_normal(Distribution(normal=(0, 10)), 4.5) == pytest.approx(45.0)  # exact, no CDF round trip
    t = Distribution(truncnormal=(0, 1, -1, 1))
    assert -1 <= from_normal(t, 9.0) <= 1 and from_normal(t, 9.0) > 0.999


def test_new_kinds_are_validated() -> None:
    for bad in ({"truncnormal": (0, 1, 2, 1)}, {"lognormal": (0, -1)}, {"beta": (0, 1, 0, 1)},
                {"uniform": (0, 1), "normal": (0, 1)}):
        with pytest.raises(ValueError):
            Distribution(**bad)


def test_existing_scenario_draws_unchanged() -> None:
    sc, _ = load("scenarios/uav_encounter.yaml")
    d = draws_for(sc, 3)
    g = np.random.default_rng(draw_seed(3, "backends.air.params.encounter.course_deg"))
    assert d["backends.air.params.encounter.course_deg"] == float(g.uniform(0, 360))


def test_event_parser() -> None:
    ev = parse_event("nmac > 0 or (sep_min_h_m < 10 and not spec.safety.satisfied)")
    assert ev.columns == ("nmac", "sep_min_h_m", "spec.safety.satisfied")
    assert ev.fails({"nmac": 1, "sep_min_h_m": 50, "spec.safety.satisfied": True})
    assert ev.fails({"nmac": 0, "sep_min_h_m": 5, "spec.safety.satisfied": False})
    assert not ev.fails({"nmac": 0, "sep_min_h_m": 5, "spec.safety.satisfied": True})
    lv = parse_event("min_ttc_s < 1.5").default_level()
    assert lv.of({"min_ttc_s": 1.0}) == pytest.approx(-0.5)
    assert parse_event("collisions >= 1").default_level().of({"collisions": 2}) == pytest.approx(-1)
    spec = parse_event("spec:safety", ["safety"])
    assert spec.fails({"spec.safety.space": -0.1}) and not spec.fails({"spec.safety.space": 0.0})
    assert parse_level("-collisions").of({"collisions": 3}) == -3


@pytest.mark.parametrize("text", ["__import__('os').system('true')", "a + b > 0", "x.y() > 1", "", "a <", "a in b",
                                  "lambda: 1", "[1] > 0", "spec:nope"])
def test_event_parser_refuses(text: str) -> None:
    with pytest.raises(CorridorError):
        parse_event(text, ["safety"])


@pytest.mark.parametrize("args,needle", [
    (["--estimate", "os.system('x') > 0", "--budget", "10"], "compare column names"),
    (["--estimate", "spec:nope", "--budget", "10"], "no spec"),
    (["--estimate", "collisions > 0 and nmac", "--budget", "10", "--method", "ce"], "--level"),
    (["--falsify", "nope", "--budget", "10"], "no spec"),
    (["--estimate", "nmac > 0", "--budget", "10", "--level", "a b"], "--level"),
    (["--estimate", "nmac > 0", "--budget", "10", "--variant", "a", "--variant", "b"], "at most one"),
    (["--estimate", "nmac > 0", "--budget", "100000000"], "--budget"),
])
def test_cli_bad_input_is_one_line_exit_2(args: list[str], needle: str, tmp_path: object, capsys: object) -> None:
    assert main([str(GAUSS), "--out", str(tmp_path / "o"), *args]) == 2  # type: ignore[operator]
    err = capsys.readouterr().err.strip()  # type: ignore[attr-defined]
    assert len(err.splitlines()) == 1 and needle in err, err


def test_cli_no_randomize_exit_2(tmp_path: object, capsys: object) -> None:
    args = [str(GAUSS), "--set", "backends.sim.params.vehicles.b.x_m=3", "--estimate", "nmac > 0", "--budget", "5",
            "--out", str(tmp_path / "o")]  # type: ignore[operator]
    assert main(args) == 2
    assert "has none" in capsys.readouterr().err  # type: ignore[attr-defined]


def test_cli_budget_needs_estimate() -> None:
    with pytest.raises(SystemExit) as exc:
        main([str(GAUSS), "--budget", "5"])
    assert exc.value.code == 2


def test_cli_naive_is_the_plain_batch(tmp_path: object, capsys: object) -> None:
    """--method naive runs the plain batch through the worker processes, with its exact interval."""
    out = tmp_path / "naive"  # type: ignore[operator]
    assert main([str(GAUSS), "--estimate", "nmac > 0", "--method", "naive", "--budget", "3", "--out", str(out)]) == 0
    text = capsys.readouterr().out  # type: ignore[attr-defined]
    assert "P(nmac > 0) ~= 0" in text and "[0, 0.7076]" in text and "nan" not in text
    assert "Rare-event estimate" in (out / "report.html").read_text()
    # a larger budget extends the plain batch on --resume, like --runs
    assert main([str(GAUSS), "--estimate", "nmac > 0", "--method", "naive", "--budget", "4", "--out", str(out),
                 "--resume", "--no-report", "--quiet"]) == 0
    assert len(list((out / "parts").glob("*.parquet"))) == 4
