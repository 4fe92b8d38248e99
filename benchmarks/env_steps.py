"""Reset and step cost of ``corridor/UavEncounter-v0`` against highway-env's ``merge-v0``, on this machine.

    python benchmarks/env_steps.py [--episodes 3] [--duration 30]

Both environments take random actions. The figures are wall seconds per reset, steps per second,
and simulated seconds per wall second. A corridor step is one controller period (0.2 s); it runs two
JSBSim quadcopters and a c172x at 120 Hz, the MAVLink link and the monitors. A highway-env step is
one policy period (1 s at 15 Hz simulation). Not run by CI; on a shared machine read the ratios,
not the absolute figures.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium
import numpy as np


def measure(env: Any, episodes: int, sim_s_per_step: float) -> dict[str, float]:
    rng = np.random.default_rng(0)
    reset_s, step_s, steps = 0.0, 0.0, 0
    for ep in range(episodes):
        t0 = time.perf_counter()
        env.reset(seed=ep)
        reset_s += time.perf_counter() - t0
        done = False
        t0 = time.perf_counter()
        while not done:
            _, _, term, trunc, _ = env.step(int(rng.integers(env.action_space.n)))
            steps += 1
            done = term or trunc
        step_s += time.perf_counter() - t0
    env.close()
    return {"reset_s": reset_s / episodes, "steps_per_s": steps / step_s,
            "sim_s_per_wall_s": steps * sim_s_per_step / step_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0, help="corridor episode length [s]")
    args = ap.parse_args()
    import highway_env  # noqa: F401  (registers merge-v0)

    import corridor.envs  # noqa: F401  (registers corridor/UavEncounter-v0)

    rows = {"corridor/UavEncounter-v0": measure(gymnasium.make("corridor/UavEncounter-v0",
                                                               sets=[f"duration={args.duration}"]), args.episodes, 0.2),
            "highway-env merge-v0": measure(gymnasium.make("merge-v0"), args.episodes, 1.0)}
    print(f"{'environment':28s} {'reset [s]':>10s} {'steps/s':>10s} {'sim s / wall s':>15s}")
    for name, r in rows.items():
        print(f"{name:28s} {r['reset_s']:10.3f} {r['steps_per_s']:10.1f} {r['sim_s_per_wall_s']:15.1f}")


if __name__ == "__main__":
    main()
