"""Subset simulation (Au & Beck, Probabilistic Engineering Mechanics 16(4), 2001), a multilevel
splitting method, with preconditioned Crank-Nicolson moves in the standard-normal space (Cotter et
al., Statistical Science 28(3), 2013; for subset simulation, Papaioannou et al., Prob. Eng. Mech. 41,
2015).

Level 0: ``n`` nominal runs.  Each next level keeps the ``p0`` fraction with the lowest score as
seeds (failures first, ``analysis.rare.ce.scores``), their worst score as the intermediate threshold
``b``, and moves each seed by ``burn + 1 / p0`` MCMC steps: ``z' = r z + sqrt(1 - r^2) xi`` leaves
``N(0, I)`` invariant, so a state is accepted iff its score is ``<= b``.  The level's samples are each
chain's last ``1 / p0`` states: with ``burn = 1`` the seeds themselves (the previous level's extreme
samples) are not reused, which lowers the correlation between levels.  One MCMC step of every chain
is one stage of runs; ``r`` is adapted per level towards 40 % acceptance.  When at least ``p0 n``
samples of a level fail, ``P = p0^m * k / n``.  ``n`` is sized so that the budget reaches ~1e-6.

Coefficient of variation: ``delta^2 = sum_i (1 - p_i) / (p_i n) * (1 + gamma_i)``, ``gamma_i`` from
the chains' indicator correlation (Au & Beck eq. 29); the 95 % interval is log-normal with it.  Even
with independent samples at every level (``gamma = 0``) ``delta^2 ~ (ln p)^2 (1 - p0) / (p0 (ln p0)^2 B)``
for a budget of ``B`` runs: ~0.12 for p = 3.4e-6 and B = 2,000 (see the README, "Safety statistics").

``select`` replaces the choice of the lowest ``p0 n`` states as seeds (``splitting_is`` passes a quota
per cluster, ``quota.py``); the estimate above then is a diagnostic only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from corridor.analysis.rare.ce import Z95, scores, stage_rng


def chain_gamma(ind: np.ndarray) -> float:
    """Au & Beck's correlation factor of an indicator over ``chains x steps`` samples."""
    nc, ns = ind.shape
    p = ind.mean()
    r0 = p * (1 - p)
    if ns < 2 or r0 <= 0:
        return 0.0
    n = nc * ns
    gamma = 0.0
    for k in range(1, ns):
        rk = float((ind[:, :-k] * ind[:, k:]).sum() / (n - k * nc)) - p * p
        gamma += 2 * (1 - k * nc / n) * rk / r0
    return max(0.0, gamma)


def level_size(budget: int, p0: float, burn: int, p_min: float = 1e-6) -> int:
    """Samples per level: level 0 and the chain levels down to ``p_min`` fit into ``budget`` runs."""
    per = int(round(1 / p0))
    levels = max(1, math.ceil(math.log(p_min) / math.log(p0)) - 1)  # chain levels after level 0
    chain_cost = (per - 1 + burn) / per  # runs per sample of a chain level
    return max(per * 5, int(budget / (1 + chain_cost * levels)) // per * per)


class SubsetSimulation:
    TAG = 0x55
    MIN_BUDGET = 100  # level 0 (50 runs at p0 = 0.1) and one level of chains (5 chains x 10 steps)
    MIN_BUDGET_WHY = "50 nominal runs and one level of Markov chains, 50 runs"

    def __init__(self, dim: int, budget: int, seed: int, p0: float = 0.1, n_level: int | None = None,
                 burn: int = 1, select: Callable[[np.ndarray, np.ndarray, int], np.ndarray] | None = None) -> None:
        self.dim, self.budget, self.seed, self.p0, self.burn = dim, budget, seed, p0, burn
        self.select = select  # seed choice (z, score, n_seeds) -> indices; None: the lowest
        self.per = int(round(1 / p0))
        self.n = n_level or level_size(budget, p0, burn)
        self.n_seeds = int(round(p0 * self.n))
        self.steps = self.per - 1 + burn  # MCMC steps (runs) of each chain per level
        self.r = 0.8  # pCN correlation (step size sqrt(1 - r^2) = 0.6), adapted per level
        self.stage, self.used, self.done = 0, 0, False
        self.levels: list[dict[str, Any]] = []
        self.chains_z: np.ndarray | None = None  # (chains, states, dim)
        self.chains_s: np.ndarray | None = None  # (chains, states)
        self.threshold: float | np.ndarray = math.inf  # per chain: max(level threshold, its seed's score)
        self.step = 0
        self.accepted = 0
        self._z: np.ndarray | None = None
        self._result: dict[str, Any] = {}

    def ask(self) -> np.ndarray | None:
        if self.done:
            return None
        rng = stage_rng(self.seed, self.stage, self.TAG)
        if self.chains_z is None:
            self._z = rng.standard_normal((self.n, self.dim))
        else:
            cur = self.chains_z[:, self.step]
            self._z = self.r * cur + math.sqrt(1 - self.r**2) * rng.standard_normal(cur.shape)
        return self._z

    def tell(self, level: np.ndarray, fail: np.ndarray) -> None:
        z, self._z = self._z, None
        assert z is not None, "tell() without ask()"
        s = scores(np.asarray(level, float), np.asarray(fail, bool))
        self.used += len(z)
        self.stage += 1
        if self.chains_z is None:  # level 0: iid nominal samples, one state per "chain"
            self._level_done(z[:, None, :], s[:, None], gamma=0.0)
            return
        ok = s <= self.threshold
        self.accepted += int(ok.sum())
        cur_z, cur_s = self.chains_z[:, self.step], self.chains_s[:, self.step]
        self.chains_z = np.concatenate([self.chains_z, np.where(ok[:, None], z, cur_z)[:, None]], axis=1)
        self.chains_s = np.concatenate([self.chains_s, np.where(ok, s, cur_s)[:, None]], axis=1)
        self.step += 1
        if self.step == self.steps:
            rate = self.accepted / (self.steps * self.n_seeds)
            self.levels[-1]["acceptance"] = round(rate, 3)
            self.levels[-1]["pcn_r"] = round(self.r, 3)
            # adapt the step towards ~40 % acceptance (deterministic: from the told values only)
            step = math.sqrt(1 - self.r**2) * math.exp(0.8 * (rate - 0.4))
            self.r = math.sqrt(1 - min(0.95, max(0.05, step)) ** 2)
            keep = slice(self.steps + 1 - self.per, None)  # each chain's last 1/p0 states
            self._level_done(self.chains_z[:, keep], self.chains_s[:, keep], gamma=None)

    def _level_done(self, cz: np.ndarray, cs: np.ndarray, gamma: float | None) -> None:
        flat_z, flat_s = cz.reshape(-1, self.dim), cs.reshape(-1)
        n = len(flat_s)
        n_fail = int(np.isneginf(flat_s).sum())
        order = np.argsort(flat_s, kind="stable")
        seeds = order[: self.n_seeds]
        b = float(flat_s[seeds[-1]])
        final = n_fail >= self.n_seeds or self.used + self.n_seeds * self.steps > self.budget
        p_i = n_fail / n if final else self.n_seeds / n
        ind = (np.isneginf(cs) if final else cs <= b).astype(float)
        g = chain_gamma(ind) if gamma is None else gamma
        self.levels.append({"level": len(self.levels), "runs_total": self.used, "threshold": None if final else b,
                            "conditional_p": p_i, "failures": n_fail, "gamma": round(g, 3),
                            "min_level": float(np.min(flat_s[np.isfinite(flat_s)])) if np.isfinite(flat_s).any() else None})
        if final:
            self._finish(reached=n_fail >= self.n_seeds or n_fail > 0)
            return
        if self.select is not None:
            seeds = self.select(flat_z, flat_s, self.n_seeds)
            self.levels[-1]["seeds_above_threshold"] = int((flat_s[seeds] > b).sum())
        self.threshold = np.maximum(b, flat_s[seeds])
        self.chains_z, self.chains_s = flat_z[seeds][:, None, :], flat_s[seeds][:, None]
        self.step = self.accepted = 0

    def _finish(self, reached: bool) -> None:
        self.done = True
        ps = np.array([lv["conditional_p"] for lv in self.levels])
        p = float(np.prod(ps))
        var = sum((1 - lv["conditional_p"]) / (lv["conditional_p"] * self.n) * (1 + lv["gamma"])
                  for lv in self.levels if lv["conditional_p"] > 0)
        cv = math.sqrt(var) if p > 0 else math.nan
        s_log = math.sqrt(math.log1p(cv**2)) if p > 0 else math.nan
        self._result = {
            "method": "splitting", "estimate": p, "cv": cv, "std_error": p * cv if p > 0 else math.nan,
            "ci95": [p * math.exp(-Z95 * s_log), p * math.exp(Z95 * s_log)] if p > 0 else [0.0, math.nan],
            "rel_half_width": Z95 * cv if p > 0 else math.nan, "reached_failure": reached,
            "p0": self.p0, "burn": self.burn, "runs_per_level": self.n, "path": self.levels,
        }

    def result(self) -> dict[str, Any]:
        return self._result
