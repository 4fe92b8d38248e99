"""run_scenario --learn --method ppo: stable-baselines3 PPO through corridor/UavEncounter-v0."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from corridor.cli import main

PPO = ["uav_encounter", "--variant", "potential_field", "--method", "ppo", "--quiet", "--learn", "avoid_enter.dist_m",
       "--objective", "-path_ratio_mean", "--constraint", "nmac == 0"]


@pytest.mark.parametrize("args, says", [
    (["--budget", "7"], "at least 8"),
    (["--budget", "8", "--resume"], "keeps no per-stage training state"),
    (["--budget", "8", "--executor", "ray"], "steps its environment in this process"),
])
def test_what_ppo_does_not_map_is_one_line_exit_2_before_any_folder(
        args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main([*PPO, *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_ppo_learns_only_a_switch_the_environment_decides(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    args = ["uav_encounter", "--variant", "potential_field", "--method", "ppo", "--quiet", "--learn",
            "return_done.heading_deg", "--objective", "-path_ratio_mean", "--budget", "8", "--out", str(out)]
    assert main(args) == 2
    assert "decides the avoid_enter/avoid_exit switch" in capsys.readouterr().err
    assert not out.exists()


def test_ppo_end_to_end_stages_policy_and_paired_holdout(tmp_path: Path) -> None:
    """Tiny budget (2 stages of 4 runs of 4 s): the stages' rows, learn.json's curve, the policy (no
    theta, no learned.yaml) and the held-out comparison on seeds the training never used, where the
    policy's row re-runs identically from the saved files."""
    from corridor.learn import problem
    from corridor.learn_ppo import evaluate_policy

    out = tmp_path / "learn"
    assert main([*PPO, "--budget", "8", "--holdout", "2", "--set", "duration=4", "--out", str(out)]) == 0
    data = json.loads((out / "learn.json").read_text())
    assert data["method"] == "ppo" and data["theta"] is None and data["training_runs"] == 8
    assert [c["runs"] for c in data["curve"]] == [4, 4] and data["switch"] == ["avoid_enter", "avoid_exit"]
    assert (out / "ppo_policy.zip").is_file() and (out / "ppo_vecnormalize.pkl").is_file()
    assert not (out / "learned.yaml").exists()
    # the policy after the first stage is kept beside the final one (checkpoint_episodes(8) == [4])
    ckpt = out / "checkpoints" / "ep00004"
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["ep00004"]
    assert (ckpt / "ppo_policy.zip").is_file() and (ckpt / "ppo_vecnormalize.pkl").is_file()
    assert (ckpt / "ppo_policy.zip").read_bytes() != (out / "ppo_policy.zip").read_bytes()
    for stage in ("000", "001"):
        rows = pd.read_parquet(out / "stages" / stage / "rows.parquet")
        assert len(rows) == 4 and (rows["status"] == "ok").all() and rows["path_ratio_mean"].notna().all()
    h = data["holdout"]
    assert h["runs"] == 2 and h["overlap_training_seeds"] == 0
    assert h["learned"]["runs"] == h["hand_tuned"]["runs"] == 2 and h["paired_diff_mean"] is not None
    runs = pd.read_parquet(out / "runs.parquet")
    assert sorted(runs["learn.stage"].unique()) == ["000", "001", "hold0", "hold1"]
    hold1 = runs[runs["learn.stage"] == "hold1"].iloc[0]
    pb = problem("uav_encounter", "avoid_enter.dist_m", "-path_ratio_mean", ["nmac == 0"], 8, "ppo",
                 "potential_field", ["duration=4"])
    hold0 = runs[runs["learn.stage"] == "hold0"].set_index("run_id")
    draws = {k: hold0.loc[hold1["run_id"].replace("hold1", "hold0"), f"draw.{k}"] for k in pb.sc.randomize}
    again = evaluate_policy(out, pb, ["duration=4"], ("avoid_enter", "avoid_exit"), int(hold1["seed"]), draws)
    assert again["path_ratio_mean"] == hold1["path_ratio_mean"] and again["seed"] == hold1["seed"]


def test_checkpoints_early_in_powers_of_two_then_every_48_runs_before_the_final_policy() -> None:
    from corridor.learn_ppo import checkpoint_episodes

    assert checkpoint_episodes(8) == [4]
    assert checkpoint_episodes(32) == [4, 8, 16]
    assert checkpoint_episodes(480) == [4, 8, 16, 32, 48, 96, 144, 192, 240, 288, 336, 384, 432]
    assert checkpoint_episodes(50) == [4, 8, 16, 32]  # 12 stages of 4: the final policy is the one after 48


MERGE = ["merging", "--variant", "v2x_cps", "--method", "ppo", "--quiet",
         "--learn", "merge_enter.dist_m,yield_enter.dist_m,yield_exit.dist_m,gap_accept.lag_lengths",
         "--objective", "-delay_mean_s", "--constraint", "collisions == 0", "--constraint", "hard_brakes <= 3",
         "--set", "duration=40", "--set", "warmup=0"]


def test_ppo_on_the_merge_decides_the_named_boundaries_end_to_end(tmp_path: Path) -> None:
    """(b): the vehicles come and go, so PPO trains on the decision-point environment (one shared policy,
    one decision a step): stages of the runs that ended, the policy and its checkpoint, the held-out
    comparison; the policy's held-out row re-runs identically."""
    from corridor.learn import problem
    from corridor.learn_ppo import evaluate_policy

    out = tmp_path / "learn"
    assert main([*MERGE, "--budget", "8", "--holdout", "2", "--out", str(out)]) == 0
    data = json.loads((out / "learn.json").read_text())
    assert data["theta"] is None and data["switch"] == ["merge_enter", "gap_accept", "yield_enter", "yield_exit"]
    assert data["training_runs"] >= 8 and sum(c["runs"] for c in data["curve"]) == data["training_runs"]
    assert len(data["curve"]) >= 2  # the policy was updated before the budget ended
    rows = pd.concat([pd.read_parquet(p) for p in sorted((out / "stages").glob("*/rows.parquet"))])
    assert len(rows) == data["training_runs"] and (rows["status"] == "ok").all()
    assert rows["delay_mean_s"].notna().all() and (rows["decisions"] > 0).all()
    assert [p.name for p in (out / "checkpoints").iterdir()] and (out / "ppo_policy.zip").is_file()
    h = data["holdout"]
    assert h["runs"] == 2 and h["overlap_training_seeds"] == 0 and h["paired_diff_mean"] is not None
    runs = pd.read_parquet(out / "runs.parquet")
    hold1 = runs[runs["learn.stage"] == "hold1"].iloc[0]
    hold0 = runs[runs["learn.stage"] == "hold0"].set_index("run_id")
    sets = ["duration=40", "warmup=0"]
    pb = problem("merging", ",".join(data["keys"]), "-delay_mean_s", data["constraints"], 8, "ppo", "v2x_cps", sets)
    draws = {k: hold0.loc[hold1["run_id"].replace("hold1", "hold0"), f"draw.{k}"] for k in pb.sc.randomize}
    again = evaluate_policy(out, pb, sets, tuple(data["switch"]), int(hold1["seed"]), draws)
    assert again["delay_mean_s"] == hold1["delay_mean_s"] and again["decisions"] == hold1["decisions"]
