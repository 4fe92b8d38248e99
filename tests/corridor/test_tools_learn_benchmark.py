"""tools/learn_benchmark.py: the held-out table of --learn folders (the same seeds and draws as --learn's
own held-out comparison, theta0 run once), episodes to 95 % of the final objective, the theta scan."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import pandas as pd
import pytest

from corridor.cli import main as run_scenario
from corridor.errors import CorridorError

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("learn_benchmark", ROOT / "tools" / "learn_benchmark.py")
lb = importlib.util.module_from_spec(spec)
sys.modules["learn_benchmark"] = lb
spec.loader.exec_module(lb)


def _curve(means: list[float], runs: int = 8) -> list[dict[str, float | int]]:
    return [{"stage": i, "objective_mean": m, "runs": runs} for i, m in enumerate(means)]


def test_episodes_to_95_counts_the_runs_until_the_trailing_mean_is_95_percent_there() -> None:
    # trailing 3-stage means: -2, -1.5, -1, -0.333, 0, 0 -> 95 % of the way from -2 to 0 is -0.1: stage 4
    assert lb.episodes_to_95(_curve([-2.0, -1.0, 0.0, 0.0, 0.0, 0.0])) == 40
    assert lb.episodes_to_95(_curve([-2.0, -1.0, 0.0, 0.0, 0.0, 0.0]), window=1) == 24
    # no gain (the final trailing mean is not above the first stage): nothing to reach
    assert lb.episodes_to_95(_curve([-1.0, -1.2, -1.1, -1.05])) is None
    assert lb.episodes_to_95(_curve([None, -1.0])) is None  # type: ignore[list-item]


def test_paired_difference_uses_only_the_seeds_both_sides_ran() -> None:
    m, lo, hi, n = lb.paired({1: 1.0, 2: 2.0, 3: 3.0, 9: 100.0}, {1: 1.5, 2: 2.5, 3: 3.5, 4: -50.0})
    assert (m, n) == (pytest.approx(0.5), 3)
    assert lo == pytest.approx(0.5) and hi == pytest.approx(0.5)  # no spread: the interval is the point
    m, lo, hi, n = lb.paired({1: 0.0}, {1: 1.0})
    assert n == 1 and m == 1.0 and math.isnan(lo)


def test_folders_of_different_problems_are_refused_in_one_line(tmp_path: Path) -> None:
    base = {"scenario": "uav_encounter", "variant": "potential_field", "keys": ["a"], "objective": "-x",
            "constraints": [], "sets": [], "seed": 0}
    lb.check_same([base, dict(base)], ["a", "b"])
    spaced = {**base, "objective": "- x", "constraints": ["nmac == 0"]}
    lb.check_same([{**base, "constraints": ["nmac==0"]}, spaced], ["a", "b"])  # the same expressions
    with pytest.raises(CorridorError, match="constraints differs"):
        lb.check_same([spaced, {**base, "constraints": ["nmac == 1"]}], ["a", "b"])
    with pytest.raises(CorridorError, match="objective differs"):
        lb.check_same([base, {**base, "objective": "-y"}], ["a", "b"])
    assert lb.main(["holdout", str(tmp_path), "--out", str(tmp_path / "o")]) == 2


def _batch(folder: Path, sets: list[str], values: list[float], nmac: list[int]) -> Path:
    folder.mkdir()
    (folder / "batch.json").write_text(json.dumps({"sets": sets}))
    pd.DataFrame({"run_id": [f"r{i}" for i in range(len(values))], "seed": [10 + i for i in range(len(values))],
                  "status": "ok", "path_ratio_mean": values, "nmac": nmac}).to_parquet(folder / "runs.parquet")
    return folder


def test_scan_pairs_every_folder_with_the_reference_by_seed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    key = "controllers.avoid.params.boundaries.avoid_enter.dist_m"
    ref = _batch(tmp_path / "ref", [f"{key}=10000"], [1.3, 1.4, 1.5], [0, 0, 0])
    near = _batch(tmp_path / "near", [f"{key}=80"], [1.2, 1.35, 1.4], [0, 1, 0])
    table = lb.scan_table([ref, near], ref, "-path_ratio_mean", ["nmac == 0"], ["nmac"])
    assert table[0]["paired_diff"][:1] == (0.0,) and table[0]["violating"] == 0
    assert table[1]["sets"] == {"avoid_enter.dist_m": "80"}
    assert table[1]["paired_diff"][0] == pytest.approx(0.25 / 3) and table[1]["violating"] == 1
    assert table[1]["paired_diff.nmac"][0] == pytest.approx(1 / 3)
    svg = tmp_path / "scan.svg"
    assert lb.main(["scan", str(ref), str(near), "--reference", str(ref), "--objective", "-path_ratio_mean",
                    "--constraint", "nmac == 0", "--x", "avoid_enter.dist_m", "--metric", "nmac", "--plot", str(svg)]) == 0
    assert "avoid_enter.dist_m=80" in capsys.readouterr().out and svg.read_text().startswith("<?xml")


def test_holdout_uses_the_seeds_and_draws_of_learns_own_comparison(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Short runs (3 s: the encounter is not reached): the table's hand-tuned figure is --learn's own
    held-out figure (same seeds, same draws), and a second call re-uses the rows it ran."""
    out = tmp_path / "cma"
    assert run_scenario(["uav_encounter", "--variant", "potential_field", "--method", "cma", "--quiet",
                         "--learn", "avoid_enter.dist_m", "--objective", "-path_ratio_mean", "--budget", "12",
                         "--holdout", "2", "--set", "duration=3", "--workers", "2", "--out", str(out),
                         # room above the enter gate: a learned enter is kept at or below the exit (hysteresis)
                         "--set", "controllers.avoid.params.boundaries.avoid_exit.dist_m=40000"]) == 0
    own = json.loads((out / "learn.json").read_text())["holdout"]
    table = lb.holdout_table([out], 2, tmp_path / "bench", ["sep_min_h_m"], 2)
    (row,) = table
    assert row["pairs"] == 2 and row["training_episodes"] == 12 and row["overlap_training_seeds"] == 0
    train = pd.read_parquet(out / "runs.parquet")
    assert lb.training_seeds(out) == {int(x) for x in train.loc[train["learn.stage"].str.isdigit(), "seed"]}
    assert row["hand_tuned_objective"][0] == pytest.approx(own["hand_tuned"]["objective_mean"])
    assert row["learned_objective"][0] == pytest.approx(own["learned"]["objective_mean"])
    assert row["violating_learned"] == 0 and row["paired_diff_reward"][0] == pytest.approx(row["paired_diff"][0])
    parts = sorted((tmp_path / "bench" / "holdout").glob("*/parts/*.parquet"))
    assert len(parts) == 4  # theta0 and the learned theta, 2 seeds each
    lb.print_holdout(table, ["sep_min_h_m"])
    assert "| cma | 12 |" in capsys.readouterr().out
    stamp = [p.stat().st_mtime_ns for p in parts]
    lb.holdout_table([out], 2, tmp_path / "bench", [], 2)
    assert [p.stat().st_mtime_ns for p in parts] == stamp  # nothing ran again


def test_a_ppo_policy_is_run_on_the_held_out_seeds_of_learns_own_comparison(tmp_path: Path) -> None:
    """The policy runs in worker processes; its held-out figure is the one --method ppo reports."""
    pytest.importorskip("stable_baselines3")
    sys.path.insert(0, str(ROOT / "tools"))  # the spawned workers import the tool by name
    out = tmp_path / "ppo"
    assert run_scenario(["uav_encounter", "--variant", "potential_field", "--method", "ppo", "--quiet",
                         "--learn", "avoid_enter.dist_m", "--objective", "-path_ratio_mean", "--budget", "8",
                         "--holdout", "2", "--set", "duration=3", "--out", str(out)]) == 0
    own = json.loads((out / "learn.json").read_text())["holdout"]
    (row,) = lb.holdout_table([out], 2, tmp_path / "bench", [], 2)
    assert row["theta"] == "policy" and row["pairs"] == 2
    assert row["learned_objective"][0] == pytest.approx(own["learned"]["objective_mean"])
    assert row["hand_tuned_objective"][0] == pytest.approx(own["hand_tuned"]["objective_mean"])
    assert len(pd.read_parquet(tmp_path / "bench" / "holdout" / "ppo-ppo" / "rows.parquet")) == 2


def test_ppo_checkpoints_are_matched_against_a_learned_theta_on_the_same_held_out_seeds(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Short runs (3 s): every policy flies the hand-tuned rows, so PPO matches cma from its first checkpoint;
    the rows of theta0 and of the learned theta are those holdout runs (shared folder)."""
    pytest.importorskip("stable_baselines3")
    sys.path.insert(0, str(ROOT / "tools"))  # the spawned workers import the tool by name
    common = ["uav_encounter", "--variant", "potential_field", "--quiet", "--learn", "avoid_enter.dist_m",
              "--objective", "-path_ratio_mean", "--holdout", "0", "--set", "duration=3"]
    ppo, cma = tmp_path / "ppo", tmp_path / "cma"
    assert run_scenario([*common, "--method", "ppo", "--budget", "8", "--out", str(ppo)]) == 0
    assert run_scenario([*common, "--method", "cma", "--budget", "12", "--out", str(cma)]) == 0
    bench = tmp_path / "bench"
    (row,) = lb.holdout_table([cma], 2, bench, [], 2)
    table = lb.checkpoint_table(ppo, cma, 2, bench, 2)
    assert [t["episodes"] for t in table] == [4, 8]
    for t in table:
        assert t["pairs"] == 2 and t["violating_learned"] == 0
        assert t["against_objective"][0] == pytest.approx(row["learned_objective"][0])
        assert t["paired_diff"][0] == pytest.approx(0.0) and t["matches"]
    assert (bench / "holdout" / "ppo-ppo-ep00004" / "rows.parquet").is_file()
    lb.print_checkpoints(table, "cma")
    assert "first match: 4 training runs" in capsys.readouterr().out
    with pytest.raises(CorridorError, match="must be a --method ppo folder"):
        lb.checkpoint_table(cma, ppo, 2, bench, 2)


def test_hand_tuned_values_replace_the_start_where_the_learners_started_elsewhere() -> None:
    """--hand-tuned open_ahead.dist_m=0: the learners started the (off by default) boundary at 150 m, the
    comparison is against today's controller."""
    from corridor.learn import problem

    pb = problem("merging", "merge_enter.dist_m,open_ahead.dist_m", "-delay_mean_s", ["collisions == 0"], 16,
                 "blrl", "v2x_cps", ["sweep.v2x_cps.controllers.merge.params.boundaries.open_ahead.dist_m=150"])
    assert pb.theta0.tolist() == [100.0, 150.0]
    assert lb.hand_tuned_theta(pb, ["open_ahead.dist_m=0"]).tolist() == [100.0, 0.0]
    assert lb.hand_tuned_theta(pb, []).tolist() == [100.0, 150.0]
    full = "controllers.merge.params.boundaries.open_ahead.dist_m=0"
    assert lb.hand_tuned_theta(pb, [full]).tolist() == [100.0, 0.0]
    for bad in ("open_ahead.dist_m", "yield_enter.dist_m=3", "open_ahead.dist_m=x"):
        with pytest.raises(CorridorError, match="--hand-tuned"):
            lb.hand_tuned_theta(pb, [bad])
