"""PPO (stable-baselines3) on ``corridor/Merge-v0`` against two fixed policies, on held-out seeds.

    python benchmarks/ppo_merge.py [--timesteps 20000] [--eval-seeds 20] [--out results/ppo_merge]

Trains ``MlpPolicy`` PPO (stable-baselines3's defaults but ``n_steps=512``, one torch thread) for
``--timesteps`` decisions (1 s each) with training seeds drawn by the environment, then runs three
policies on the held-out seeds ``10_000 ..`` (never asked for in training; a drawn training seed
could coincide with one with probability ~1e-5): the trained policy (deterministic actions),
``idle`` (IDLE every step: the ego never merges, it waits at the end of the acceleration lane
until the episode is truncated) and ``merge_asap`` (LANE_LEFT every step: SUMO moves the ego over
into the first gap that respects the others' safe gaps). Printed per policy: the mean return with
its 95 % t interval, the share of merged egos, collisions, and the ego's mean speed. The model is
saved to ``--out``. CPU seconds of training and evaluation are printed: scale ``--timesteps``
from them.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from scipy import stats

from corridor.controllers.ego_actions import IDLE, LANE_LEFT

HELD_OUT = 10_000  # first held-out seed


def episode(env: Any, seed: int, policy: Any) -> dict[str, float]:
    obs, _ = env.reset(seed=seed)
    total, done, speeds = 0.0, False, []
    while not done:
        obs, r, term, trunc, info = env.step(policy(obs))
        total += r
        speeds.append(info["ego_speed_mps"])
        done = term or trunc
    return {"return": total, "merged": info["ego_merged"], "collisions": info["collisions"],
            "crashed": int(info["crashed"]), "speed": float(np.mean(speeds))}


def ci95(x: np.ndarray) -> tuple[float, float]:
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)) if len(x) > 1 else float("nan")
    return float(x.mean()), float(half)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--timesteps", type=int, default=20_000)
    ap.add_argument("--eval-seeds", type=int, default=20)
    ap.add_argument("--out", default="results/ppo_merge")
    args = ap.parse_args()
    import torch
    from stable_baselines3 import PPO

    import corridor.envs  # noqa: F401  (registers corridor/Merge-v0)

    torch.set_num_threads(1)
    env = gymnasium.make("corridor/Merge-v0")
    model = PPO("MlpPolicy", env, n_steps=512, seed=0, verbose=0)
    t0 = time.process_time()
    model.learn(total_timesteps=args.timesteps)
    train_cpu = time.process_time() - t0
    Path(args.out).mkdir(parents=True, exist_ok=True)
    model.save(Path(args.out) / "ppo_merge.zip")
    policies = {"ppo": lambda o: int(model.predict(o, deterministic=True)[0]),
                "idle": lambda o: IDLE, "merge_asap": lambda o: LANE_LEFT}
    t0 = time.process_time()
    rows = {name: [episode(env, HELD_OUT + k, pol) for k in range(args.eval_seeds)] for name, pol in policies.items()}
    eval_cpu = time.process_time() - t0
    print(f"PPO {args.timesteps} timesteps: {train_cpu:.0f} CPU s training; evaluation {eval_cpu:.0f} CPU s; "
          f"held-out seeds {HELD_OUT}..{HELD_OUT + args.eval_seeds - 1}")
    print(f"{'policy':12s} {'return (95% CI)':>20s} {'merged':>7s} {'crashed':>8s} {'collisions':>11s} {'speed [m/s]':>12s}")
    for name, rs in rows.items():
        ret = np.array([r["return"] for r in rs])
        m, h = ci95(ret)
        print(f"{name:12s} {m:10.2f} ± {h:6.2f} {np.mean([r['merged'] for r in rs]):7.2f}"
              f" {np.sum([r['crashed'] for r in rs]):8d} {np.sum([r['collisions'] for r in rs]):11d}"
              f" {np.mean([r['speed'] for r in rs]):12.1f}")
    diff = np.array([a["return"] - b["return"] for a, b in zip(rows["ppo"], rows["merge_asap"])])
    m, h = ci95(diff)
    print(f"paired ppo - merge_asap: {m:.2f} ± {h:.2f} (95 % t interval, {len(diff)} seeds)")
    env.close()


if __name__ == "__main__":
    main()
