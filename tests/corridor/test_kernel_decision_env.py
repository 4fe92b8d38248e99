"""The merge's decision-point environment: API check, determinism, theta0's actions give run_scenario's row,
decisions only at the named boundaries inside blrl's band."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pandas as pd
import pytest
from gymnasium.utils.env_checker import check_env

import corridor.decision_env  # noqa: F401  (registers corridor/MergeDecisions-v0)
from corridor.cli import main
from corridor.decision_env import DecisionEnv

SHORT = ["duration=40", "warmup=0"]  # ramp vehicles reach the control zone within seconds
KEYS = ("merge_enter", "gap_accept", "yield_enter", "yield_exit")


def _rollout(env: DecisionEnv, seed: int, policy: Any) -> tuple[list[np.ndarray], list[dict[str, Any]], float]:
    """Run one episode; ``policy(step, info) -> action``: (observations, infos, final reward)."""
    obs, info = env.reset(seed=seed)
    seen, infos = [obs], [info]
    for k in range(100_000):
        obs, r, term, trunc, info = env.step(policy(k, info))
        seen.append(obs)
        infos.append(info)
        if term or trunc:
            assert term and not trunc  # the run's end is the task's end (no bootstrapping past it)
            return seen, infos, r
    raise AssertionError("the episode did not end")


def test_gymnasium_make_and_check_env() -> None:
    env = gymnasium.make("corridor/MergeDecisions-v0", sets=SHORT, boundaries=KEYS)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_same_seed_same_actions_same_decisions_and_row() -> None:
    env = DecisionEnv(sets=SHORT, boundaries=KEYS)
    flip = lambda k, info: int(k % 7 == 6)  # noqa: E731  (switch at some decisions, not at others)
    a_obs, a_inf, ra = _rollout(env, 4, flip)
    b_obs, b_inf, rb = _rollout(env, 4, flip)
    assert len(a_obs) == len(b_obs) > 20 and all(np.array_equal(x, y) for x, y in zip(a_obs, b_obs, strict=True))
    assert [i.get("vehicle") for i in a_inf[:-1]] == [i.get("vehicle") for i in b_inf[:-1]]
    assert ra == rb and a_inf[-1]["delay_mean_s"] == b_inf[-1]["delay_mean_s"]
    assert a_inf[-1]["decisions"] == len(a_obs) - 1 and a_inf[-1]["seed"] == 4
    never = _rollout(env, 4, lambda k, info: 0)  # the actions decide: never switching inside the band differs
    assert len(never[0]) != len(a_obs) or never[2] != ra
    env.close()


def test_theta0s_actions_reproduce_run_scenarios_row(tmp_path: Path) -> None:
    """Taking, at every decision, what the hand-tuned boundary decides gives the batch runner's row: the
    environment stops the run without changing it."""
    out = tmp_path / "batch"
    assert main(["merging", "--variant", "v2x_cps", "--seed", "3", "--quiet", "--no-report", "--workers", "1",
                 *[a for s in SHORT for a in ("--set", s)], "--out", str(out)]) == 0
    row = pd.read_parquet(out / "runs.parquet").iloc[0]
    env = DecisionEnv(sets=SHORT, boundaries=KEYS)
    _, infos, r = _rollout(env, 3, lambda k, info: info["default_action"])
    end = infos[-1]
    assert end["decisions"] > 20
    for col in ("delay_mean_s", "hard_brakes", "collisions", "throughput_vph", "events_mode", "min_ttc_s"):
        assert end[col] == row[col], col
    assert r == -row["delay_mean_s"]
    env.close()


def test_decisions_only_at_the_named_boundaries_inside_the_band() -> None:
    """Only merge_enter named: every decision is a ramp vehicle's merge_enter; a narrower band (blrl's later
    temperatures) asks fewer; ``default_action`` is the hand-tuned guard's outcome (0 before d <= 100 m)."""
    wide = DecisionEnv(sets=SHORT, boundaries=("merge_enter",))
    _, infos, _ = _rollout(wide, 2, lambda k, info: info["default_action"])
    asked = infos[:-1]
    assert {i["boundary"] for i in asked} == {"merge_enter"} and len(asked) > 20
    assert {i["default_action"] for i in asked} == {0, 1}
    narrow = DecisionEnv(sets=SHORT, boundaries=("merge_enter",), temperature=0.05)
    _, infos_n, _ = _rollout(narrow, 2, lambda k, info: info["default_action"])
    assert 0 < len(infos_n) - 1 < len(asked)
    assert infos_n[-1]["delay_mean_s"] == infos[-1]["delay_mean_s"]  # theta0's actions: the same run
    wide.close()
    narrow.close()


def test_reset_mid_run_abandons_it_and_the_next_run_is_unchanged() -> None:
    env = DecisionEnv(sets=SHORT, boundaries=KEYS)
    first, _, r = _rollout(env, 6, lambda k, info: 1)
    env.reset(seed=7)
    for _ in range(5):
        env.step(0)
    again, _, r2 = _rollout(env, 6, lambda k, info: 1)  # libsumo's one simulation per process: closed first
    assert r == r2 and all(np.array_equal(x, y) for x, y in zip(first, again, strict=True))
    env.close()


@pytest.mark.parametrize("kwargs, says", [
    ({"variant": "human"}, "no automata to decide"),
    ({"variant": "nope"}, "no variant 'nope'"),
])
def test_bad_setup_is_one_line(kwargs: dict[str, Any], says: str) -> None:
    from corridor.errors import CorridorError

    with pytest.raises(CorridorError, match=says):
        env = DecisionEnv(sets=SHORT, **kwargs)
        env.reset(seed=0)


OPEN = "sweep.v2x_cps.controllers.merge.params.boundaries.open_ahead.dist_m=250"  # (b) v5's start


def test_ppo_decides_open_ahead_and_theta0s_actions_reproduce_the_row(tmp_path: Path) -> None:
    """(b) with new boundaries: --method ppo takes the five keys blrl learns (open_ahead from 250 m), the
    environment it builds stops at open_ahead decisions too, and the hand-tuned actions give run_scenario's
    row exactly."""
    from corridor.learn import problem
    from corridor.learn_ppo import check, make_env

    sets = ["duration=100", "warmup=0", OPEN]  # seed 3: the first open_ahead decisions come after 40 s
    out = tmp_path / "batch"
    assert main(["merging", "--variant", "v2x_cps", "--seed", "3", "--quiet", "--no-report", "--workers", "1",
                 *[a for s in sets for a in ("--set", s)], "--out", str(out)]) == 0
    row = pd.read_parquet(out / "runs.parquet").iloc[0]
    keys = "merge_enter.dist_m,yield_enter.dist_m,yield_exit.dist_m,gap_accept.lag_lengths,open_ahead.dist_m"
    pb = problem("merging", keys, "-delay_mean_s", ["collisions == 0", "hard_brakes <= 3"], 8, "ppo", "v2x_cps",
                 sets, "hinge")
    switch = check(pb, False, "local")
    assert set(switch) == {"merge_enter", "gap_accept", "yield_enter", "yield_exit", "open_ahead"}
    env = make_env(pb, sets, switch)
    _, infos, r = _rollout(env, 3, lambda k, info: info["default_action"])
    asked = [i["boundary"] for i in infos[:-1]]
    assert asked.count("open_ahead") >= 1 and asked.count("merge_enter") > 20
    end = infos[-1]
    for col in ("delay_mean_s", "hard_brakes", "collisions", "throughput_vph", "events_mode", "min_ttc_s"):
        assert end[col] == row[col], col
    assert r == pb.reward({**end, "status": "ok"})
    env.close()


def test_the_hinge_penalty_reaches_the_reward() -> None:
    """--penalty hinge: a broken constraint costs 1 + how far the row is past it (corridor.learn_core), in
    PPO's reward as in blrl's and cma's; the count penalty 1."""
    from corridor.learn import problem
    from corridor.learn_ppo import make_env

    row = {"delay_mean_s": 9.0, "collisions": 0, "hard_brakes": 8, "status": "ok"}  # 5 past H = 3
    for kind, want in (("hinge", -9.0 - 6.0), ("count", -9.0 - 1.0)):
        pb = problem("merging", "merge_enter.dist_m", "-delay_mean_s", ["collisions == 0", "hard_brakes <= 3"], 8,
                     "ppo", "v2x_cps", SHORT, kind)
        env = make_env(pb, SHORT, ("merge_enter",))
        assert env.reward(row) == pb.reward(row) == want
