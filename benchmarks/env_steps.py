"""Reset and step cost of corridor's Gymnasium environments against highway-env's ``merge-v0``, on this machine.

    python benchmarks/env_steps.py [--episodes 3] [--hw-episodes 20] [--duration 30] [--only merge,overtaking,uav]

Every environment takes uniformly random actions (seeded) for ``--episodes`` episodes. Printed: CPU
seconds per reset, steps per CPU second, simulated seconds per CPU second, and each corridor
environment's ratio to highway-env's ``merge-v0`` measured in the same run (CPU time of this
process: on a shared machine the ratios hold, wall-clock figures would not).

- ``corridor/Merge-v0``: a step is 1 s (highway-env's policy period): 10 SUMO ticks of the merging
  scenario (a 2.7 km freeway with its on-ramp at 3,000+ vehicles/h of calibrated human drivers) with
  its monitors; the reset runs the scenario until the ego departs (``ego_depart_s``, 60 s by default).
- ``corridor/Overtaking-v0``: a step is 1 s: 10 ticks of the kinematic-bicycle ego, SUMO and the
  overtaking monitors; the reset runs the 60 s of oncoming traffic before the ego enters.
- ``corridor/UavEncounter-v0``: a step is one controller period (0.2 s) of two JSBSim quadcopters and
  a c172x at 120 Hz, the MAVLink link and the monitors.
- highway-env ``merge-v0``: a step is 1 s (15 Hz simulation), its reset builds the road and a few
  vehicles.
Not run by CI.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium


def measure(env: Any, episodes: int, sim_s_per_step: float, max_steps: int = 10_000) -> dict[str, float]:
    """CPU seconds per reset, and steps / simulated seconds per CPU second, over random actions."""
    env.action_space.seed(0)
    reset_s, step_s, steps = 0.0, 0.0, 0
    for ep in range(episodes):
        t0 = time.process_time()
        env.reset(seed=ep)
        reset_s += time.process_time() - t0
        done, n = False, 0
        t0 = time.process_time()
        while not done and n < max_steps:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            n += 1
            done = term or trunc
        step_s += time.process_time() - t0
        steps += n
    env.close()
    return {"reset_s": reset_s / episodes, "steps_per_s": steps / step_s,
            "sim_s_per_cpu_s": steps * sim_s_per_step / step_s, "steps": steps}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0, help="UavEncounter episode length [s]")
    ap.add_argument("--only", default="merge,overtaking,uav", help="corridor environments to measure")
    ap.add_argument("--hw-episodes", type=int, default=20, help="highway-env merge-v0 episodes (they are short)")
    args = ap.parse_args()
    import highway_env  # noqa: F401  (registers merge-v0)

    import corridor.envs  # noqa: F401  (registers the corridor/ ids)

    which = set(args.only.split(","))
    rows: dict[str, dict[str, float]] = {
        "highway-env merge-v0": measure(gymnasium.make("merge-v0"), args.hw_episodes, 1.0)}
    if "merge" in which:
        rows["corridor/Merge-v0"] = measure(gymnasium.make("corridor/Merge-v0"), args.episodes, 1.0)
    if "overtaking" in which:
        rows["corridor/Overtaking-v0"] = measure(gymnasium.make("corridor/Overtaking-v0"), args.episodes, 1.0)
    if "uav" in which:
        rows["corridor/UavEncounter-v0"] = measure(
            gymnasium.make("corridor/UavEncounter-v0", sets=[f"duration={args.duration}"]), args.episodes, 0.2)
    ref = rows["highway-env merge-v0"]
    print(f"{'environment':28s} {'steps':>6s} {'reset [cpu s]':>14s} {'steps/cpu s':>12s} {'sim s/cpu s':>12s}"
          f" {'reset / hw':>11s} {'steps/s / hw':>13s}")
    for name, r in rows.items():
        print(f"{name:28s} {r['steps']:6.0f} {r['reset_s']:14.3f} {r['steps_per_s']:12.1f} {r['sim_s_per_cpu_s']:12.1f}"
              f" {r['reset_s'] / ref['reset_s']:11.1f} {r['steps_per_s'] / ref['steps_per_s']:13.2f}")


if __name__ == "__main__":
    main()
