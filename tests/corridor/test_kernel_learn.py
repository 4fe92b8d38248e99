"""Learning boundaries: row expressions, stochastic switching near a boundary, --learn input checks."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from corridor.cli import main
from corridor.errors import CorridorError
from corridor.events import EventLog
from corridor.modes import Boundary, HybridAutomaton, SwitchingParams, Transition
from corridor.objective import Expression, value, violations


def test_row_expressions() -> None:
    row = {"nmac": 0, "path_ratio_mean": 1.25, "spec.safety.space": -0.5, "collisions": 1}
    assert value(Expression("-path_ratio_mean"), row) == -1.25
    assert value(Expression("2 * abs(spec.safety.space) - max(1, nmac)"), row) == 0.0
    cons = [Expression("nmac == 0"), Expression("collisions == 0"), Expression("spec.safety.space > 0 or nmac < 1")]
    assert violations(cons, row) == 1
    assert math.isnan(value(Expression("-missing"), row))
    with pytest.raises(CorridorError, match="not allowed"):
        Expression("__import__('os')")
    with pytest.raises(CorridorError, match="unknown column 'nmc'.*nmac"):
        Expression("nmc == 0").check_columns(["nmac", "los"])


def _automaton(temperature: float | None, seed: int = 0, fn: object = None, theta: dict[str, float] | None = None,
               ) -> HybridAutomaton:
    fn = fn or (lambda x, th: (th["dist_m"] - x) / th["dist_m"])
    b = Boundary("enter", fn, theta or {"dist_m": 100.0})  # type: ignore[arg-type]
    return HybridAutomaton("uav", ["mission", "avoid"], "mission", [Transition("mission", "avoid", b, "threat")],
                           switching=SwitchingParams(temperature=temperature, band=4.0),
                           rng=np.random.default_rng(seed))


def _sigma(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-z))


def test_stochastic_switch_only_near_the_boundary_with_its_score() -> None:
    """g = (100 - d) / 100, T = 0.05 log units (band 4 T = 0.2: d within 100 e^(+-0.2) = 82..122 m):
    at d = 300 the switch is deterministic (no draw); at d = 103 it is a draw (eps, held for the band
    visit) with p = sigma(log(100 / 103) / T) and score tanh(eps / 2T) / (T dist_m)."""
    ha, ev = _automaton(0.05), EventLog()
    ha.update(0.0, 300.0, ev)
    assert ha.mode == "mission" and not ev.of_kind("switch_draw")
    ha.update(0.1, 103.0, ev)
    (d,) = ev.of_kind("switch_draw")
    p = _sigma(math.log(100.0 / 103.0) / 0.05)
    assert d.data["p"] == pytest.approx(p, rel=1e-6)
    eps = d.data["eps"]
    assert d.data["score"]["enter.dist_m"] == pytest.approx(math.tanh(eps / 0.1) / (0.05 * 100.0), rel=1e-6)
    assert d.data["a"] == (eps >= math.log(103.0 / 100.0))
    assert ha.mode == ("avoid" if d.data["a"] else "mission")


def test_the_temperature_reads_in_theta_whatever_the_units_of_g() -> None:
    """The same gate written in metres, as a ratio, or falling instead of rising with theta: the same
    p at the same state (p_enter + p_exit = 1), because T is a log-scale of theta, not of g.  With
    T in units of g the metre version would switch with p = sigma(-3 m / 0.05) ~ 1e-26."""
    ps = []
    for fn in (lambda x, th: (th["dist_m"] - x) / th["dist_m"], lambda x, th: th["dist_m"] - x):
        ha, ev = _automaton(0.05, fn=fn), EventLog()
        ha.update(0.0, 103.0, ev)
        ps.append(ev.of_kind("switch_draw")[0].data["p"])
    ha, ev = _automaton(0.05, fn=lambda x, th: (x - th["dist_m"]) / th["dist_m"]), EventLog()  # the exit's sign
    ha.update(0.0, 103.0, ev)
    assert ps[0] == pytest.approx(ps[1], rel=1e-6)
    assert ps[0] + ev.of_kind("switch_draw")[0].data["p"] == pytest.approx(1.0, rel=1e-6)


def test_the_band_follows_theta_and_scores_every_scaled_parameter() -> None:
    """g = a b - x (a, b > 0): both parameters are scaled, c* = log(x / (a b)) / 2, so
    p = sigma(log(a b / x) / (2 T)), and the shift's score splits as 1 / (2 a), 1 / (2 b).  A 10 km gate at T = 0.5 draws
    for an aircraft 3 km away (inside 10 km x e^(+-2)); T in units of g = 0.1 did not."""
    ha, ev = _automaton(0.5, fn=lambda x, th: th["a"] * th["b"] - x, theta={"a": 50.0, "b": 4.0}), EventLog()
    ha.update(0.0, 300.0, ev)
    (d,) = ev.of_kind("switch_draw")
    assert d.data["p"] == pytest.approx(_sigma(math.log(200.0 / 300.0) / 1.0), rel=1e-6)
    shift = math.tanh(d.data["eps"] / 1.0) / 0.5
    assert d.data["score"]["enter.a"] == pytest.approx(shift / (2 * 50.0), rel=1e-4)
    assert d.data["score"]["enter.b"] == pytest.approx(shift / (2 * 4.0), rel=1e-4)
    ha, ev = _automaton(0.5, theta={"dist_m": 10000.0}), EventLog()
    ha.update(0.0, 3000.0, ev)
    assert ev.of_kind("switch_draw")[0].data["p"] == pytest.approx(_sigma(math.log(10000.0 / 3000.0) / 0.5))


def test_switch_probability_is_sigma_of_the_log_distance_over_t() -> None:
    hits = 0
    for seed in range(400):
        ha = _automaton(0.05, seed)
        ha.update(0.0, 103.0)
        hits += ha.mode == "avoid"
    assert hits / 400 == pytest.approx(_sigma(math.log(100.0 / 103.0) / 0.05), abs=0.06)


def test_deterministic_without_temperature() -> None:
    ha, ev = _automaton(None), EventLog()
    ha.update(0.0, 103.0, ev)
    ha.update(0.1, 99.0, ev)
    assert ha.mode == "avoid" and not ev.of_kind("switch_draw")


LEARN = ["uav_encounter", "--variant", "potential_field", "--method", "blrl", "--quiet"]


@pytest.mark.parametrize("args, says", [
    (["--learn", "avoid_entr.dist_m", "--objective", "-path_ratio_mean", "--budget", "16"], "no such boundary"),
    (["--learn", "avoid_enter.dist_m", "--objective", "-path_ratio_mean +", "--budget", "16"], "not an expression"),
    (["--learn", "avoid_enter.dist_m", "--objective", "-path_ratio_mea", "--budget", "16"], "unknown column"),
    (["--learn", "avoid_enter.dist_m", "--objective", "-path_ratio_mean", "--budget", "15"], "at least 16"),
])
def test_bad_learn_input_is_one_line_exit_2_before_any_folder(
        args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main([*LEARN, *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_learn_cma_end_to_end_writes_a_rerunnable_learned_yaml(tmp_path: Path) -> None:
    """Short runs (the encounter is not reached: the objective is flat), but every piece runs: stages
    through the batch executor, the held-out comparison, learn.json, learned.yaml that loads with the
    learned theta, and --resume reading the finished runs back to the same result."""
    import json

    from corridor.scenario import load

    out = tmp_path / "learn"
    args = [*LEARN[:3], "--method", "cma", "--quiet", "--learn", "avoid_enter.dist_m", "--objective",
            "-path_ratio_mean", "--constraint", "nmac == 0", "--budget", "12", "--holdout", "2",
            "--set", "duration=3", "--workers", "2", "--out", str(out)]
    assert main(args) == 0
    data = json.loads((out / "learn.json").read_text())
    assert data["training_runs"] == 12 and len(data["curve"]) == 2 and data["holdout"]["runs"] == 2
    key = "controllers.avoid.params.boundaries.avoid_enter.dist_m"
    assert data["theta0"][key] == 10000.0
    sc, raw = load(out / "learned.yaml")
    assert raw["controllers"]["avoid"]["params"]["boundaries"]["avoid_enter"]["dist_m"] == pytest.approx(data["theta"][key])
    assert main([*args, "--resume"]) == 0
    assert json.loads((out / "learn.json").read_text())["theta"] == data["theta"]


def test_a_stochastic_switch_before_the_crossing_is_logged_at_its_own_time() -> None:
    """g = -0.5 (deterministic, no switch) then -0.03: a switch drawn there is not a crossing (g has not
    reached 0), so t_cross is the jump's own time, not an extrapolation past it."""
    for seed in range(50):
        ha, ev = _automaton(0.05, seed), EventLog()
        ha.update(0.0, 150.0, ev)
        ha.update(0.1, 103.0, ev)
        if ha.mode == "avoid":
            (jump,) = ev.of_kind("mode")
            assert jump.data["t_cross"] == jump.t == 0.1 and jump.data["g"] < 0
            return
    raise AssertionError("no seed switched")


def test_a_blrl_stage_at_todays_boundaries_draws_switches_and_has_a_gradient(tmp_path: Path) -> None:
    """Today's gate (10 km) lies beyond the 3 km MAVLink range.  blrl's first stage there (8 full
    runs at theta0, T0) must still draw switches and get a nonzero gradient: the band is a log-scale
    of theta (10 km x e^(+-4 T0) reaches the tracked aircraft).  With T0 = 0.1 in units of g
    (|g| < 0.4: predicted ranges of 6-14 km) no tracked aircraft was ever inside it: 0 draws, theta stayed."""
    from corridor import learn

    pb = learn.problem("uav_encounter", "avoid_enter.dist_m,avoid_exit.dist_m", "-path_ratio_mean",
                       ["nmac == 0", "collisions == 0"], learn.min_budget("blrl"), "blrl", "potential_field", [])

    def run(specs: list[object], stage: int) -> list[dict[str, object]]:
        return learn._run(specs, tmp_path / f"{stage:03d}", "local", 2, None, False)

    theta, (stage,) = learn.blrl(pb, learn.RUNS_PER_STAGE, 0, tmp_path, run)
    assert stage["runs"] == learn.RUNS_PER_STAGE and stage["temperature"] == learn.T0
    assert stage["draws"] > 0 and stage["grad_norm"] > 0.0
    assert not np.allclose(theta, pb.theta0)


def test_hinge_penalty_grows_with_how_far_a_row_is_past_its_bound() -> None:
    """--penalty hinge: 1 + the excess per broken comparison, so blrl's leave-one-out gradient still sees
    a difference when every run of a stage breaks ``hard_brakes <= H`` (count: the same 1 for all)."""
    from corridor.objective import excess, hinge_violations

    cons = [Expression("collisions == 0"), Expression("hard_brakes <= 3")]
    assert [excess(c, {"collisions": 0, "hard_brakes": 8}) for c in cons] == [0.0, 5.0]
    assert excess(Expression("3 >= hard_brakes"), {"hard_brakes": 8}) == 5.0
    assert excess(Expression("sep > 10"), {"sep": 4.0}) == 6.0
    assert excess(Expression("a > 0 or b > 0"), {"a": -1, "b": -2}) == 0.0  # not a single comparison
    assert hinge_violations(cons, {"collisions": 0, "hard_brakes": 3}) == 0.0
    assert hinge_violations(cons, {"collisions": 0, "hard_brakes": 4}) == 2.0
    assert hinge_violations(cons, {"collisions": 2, "hard_brakes": 8}) == 3.0 + 6.0
    assert hinge_violations(cons, {"collisions": 0}) == 1.0  # a missing column: broken, no excess


def test_the_penalty_option_reaches_the_learners_reward(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from corridor.learn import problem

    args = ("merging", "merge_enter.dist_m", "-delay_mean_s", ["collisions == 0", "hard_brakes <= 3"], 16, "blrl",
            "v2x_cps", [])
    row = {"status": "ok", "delay_mean_s": 9.0, "collisions": 0, "hard_brakes": 8}
    assert problem(*args).reward(row) == -9.0 - 1.0
    assert problem(*args, penalty="hinge").reward(row) == -9.0 - 6.0
    assert problem(*args, penalty="hinge").reward({**row, "hard_brakes": 2}) == -9.0
    with pytest.raises(CorridorError, match="--penalty 'square': one of count, hinge"):
        problem(*args, penalty="square")
    with pytest.raises(SystemExit) as exc:
        main(["uav_encounter", "--penalty", "hinge", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "--penalty go with --learn" in capsys.readouterr().err
