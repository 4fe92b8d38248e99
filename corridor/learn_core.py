"""What every ``--learn`` method shares: the problem, its run specs and the stage summaries."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from corridor.objective import Expression, hinge_violations, value, violations

PENALTY = 1.0  # objective units per broken constraint (--penalty hinge: per broken constraint and unit past it)
PENALTIES = ("count", "hinge")
PPO_EPISODES_PER_STAGE = 4  # --method ppo: runs per PPO rollout (corridor.learn_ppo)


@dataclass
class Problem:
    """What is learned and how it is judged (validated before any folder is touched)."""

    sc: Any
    raw: dict[str, Any]
    path: Path
    variant: str
    controller: str
    keys: list[str]  # full dotted paths
    theta0: np.ndarray
    log: np.ndarray  # per key: searched in log space
    objective: Expression
    constraints: list[Expression]
    after: dict[str, Any] = field(default_factory=dict)  # --set values
    # hysteresis pairs (the controller's ``hysteresis``): (follower, anchor, +1: theta_f >= theta_a, -1: <=)
    # with both keys learned: the follower's coordinate is the margin |log(theta_f / theta_a)| >= 0
    pairs: list[tuple[int, int, int]] = field(default_factory=list)
    # one key of a pair learned: (key, the other's fixed value, +1: theta >= it, -1: <=), a clamp
    bounds: list[tuple[int, float, int]] = field(default_factory=list)
    # "count": PENALTY x the broken constraints; "hinge": PENALTY x (1 + how far past it) per broken one
    penalty: str = "count"

    def theta(self, u: np.ndarray) -> np.ndarray:
        """theta of the learner's coordinates ``u``: log theta (positive keys), a follower's margin
        max(u, 0) in log units over its anchor, so a learned exit never crosses its enter."""
        th = np.where(self.log, np.exp(u), u)
        for i, j, d in self.pairs:
            th[i] = th[j] * math.exp(d * max(float(u[i]), 0.0))
        for i, ref, d in self.bounds:
            th[i] = max(th[i], ref) if d > 0 else min(th[i], ref)
        return th

    def u0(self) -> np.ndarray:
        u = np.where(self.log, np.log(np.where(self.log, self.theta0, 1.0)), self.theta0)
        for i, j, d in self.pairs:
            u[i] = d * math.log(self.theta0[i] / self.theta0[j])
        return u

    def grad_u(self, grad_theta: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """d J / d u from d J / d theta.  A pair's shared draw moves anchor and follower together: its
        score (on the anchor's column) is the gradient of the anchor's coordinate, which moves both;
        it says nothing of the margin, whose gradient is 0 (the follower's column repeats the anchor's)."""
        g = grad_theta * np.where(self.log, theta, 1.0)  # chain rule: d theta / d log theta
        for i, _j, _d in self.pairs:
            g[i] = 0.0
        return g

    def overrides(self, theta: np.ndarray, temperature: float | None) -> dict[str, Any]:
        out: dict[str, Any] = {k: float(v) for k, v in zip(self.keys, theta, strict=True)}
        out[f"controllers.{self.controller}.params.switching.temperature"] = temperature
        return out

    def reward(self, row: dict[str, Any]) -> float:
        if row.get("status") != "ok":
            return math.nan
        v = value(self.objective, row)
        broken = (hinge_violations if self.penalty == "hinge" else violations)(self.constraints, row)
        return (v if math.isfinite(v) else -PENALTY) - PENALTY * broken


def stage_normals(seed: int, tag: str, stage: int, n: int, d: int) -> np.ndarray:
    from corridor.engine import stable_key

    ss = np.random.SeedSequence(seed, spawn_key=(stable_key(f"learn-{tag}"), stage))
    return np.random.default_rng(ss).standard_normal((n, d))


def specs(pb: Problem, out: Path, seed: int, tag: str, stage: int, thetas: np.ndarray,
           temperature: float | None, prefix: str | None = None) -> list[Any]:
    """One run per theta; the draws and seeds are keyed by ``tag`` and the stage (common to every
    ``prefix``: the held-out runs of theta0 and the learned theta see the same inputs)."""
    from corridor.distributions import draws_from_normal
    from corridor.estimate import stage_seeds
    from corridor.run import RunSpec

    z = stage_normals(seed, tag, stage, len(thetas), len(pb.sc.randomize))
    seeds = stage_seeds(seed + (0 if tag == "train" else 7919), stage, len(thetas))
    specs = []
    for i, (th, zi, s) in enumerate(zip(thetas, z, seeds, strict=True)):
        draws = draws_from_normal(pb.sc.randomize, zi)
        specs.append(RunSpec(run_id=f"{pb.variant}-{prefix or tag}{stage:03d}-{i:05d}", scenario=pb.sc.name, source=str(pb.path),
                             variant=pb.variant, seed=s, base=pb.raw,
                             overrides={**pb.sc.sweep[pb.variant], **draws, **pb.after,
                                        **pb.overrides(th, temperature)},
                             draws=draws, out_dir=str(out)))
    return specs


def is_nan(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def summary(rewards: np.ndarray, rows: list[dict[str, Any]], pb: Problem) -> dict[str, Any]:
    objs = np.array([value(pb.objective, r) if r.get("status") == "ok" else math.nan for r in rows])
    viol = int(sum(violations(pb.constraints, r) > 0 for r in rows))
    return {"objective_mean": finite(np.nanmean(objs)), "objective_ci95": ci95(objs), "reward_mean": finite(np.nanmean(rewards)),
            "violating_runs": viol, "runs": len(rows)}


def finite(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def ci95(x: np.ndarray) -> list[float | None]:
    """95 % t interval of the mean."""
    from scipy import stats

    x = x[np.isfinite(x)]
    if len(x) < 2:
        return [None, None]
    h = float(stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x)))
    return [finite(x.mean() - h), finite(x.mean() + h)]
