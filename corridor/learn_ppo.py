"""``run_scenario SCENARIO --learn KEYS --method ppo``: PPO (stable-baselines3) through the Gymnasium env.

The comparison the issue asks for: a policy-gradient learner that is *not* localised to the
boundaries.  PPO trains a policy network on ``corridor.envs.CorridorEnv``: one agent (the first of
the controller's agents, e.g. one UAV) decides, every controller period, the switch whose
boundaries ``KEYS`` name (``avoid_enter.*`` / ``avoid_exit.*``: the pair ``(avoid_enter,
avoid_exit)``), from highway-env's Kinematics observation; the other agents keep their boundaries.
With the merge's boundaries (``merge_enter.*``, ``gap_accept.*``, ``yield_enter.*``, ...), whose
vehicles come and go, it trains on ``corridor.decision_env.DecisionEnv`` instead: one policy shared
by every vehicle, one step per pending switch decision inside blrl's band.
The reward is the row's ``objective - PENALTY x violated constraints`` at the end of the run (the
same expression ``blrl`` and ``cma`` maximise).

What it produces, and how that maps onto ``blrl``/``cma``:

- stages: a stage is one PPO rollout of ``EPISODES_PER_STAGE`` runs followed by its update; every
  finished run's row (the env's ``info``: the run's metrics and seed) is written to
  ``DIR/stages/NNN/rows.parquet`` as the stage ends, and the curve (objective per stage with its
  95 % interval, violating runs) goes to ``learn.json`` as for the other methods.
- **no theta**: PPO learns a state-feedback policy, not boundary parameters, so there is no
  ``learned.yaml`` (``run_scenario`` cannot run a neural policy).  Instead ``DIR/ppo_policy.zip``
  (the stable-baselines3 model) and ``DIR/ppo_vecnormalize.pkl`` (its observation normaliser);
  ``learn.json`` has ``"theta": null`` and ``"policy"``.  ``evaluate_policy(DIR, seed, draws)`` re-runs it.
- held-out: theta0 runs through the batch runner on ``--holdout`` seeds never used in training, with
  deterministic boundaries (as for ``blrl``/``cma``), and the PPO policy (deterministic actions) runs in
  the environment on the same seeds with the same ``randomize`` draws; the paired difference of the
  objective gets a 95 % t interval.  The training seeds are drawn by the environment; how many of
  them are also held-out seeds is reported (``holdout.overlap_training_seeds``).
- checkpoints: the policy and its normaliser after 4, 8, 16, 32 and every 48 training runs
  (``DIR/checkpoints/epNNNNN``), so that ``tools/learn_benchmark.py checkpoints`` can run them on held-out seeds.
- not mapped: ``--resume`` (the optimiser state is not saved per stage) and ``--executor ray`` (the
  environment is stepped in this process): both are refused with one line.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from corridor.errors import CorridorError
from corridor.learn_core import PENALTY, PPO_EPISODES_PER_STAGE, Problem, ci95, finite, specs, summary
from corridor.objective import value

EPISODES_PER_STAGE = PPO_EPISODES_PER_STAGE  # runs per rollout (n_steps = EPISODES_PER_STAGE x decisions per run)
N_EPOCHS = 4
LEARNING_RATE = 3e-4
SWITCHES = {"avoid_enter": ("avoid_enter", "avoid_exit"), "avoid_exit": ("avoid_enter", "avoid_exit")}
POLICY = "ppo_policy.zip"
NORMALISER = "ppo_vecnormalize.pkl"
CHECKPOINTS = "checkpoints"  # DIR/checkpoints/epNNNNN/{POLICY, NORMALISER}: the policy after NNNNN training runs
GAMMA_DECISIONS = 1.0  # the merge's decision points: the run's one reward, undiscounted over its decisions
CHECKPOINT_EVERY = 48  # runs between checkpoints (blrl's budget on uav_encounter), besides 4, 8, 16, 32


def checkpoint_episodes(budget: int) -> list[int]:
    """Training runs after which the policy is saved: every stage up to 32 that is a power of two, then
    every ``CHECKPOINT_EVERY`` runs, below the final budget (the final policy is ``POLICY`` itself)."""
    n = (budget // EPISODES_PER_STAGE) * EPISODES_PER_STAGE
    early = [EPISODES_PER_STAGE * 2**k for k in range(8) if EPISODES_PER_STAGE * 2**k <= 32]
    return sorted({e for e in [*early, *range(CHECKPOINT_EVERY, n, CHECKPOINT_EVERY)] if 0 < e < n})


def check(pb: Problem, resume: bool, executor: str) -> tuple[str, ...]:
    """The boundaries the env decides for ``pb``'s keys (the avoid pair, or the merge's boundaries the
    keys name); refuses what PPO does not map (one line each)."""
    try:
        import stable_baselines3  # noqa: F401

        from corridor.decision_env import MERGE_BOUNDARIES
    except ImportError:
        raise CorridorError("--method ppo needs stable-baselines3: pip install -e '.[rl]'") from None
    names = {k.split(".params.boundaries.", 1)[1].split(".", 1)[0] for k in pb.keys}
    pairs = {SWITCHES.get(n) for n in names}
    if names <= set(MERGE_BOUNDARIES):
        switch: tuple[str, ...] = tuple(n for n in MERGE_BOUNDARIES if n in names)
    elif None in pairs or len(pairs) != 1:
        raise CorridorError(f"--method ppo: corridor.envs decides the avoid_enter/avoid_exit switch, corridor.decision_env "
                            f"the merge's boundaries ({', '.join(MERGE_BOUNDARIES)}); --learn names {', '.join(sorted(names))}")
    else:
        pair = pairs.pop()
        assert pair is not None
        switch = pair
    if resume:
        raise CorridorError("--resume: --method ppo keeps no per-stage training state; start afresh")
    if executor != "local":
        raise CorridorError(f"--executor {executor}: --method ppo steps its environment in this process")
    return switch


def decision_points(switch: tuple[str, ...]) -> bool:
    """Whether ``switch`` is decided in the decision-point environment (the merge) rather than per period."""
    return tuple(switch) not in set(SWITCHES.values())


def make_env(pb: Problem, sets: list[str], switch: tuple[str, ...]) -> Any:
    if decision_points(switch):
        from corridor.decision_env import DecisionEnv

        return DecisionEnv(scenario=pb.path, controller=pb.controller, variant=pb.variant, sets=sets,
                           boundaries=switch, objective=pb.objective.text,
                           constraints=tuple(c.text for c in pb.constraints), penalty=PENALTY,
                           penalty_kind=pb.penalty)
    from corridor.envs import CorridorEnv

    return CorridorEnv(scenario=pb.path, controller=pb.controller, variant=pb.variant, sets=sets,
                       switch=(switch[0], switch[1]),
                       objective=pb.objective.text, constraints=tuple(c.text for c in pb.constraints),
                       penalty=PENALTY, penalty_kind=pb.penalty)


def decisions_per_run(env: Any) -> int:
    """Steps of one episode: the decision periods after the first, which the boundaries decide; in the
    decision-point environment the decisions of the run of seed 0 under uniformly random actions (what
    PPO's first policy does; a policy that switches later meets more decisions)."""
    if hasattr(env, "boundaries"):
        rng = np.random.default_rng(0)
        env.reset(seed=0)
        n = 0
        while True:
            n += 1
            _, _, terminated, _, _ = env.step(int(rng.integers(2)))
            if terminated:
                env.close()
                return max(n, 1)
    env.reset(seed=0)
    ep = env.unwrapped.episode
    n = math.ceil((ep.sim.n_ticks - ep.tick) / ep.ticks_per_decision)
    env.close()
    return max(int(n), 1)


def train(pb: Problem, budget: int, seed: int, out: Path, sets: list[str], switch: tuple[str, ...]
          ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """PPO for ``budget // EPISODES_PER_STAGE`` stages; (curve, every training row).

    The avoid switch: every run has the same number of steps, a rollout is ``EPISODES_PER_STAGE`` runs.
    The merge's decision points: runs differ in decisions, a rollout is ``EPISODES_PER_STAGE`` x the
    decisions of a probe run (seed 0 at theta0), a stage holds the runs that ended in it, training stops
    after the update of the first rollout by which ``budget // EPISODES_PER_STAGE x EPISODES_PER_STAGE``
    runs have ended (so a few more may have; the run cut by that rollout's end is not counted), and the
    terminal reward is not discounted (``GAMMA_DECISIONS``: thousands of decisions share one reward at the run's end).
    """
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    variable = decision_points(switch)
    steps = decisions_per_run(make_env(pb, sets, switch))
    venv = VecNormalize(DummyVecEnv([lambda: make_env(pb, sets, switch)]), norm_obs=True, norm_reward=False)
    n_steps = steps * EPISODES_PER_STAGE
    extra: dict[str, Any] = {"gamma": GAMMA_DECISIONS} if variable else {}
    model = PPO("MlpPolicy", venv, n_steps=n_steps, batch_size=steps, n_epochs=N_EPOCHS,
                learning_rate=LEARNING_RATE, seed=seed, device="cpu", verbose=0, **extra)
    curve: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    episodes = (budget // EPISODES_PER_STAGE) * EPISODES_PER_STAGE
    pending = sorted(checkpoint_episodes(budget))
    ended = [0]  # training runs ended so far

    def flush(stage_rows: list[dict[str, Any]]) -> None:
        import pandas as pd

        stage = len(curve)
        batch = [{**r, "run_id": f"{pb.variant}-train{stage:03d}-{i:05d}", "learn.stage": f"{stage:03d}"}
                 for i, r in enumerate(stage_rows)]
        (out / "stages" / f"{stage:03d}").mkdir(parents=True, exist_ok=True)
        pd.DataFrame(batch).to_parquet(out / "stages" / f"{stage:03d}" / "rows.parquet", index=False)
        r = np.array([pb.reward(x) for x in batch])
        curve.append({"stage": stage, "theta": None, **summary(r, batch, pb)})
        rows.extend(batch)

    class Stages(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.stage_rows: list[dict[str, Any]] = []
            self.stop = False

        def _on_rollout_start(self) -> None:
            self.stop = variable and ended[0] >= episodes  # the decision points: the budget's runs trained on
            # the policy (and its normaliser) trained on every run ended before this rollout
            while pending and ended[0] >= pending[0]:
                done = pending.pop(0)
                dest = out / CHECKPOINTS / f"ep{(ended[0] if variable else done):05d}"
                dest.mkdir(parents=True, exist_ok=True)
                model.save(dest / POLICY)
                venv.save(str(dest / NORMALISER))

        def _on_step(self) -> bool:
            if self.stop:
                return False
            for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                if done:
                    row = {k: v for k, v in info.items() if k not in ("terminal_observation", "TimeLimit.truncated")}
                    self.stage_rows.append({**row, "status": "ok"})
                    ended[0] += 1
            return True

        def _on_rollout_end(self) -> None:
            if self.stage_rows:  # the decision points: a rollout may end no run (they go on into the next)
                flush(self.stage_rows)
            self.stage_rows = []

    with _lean_torch():
        model.learn(total_timesteps=n_steps * (budget // EPISODES_PER_STAGE) * (1000 if variable else 1), callback=Stages())
    model.save(out / POLICY)
    venv.save(str(out / NORMALISER))
    venv.close()
    return curve, rows


@contextmanager
def _lean_torch() -> Iterator[None]:
    """PyTorch without what PPO's small networks do not need, restored afterwards: one intra-op thread (a
    batch of one, and minibatches of a few thousand rows of 64 units: a second thread only takes the other
    core) and no argument validation of the action distribution at each decision (it checks, computes
    nothing).  The same training rows for a seed; the weights differ from a two-thread run in the last bits
    (another summation order), and no longer depend on the machine's core count."""
    import torch

    threads, validate = torch.get_num_threads(), torch.distributions.Distribution._validate_args
    torch.set_num_threads(1)
    torch.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
        torch.distributions.Distribution.set_default_validate_args(validate)


def evaluate_policy(folder: str | Path, pb: Problem, sets: list[str], switch: tuple[str, ...], seed: int,
                    draws: dict[str, Any] | None = None) -> dict[str, Any]:
    """One run of the saved PPO policy (deterministic actions) at ``seed`` with ``draws``: its row."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    folder = Path(folder)
    env = make_env(pb, sets, switch)
    norm = VecNormalize.load(str(folder / NORMALISER), DummyVecEnv([lambda: make_env(pb, sets, switch)]))
    norm.training = False
    model = PPO.load(folder / POLICY, device="cpu")
    obs, _ = env.reset(seed=seed, options={"draws": draws} if draws is not None else None)
    try:
        while True:
            action, _ = model.predict(norm.normalize_obs(obs[None]), deterministic=True)
            obs, _, terminated, truncated, info = env.step(int(action[0]))
            if terminated or truncated:
                return {**info, "status": "ok"}
    finally:
        env.close()
        norm.close()


def holdout(pb: Problem, folder: Path, n: int, seed: int, sets: list[str], switch: tuple[str, ...], run: Any,
            training_seeds: set[int]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """theta0 (batch runner) against the PPO policy (env) on the same ``n`` held-out seeds and draws."""
    if n < 1:
        return {}, []
    hold = specs(pb, folder, seed, "hold", 0, np.tile(pb.theta0, (n, 1)), None, prefix="hold0")
    rows0 = run(hold, "hold0")
    rows1 = [{**evaluate_policy(folder, pb, sets, switch, s.seed, s.draws),
              "run_id": s.run_id.replace("hold0", "hold1"), "learn.stage": "hold1"} for s in hold]
    objs = [np.array([value(pb.objective, r) if r.get("status") == "ok" else math.nan for r in rows])
            for rows in (rows0, rows1)]
    diff = objs[1] - objs[0]
    res = {"runs": n, "hand_tuned": summary(np.array([pb.reward(r) for r in rows0]), rows0, pb),
           "learned": summary(np.array([pb.reward(r) for r in rows1]), rows1, pb),
           "paired_diff_mean": finite(np.nanmean(diff)), "paired_diff_ci95": ci95(diff),
           "overlap_training_seeds": len({s.seed for s in hold} & training_seeds)}
    return res, rows1
