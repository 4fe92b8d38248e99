"""Cross-entropy adaptive importance sampling (Rubinstein & Kroese, *The Cross-Entropy Method*, 2004;
for rare events with a likelihood-ratio-weighted refit, de Boer et al., Ann. Oper. Res. 134, 2005).

Proposal family: independent Gaussians ``N(mean, std^2)`` in the standard-normal space of the inputs.
Adaptive stages draw ``n_stage`` runs each; the elite (the ``rho`` fraction with the lowest score,
failures first) refits the proposal by weighted moments, weights ``w = phi(z) / q(z)``, so the fit
estimates the nominal law conditioned on the elite region (the optimal proposal's shape).  Adaptation
stops when the elite are all failures or the adaptive share of the budget is spent.  The final stage
spends the rest of the budget on the defensive mixture ``alpha * phi + (1 - alpha) * q`` (weights
bounded by ``1 / alpha``) and alone gives the estimate, unbiased: ``p = mean(w * 1{fail})``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from corridor.distributions import log_ratio_normal

Z95 = 1.959963984540054


def missed_mode_warning(w: np.ndarray, fail: np.ndarray, alpha: float) -> dict[str, Any]:
    """Failures of a defensive final stage (``alpha phi + (1 - alpha) g``) outside every proposal
    component: ``alpha phi > (1 - alpha) g``, i.e. a weight above ``1 / (2 alpha)``.  Such a failure was
    (most likely) drawn by the nominal part: a failure mode the proposal missed.  The estimate stays
    unbiased, but its interval then rests on a handful of large weights and is not to be trusted."""
    out = fail & (w > 1 / (2 * alpha))
    count = int(out.sum())
    total = float((w * fail).sum())
    share = float((w * out).sum()) / total if total > 0 else math.nan
    text = None
    if count:
        text = (f"{count} failure(s) of the final stage lie outside every proposal component (drawn by the "
                f"defensive nominal part; {share:.0%} of the estimate): a failure mode the proposal missed; the "
                "estimate is unbiased but its interval is not to be trusted; re-run with a larger budget or "
                "another method (splitting_is)")
    return {"uncovered_failures": count, "uncovered_share": share, "missed_mode_warning": text}


def stage_rng(seed: int, stage: int, tag: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(tag, stage)))


def scores(level: np.ndarray, fail: np.ndarray) -> np.ndarray:
    """The adaptive methods' ordering: failures first (-inf), then by level (NaN last)."""
    s = np.where(np.isnan(level), np.inf, level)
    return np.where(fail, -np.inf, s)


class CrossEntropy:
    TAG = 0xCE
    MIN_BUDGET = 100  # one adaptive stage (50 runs) and a final stage of at least as many
    MIN_BUDGET_WHY = "an adaptive stage of 50 runs and a final stage of 50"

    def __init__(self, dim: int, budget: int, seed: int, rho: float = 0.1, alpha: float = 0.05,
                 adaptive_share: float = 0.6, inflate: float = 1.5) -> None:
        self.dim, self.budget, self.seed, self.rho, self.alpha = dim, budget, seed, rho, alpha
        self.inflate = inflate
        self.n_stage = max(50, budget // 10)
        self.adaptive_budget = int(adaptive_share * budget)
        self.mean, self.std = np.zeros(dim), np.ones(dim)
        self.stage, self.used, self.final, self.done = 0, 0, False, False
        self.path: list[dict[str, Any]] = []
        self._z: np.ndarray | None = None
        self._result: dict[str, Any] = {}

    def ask(self) -> np.ndarray | None:
        if self.done:
            return None
        rng = stage_rng(self.seed, self.stage, self.TAG)
        if self.final:
            n = self.budget - self.used
            z = self.mean + self.std * rng.standard_normal((n, self.dim))
            nominal = rng.random(n) < self.alpha
            z[nominal] = rng.standard_normal((int(nominal.sum()), self.dim))
        else:
            z = self.mean + self.std * rng.standard_normal((self.n_stage, self.dim))
        self._z = z
        return z

    def log_w(self, z: np.ndarray) -> np.ndarray:
        """log of phi(z) / q(z) for the current proposal (the mixture in the final stage)."""
        lr = log_ratio_normal(z, self.mean, self.std)  # log phi - log q_ce
        if not self.final:
            return lr
        return -np.logaddexp(math.log(self.alpha), math.log1p(-self.alpha) - lr)

    def tell(self, level: np.ndarray, fail: np.ndarray) -> None:
        z, self._z = self._z, None
        assert z is not None, "tell() without ask()"
        level, fail = np.asarray(level, float), np.asarray(fail, bool)
        self.used += len(z)
        log_w = self.log_w(z)
        info = {"stage": self.stage, "runs": len(z), "failures": int(fail.sum()),
                "mean": self.mean.round(4).tolist(), "std": self.std.round(4).tolist()}
        self.stage += 1
        if self.final:
            self.path.append({**info, "kind": "final"})
            self._finish(np.exp(log_w), fail)
            return
        s = scores(level, fail)
        n_elite = max(2, int(math.ceil(self.rho * len(z))))
        order = np.argsort(s, kind="stable")
        threshold = float(s[order[n_elite - 1]])
        self.path.append({**info, "kind": "adaptive", "elite_level": threshold if math.isfinite(threshold) else None})
        converged = fail.sum() >= n_elite
        if converged:  # the failures themselves, weighted: the nominal law conditioned on failure
            w = np.exp(log_w[fail] - log_w[fail].max())
            w /= w.sum()
            self.mean = w @ z[fail]
            std = np.sqrt(np.maximum(w @ (z[fail] - self.mean) ** 2, 0.0))
            self.std = np.clip(self.inflate * std, 0.1, 1.0)
        else:  # shift the mean to the elite's (unweighted: fast progress; the std stays 1)
            self.mean = z[order[:n_elite]].mean(axis=0)
        if converged or self.used + self.n_stage > self.adaptive_budget:
            self.final, self.converged = True, bool(converged)

    def _finish(self, w: np.ndarray, fail: np.ndarray) -> None:
        n = len(w)
        x = w * fail
        p = float(x.mean())
        se = float(x.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
        wf = w[fail]
        self.done = True
        self._result = {
            "method": "ce", "estimate": p, "std_error": se,
            "ci95": [max(0.0, p - Z95 * se), p + Z95 * se] if p > 0 else [0.0, math.nan],
            "rel_half_width": Z95 * se / p if p > 0 else math.nan,
            "final_runs": n, "final_failures": int(fail.sum()), "converged": getattr(self, "converged", False),
            "ess": float(w.sum() ** 2 / (w**2).sum()),
            "ess_failures": float(wf.sum() ** 2 / (wf**2).sum()) if len(wf) else 0.0,
            "weight_max": float(w.max()), "weight_cv": float(w.std() / w.mean()),
            "max_weight_share_failures": float(wf.max() / wf.sum()) if len(wf) else math.nan,
            "proposal_mean": self.mean.tolist(), "proposal_std": self.std.tolist(),
            "defensive_alpha": self.alpha, **missed_mode_warning(w, fail, self.alpha), "path": self.path,
        }

    def result(self) -> dict[str, Any]:
        return self._result
