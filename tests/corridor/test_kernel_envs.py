"""Gymnasium / PettingZoo environments over uav_encounter: API checks, determinism, the action decides."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

import corridor.envs  # noqa: F401  (registers corridor/UavEncounter-v0)
from corridor.envs import CorridorEnv, parallel_env
from corridor.errors import CorridorError

SHORT = ["duration=4"]


def _rollout(env: CorridorEnv, seed: int, actions: list[int]) -> tuple[list[np.ndarray], float, dict]:
    obs, _ = env.reset(seed=seed)
    out, r, info = [obs], 0.0, {}
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        if term or trunc:
            break
    return out, r, info


def test_gymnasium_make_and_check_env() -> None:
    env = gymnasium.make("corridor/UavEncounter-v0", sets=SHORT)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_same_seed_same_trajectory_and_reward() -> None:
    env = CorridorEnv(sets=SHORT)
    actions = [1, 0, 1, 1, 0] * 10
    a, ra, ia = _rollout(env, 5, actions)
    b, rb, ib = _rollout(env, 5, actions)
    assert len(a) == len(b) > 10 and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert ra == rb and ia["path_ratio_max"] == ib["path_ratio_max"]
    c, _, _ = _rollout(env, 6, actions)  # another seed: another encounter (randomize draws)
    assert not np.array_equal(a[0], c[0])
    env.close()


def test_the_action_decides_the_switch() -> None:
    """Always 0: the agent never avoids (no mode event of its own); always 1: it avoids at once."""
    env = CorridorEnv(sets=SHORT)
    _rollout(env, 1, [0] * 100)
    never = env.episode
    assert never.sim is None  # the run ended and was closed
    env.reset(seed=1)
    ha = env.episode.ctrl.automata[env._agent]
    env.step(1)
    env.step(1)
    assert ha.in_mode("avoid")
    env.reset(seed=1)
    ha = env.episode.ctrl.automata[env._agent]
    for _ in range(5):
        env.step(0)
    assert ha.mode == "mission"
    env.close()


def test_pettingzoo_parallel_api() -> None:
    env = parallel_env(sets=SHORT)
    assert env.possible_agents == ["uav_a", "uav_b"]
    parallel_api_test(env, num_cycles=30)
    env.close()


def test_bad_variant_and_uav_none_are_one_line_errors() -> None:
    with pytest.raises(CorridorError, match="no variant 'potential'"):
        CorridorEnv(variant="potential", sets=SHORT)
    env = CorridorEnv(variant="none", sets=SHORT)
    with pytest.raises(CorridorError, match="no agents with modes"):
        env.reset(seed=0)


def test_the_hinge_penalty_reaches_the_reward() -> None:
    """--penalty hinge with --method ppo on uav_encounter: the environment's reward is the learner's (1 + how
    far past the bound per broken constraint), not the count penalty; a wrong kind is a one-line error."""
    from corridor.learn import problem
    from corridor.learn_ppo import make_env

    row = {"path_ratio_mean": 1.25, "nmac": 3, "collisions": 0, "status": "ok"}  # 3 past nmac == 0
    for kind, want in (("hinge", -1.25 - 4.0), ("count", -1.25 - 1.0)):
        pb = problem("uav_encounter", "avoid_enter.dist_m", "-path_ratio_mean", ["nmac == 0", "collisions == 0"], 8,
                     "ppo", "potential_field", SHORT, kind)
        env = make_env(pb, SHORT, ("avoid_enter", "avoid_exit"))
        assert env.episode.reward(row) == pb.reward(row) == want
    with pytest.raises(CorridorError, match="penalty_kind 'squared'"):
        CorridorEnv(sets=SHORT, penalty_kind="squared")
