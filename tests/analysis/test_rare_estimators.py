"""Rare-event estimators against a closed form: P(NMAC) = P(x > 4.5 sigma) = 3.3977e-6 on the
point-mass backend (tests/corridor/data/gauss_tail.yaml), through the estimate runner (stages of
RunSpecs, the results store, rows read back); the ``inline`` executor runs them in this process."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from corridor.analysis.rare.ce import CrossEntropy
from corridor.analysis.rare.splitting import SubsetSimulation, level_size
from corridor.cli import main
from corridor.errors import CorridorError
from corridor.rare_api import estimate, falsify
from tests.corridor.rare_data import GAUSS, TRUTH


def _ce(tmp_path: Path, budget: int = 600, seed: int = 0, **kw: object) -> dict:
    return estimate(GAUSS, "nmac > 0", method="ce", budget=budget, level="sep_min_h_m", seed=seed,
                    out=tmp_path / f"ce{seed}", executor="inline", **kw)


def test_ce_closed_form(tmp_path: Path) -> None:
    data = _ce(tmp_path, report=True)
    res = data["result"]
    assert abs(res["estimate"] / TRUTH - 1) < 0.2 and res["ci95"][0] <= TRUTH <= res["ci95"][1]
    assert res["runs"] == 600 and res["converged"] and res["final_failures"] > 100
    assert res["runs_ratio"] > 1000  # plain Monte Carlo would need > 1000 x the runs for this precision
    assert [p["kind"] for p in res["path"]][-1] == "final" and res["path"][0]["mean"] == [0.0]
    # the most likely failures are the ones just beyond 45 m, and their command re-runs them exactly
    top = data["likely_failures"][0]
    assert 45 < top["draws"]["backends.sim.params.vehicles.b.x_m"] < 46 and "--seed" in top["rerun"]
    df = pd.read_parquet(tmp_path / "ce0" / "runs.parquet")
    assert len(df) == 600 and df["estimate.fail"].sum() == sum(p["failures"] for p in res["path"])
    assert "Rare-event estimate" in (tmp_path / "ce0" / "report.html").read_text()


@pytest.mark.parametrize("budget", [1000, pytest.param(2000, marks=pytest.mark.slow)])
def test_splitting_closed_form(tmp_path: Path, budget: int) -> None:
    """Subset simulation: its own CV is 0.6-0.8 here with 2,000 runs (the method's variance at p0 = 0.1
    over ~6 levels is (1 - p0) / (p0 n) (1 + gamma) per level), so the check is its interval."""
    res = estimate(GAUSS, "spec:separation", method="splitting", budget=budget, out=tmp_path / "ss",
                   executor="inline", report=False)["result"]
    assert res["runs"] <= budget and res["reached_failure"]
    assert res["ci95"][0] <= TRUTH <= res["ci95"][1] and 0.25 < res["estimate"] / TRUTH < 4
    assert [lv["conditional_p"] for lv in res["path"][:-1]] == [0.1] * (len(res["path"]) - 1)


def test_determinism_and_resume(tmp_path: Path) -> None:
    a = _ce(tmp_path, budget=200, seed=5)
    b = _ce(tmp_path / "again", budget=200, seed=5)
    assert a["result"]["estimate"] == b["result"]["estimate"] and a["result"]["path"] == b["result"]["path"]
    # an interrupted estimate: the last stage lost some rows; --resume runs only those and agrees
    last = sorted((tmp_path / "ce5" / "stages").iterdir())[-1]
    lost = sorted((last / "parts").glob("*.parquet"))[:7]
    for p in lost:
        p.unlink()
    (last / "runs.parquet").unlink(missing_ok=True)  # (the inline executor writes parts only)
    c = _ce(tmp_path, budget=200, seed=5, resume=True)
    assert c["result"]["estimate"] == a["result"]["estimate"]
    # stage rows of another estimate (another seed) are refused on resume, never mixed in
    _ce(tmp_path, budget=200, seed=6)
    shutil.rmtree(tmp_path / "ce6" / "stages" / "000")
    shutil.copytree(tmp_path / "ce5" / "stages" / "000", tmp_path / "ce6" / "stages" / "000")
    with pytest.raises(CorridorError, match="other inputs"):
        _ce(tmp_path, budget=200, seed=6, resume=True)
    with pytest.raises(Exception, match="settings differ"):
        estimate(GAUSS, "nmac > 0", method="splitting", budget=200, level="sep_min_h_m", seed=5,
                 out=tmp_path / "ce5", executor="inline", resume=True)


def test_falsify_finds_the_planted_violation_and_reproduces_it(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = falsify(GAUSS, "separation", budget=120, out=tmp_path / "f", executor="inline")
    assert data["counterexample"] and data["best_robustness"] < 0 and data["result"]["runs"] <= 120
    x = data["best_draws"]["backends.sim.params.vehicles.b.x_m"]
    assert data["best_robustness"] == pytest.approx(abs(75.48 - x) - 30.48, abs=1e-6)
    # plain run_scenario on the counterexample (worker process) gives the same violation
    assert main([data["counterexample"], "--out", str(tmp_path / "rerun"), "--quiet", "--no-report"]) == 0
    row = pd.read_parquet(tmp_path / "rerun" / "runs.parquet").iloc[0]
    assert row["spec.separation.space"] == pytest.approx(data["best_robustness"], abs=1e-9)
    assert row["nmac"] == 1


def test_falsify_reports_when_none_is_found(tmp_path: Path) -> None:
    data = falsify(GAUSS, "separation", budget=30, sets=["backends.sim.params.vehicles.a.x_m=1000"],
                   out=tmp_path / "f", executor="inline")
    assert data["counterexample"] is None and data["result"]["runs"] == 30
    assert not (tmp_path / "f" / "counterexample.yaml").exists()
    assert 889 < data["best_robustness"] < 1000  # it walked towards the far UAV (z is kept within 8 sigma)
    saved = json.loads((tmp_path / "f" / "falsify.json").read_text())
    assert saved["best_robustness"] == data["best_robustness"]


def _core(cls: type, seed: int) -> dict:
    """The method alone on the closed-form level (robustness |75.48 - 10 z| - 30.48)."""
    m = cls(1, 2000, seed)
    while (z := m.ask()) is not None:
        level = np.abs(75.48 - 10 * z[:, 0]) - 30.48
        m.tell(level, level < 0)
    return m.result()


def test_splitting_chain_levels_drop_the_seeds() -> None:
    """Each chain takes burn + 1/p0 - 1 steps and keeps its last 1/p0 states: a chain level costs
    n runs and holds n samples, none of them a seed (the previous level's extreme samples)."""
    res = _core(SubsetSimulation, 3)
    n = res["runs_per_level"]
    assert res["burn"] == 1 and n == level_size(2000, 0.1, 1) == 330
    totals = [lv["runs_total"] for lv in res["path"]]
    assert totals[0] == n and all(b - a == n for a, b in zip(totals, totals[1:])) and totals[-1] <= 2000
    old = SubsetSimulation(1, 2000, 3, burn=0)  # the seed kept as a sample: 9 new runs per chain
    assert old.n == level_size(2000, 0.1, 0) == 360 and old.steps == 9


@pytest.mark.parametrize("cls,coverage", [(CrossEntropy, 18), (SubsetSimulation, 17)])
def test_interval_coverage_of_the_methods(cls: type, coverage: int) -> None:
    """20 repeated estimates of the methods alone (no runs): their 95 % intervals cover the truth."""
    results = [_core(cls, seed) for seed in range(20)]
    assert sum(r["ci95"][0] <= TRUTH <= r["ci95"][1] for r in results) >= coverage
    if cls is CrossEntropy:
        assert all(abs(r["estimate"] / TRUTH - 1) < 0.2 for r in results)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ce", "splitting"])
def test_interval_coverage_through_the_runner(method: str, tmp_path: Path) -> None:
    """The done-when check: 20 repeated estimates with 2,000 runs each; CIs cover the truth >= 90 %.
    The figures (coverage, within 20 %, spread) are printed for the README (``-s``)."""
    results = []
    for seed in range(20):
        res = estimate(GAUSS, "spec:separation", method=method, budget=2000, seed=seed, out=tmp_path / str(seed),
                       executor="inline", report=False)["result"]
        assert math.isfinite(res["estimate"]) and res["runs"] <= 2000
        results.append(res)
    ratio = np.array([r["estimate"] for r in results]) / TRUTH
    covered = sum(r["ci95"][0] <= TRUTH <= r["ci95"][1] for r in results)
    print(f"\n{method}: coverage {covered}/20, within 20 % {int(np.sum(abs(ratio - 1) < 0.2))}/20, mean "
          f"{ratio.mean():.3f} x truth, spread {ratio.std(ddof=1):.1%}, runs <= {max(r['runs'] for r in results)}")
    assert covered >= 18
    if method == "ce":
        assert all(abs(ratio - 1) < 0.2)
