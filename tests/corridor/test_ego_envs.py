"""corridor/Merge-v0 and corridor/Overtaking-v0 (corridor.ego_env): Gymnasium's checker, determinism,
what the actions do, the safety layer, and a collision ending the episode with the metric in info; the
merge's PettingZoo ParallelEnv (corridor.envs.merge_parallel_env): the parallel API test, determinism.

Short episodes: the merge ego departs at 10 s (instead of 60 s), the overtaking ego at 5 s (instead of
60 s). libsumo allows one simulation per process and every ``reset`` closes the previous run, so one
process runs these environments one after the other.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

import corridor.envs  # noqa: F401  (registers the corridor/ ids)
from corridor.controllers.ego_actions import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from corridor.envs import merge_parallel_env
from corridor.errors import CorridorError

MERGE = {"agent_params": {"ego_depart_s": 10.0}, "max_episode_s": 12.0}
OVERTAKE = {"sets": ["backends.ego.params.depart_s=5"], "max_episode_s": 12.0}


def _rollout(env: Any, seed: int, actions: list[Any]) -> tuple[list[np.ndarray], list[float], dict[str, Any]]:
    obs, _ = env.reset(seed=seed)
    out, rewards, info = [obs], [], {}
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return out, rewards, info


@pytest.mark.parametrize("env_id,kwargs", [("corridor/Merge-v0", MERGE), ("corridor/Overtaking-v0", OVERTAKE)])
@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_gymnasium_make_and_check_env(env_id: str, kwargs: dict[str, Any], action_type: str) -> None:
    env = gymnasium.make(env_id, action_type=action_type, **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (5, 5)
    assert env.action_space == (gymnasium.spaces.Discrete(5) if action_type == "discrete"
                                else gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32))
    env.close()


@pytest.mark.parametrize("env_id,kwargs,actions", [
    ("corridor/Merge-v0", MERGE, [FASTER, IDLE, LANE_LEFT, SLOWER, LANE_LEFT, FASTER] * 3),
    ("corridor/Overtaking-v0", OVERTAKE, [FASTER, LANE_LEFT, FASTER, IDLE, LANE_RIGHT, SLOWER] * 3)])
def test_same_seed_same_trajectory(env_id: str, kwargs: dict[str, Any], actions: list[int]) -> None:
    """reset(seed=s) twice: identical observations, rewards and end row for the same actions."""
    env = gymnasium.make(env_id, **kwargs)
    a, ra, ia = _rollout(env, 3, actions)
    b, rb, ib = _rollout(env, 3, actions)
    assert len(a) == len(b) > 5 and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert ra == rb
    assert ia == ib and "collisions" in ia
    c, _, _ = _rollout(env, 4, actions)  # another seed: other traffic
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))
    env.close()


def test_merge_actions_drive_the_ramp_vehicle() -> None:
    """Only the agent merges its ego (its own lane changes are off): IDLE stays on the acceleration
    lane, LANE_LEFT moves onto the mainline; SLOWER lowers the speed and FASTER raises it."""
    env = gymnasium.make("corridor/Merge-v0", **{**MERGE, "max_episode_s": 40.0})
    _, _, info = _rollout(env, 1, [IDLE] * 40)
    assert info["ego_merged"] == 0 and info["ego_lane"] == "merge_0"  # stuck at the acceleration lane's end
    _, rewards, info = _rollout(env, 1, [IDLE] * 15 + [LANE_LEFT] * 25)
    assert info["ego_merged"] == 1 and 0.9 < max(rewards)  # the merged reward (1.0) once
    env.reset(seed=1)
    speeds = [env.step(SLOWER)[4]["ego_speed_mps"] for _ in range(4)]
    assert speeds[-1] < speeds[0] - 2.0
    speeds = [env.step(FASTER)[4]["ego_speed_mps"] for _ in range(4)]  # (up to the ramp's speed limit)
    assert speeds[-1] > speeds[0] + 2.0
    env.close()


def test_merge_full_throttle_is_capped_by_the_safety_layer() -> None:
    """Continuous [full throttle, merge left] every step: the Gipps/RSS bound lowers the command behind
    the mainline leader (seed 1), and nobody collides."""
    env = gymnasium.make("corridor/Merge-v0", action_type="continuous", **{**MERGE, "max_episode_s": 40.0})
    _, _, info = _rollout(env, 1, [np.array([1.0, 1.0], np.float32)] * 40)
    assert info["ego_merged"] == 1 and info["ego_safety_caps"] > 0 and info["collisions"] == 0
    env.close()


def test_overtaking_pass_completes_and_the_safety_layer_holds_full_throttle() -> None:
    env = gymnasium.make("corridor/Overtaking-v0", **OVERTAKE)
    _, rewards, info = _rollout(env, 0, [FASTER, LANE_LEFT, FASTER] + [IDLE] * 5 + [LANE_RIGHT] + [IDLE] * 10)
    assert info["ego_passed"] == 1 and info["collisions"] == 0 and max(rewards) > 1.0
    cont = gymnasium.make("corridor/Overtaking-v0", action_type="continuous", **OVERTAKE)
    _, _, info = _rollout(cont, 0, [np.array([1.0, 0.0], np.float32)] * 12)  # full throttle, straight on
    assert info["collisions"] == 0 and info["ego_safety_caps"] > 0 and info["min_gap_lead_m"] > 0.0
    env.close()
    cont.close()


def test_a_collision_ends_the_episode_with_the_metric_in_info() -> None:
    """Driving on in the oncoming lane of a busy road: a head-on collision ends the episode."""
    env = gymnasium.make("corridor/Overtaking-v0", sets=["backends.ego.params.depart_s=5",
                                                        "road.demand.flows.oncoming.flow_vph=1500"])
    _, rewards, info = _rollout(env, 0, [LANE_LEFT] * 2 + [FASTER] * 60)
    assert info["crashed"] and info["collisions"] >= 1 and rewards[-1] < 0.0
    assert env.unwrapped.sim is None  # the run is closed
    with pytest.raises(CorridorError, match="call reset"):
        env.step(IDLE)
    env.close()


def test_bad_settings_are_one_line_errors() -> None:
    with pytest.raises(CorridorError, match="action_type 'steer'"):
        gymnasium.make("corridor/Merge-v0", action_type="steer")
    with pytest.raises(CorridorError, match="no variant 'v2x'"):
        gymnasium.make("corridor/Merge-v0", variant="v2x")


def test_merge_parallel_env_api_and_determinism() -> None:
    """Every agent a connected vehicle near the merge (PettingZoo's parallel API test), joining when it
    comes near and leaving when done; the same seed and actions give the same observations."""
    env = merge_parallel_env(n_agents=3, agent_params={"ego_depart_s": 10.0}, max_episode_s=15.0)
    assert env.possible_agents == ["cv_0", "cv_1", "cv_2"]
    parallel_api_test(env, num_cycles=20)

    def run(seed: int) -> tuple[list[dict[str, np.ndarray]], set[str], dict[str, Any]]:
        obs, _ = env.reset(seed=seed)
        out, seen, info = [obs], set(env.agents), {}
        while env.agents:
            obs, _, _, _, info = env.step({a: (LANE_LEFT if k % 2 else FASTER) for k, a in enumerate(env.agents)})
            out.append(obs)
            seen |= set(obs)
        return out, seen, info

    a, seen, info = run(2)
    b, _, _ = run(2)
    assert seen == {"cv_0", "cv_1", "cv_2"} and len(a) == len(b) == 16  # 15 decisions of 1 s
    assert all(x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x) for x, y in zip(a, b, strict=True))
    assert all("collisions" in i and i["vid"] for i in info.values())
    assert len({i["vid"] for i in info.values()}) == len(info)  # one vehicle per agent
    env.close()
