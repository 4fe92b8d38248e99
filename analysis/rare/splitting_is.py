"""Subset simulation to reach every failure mode, then importance sampling with a Gaussian mixture
fitted to its failures (``--method splitting_is``): for failure sets with several modes.

Why not the single-Gaussian cross-entropy method (``ce.py``): its refit averages the elite, so it
follows the mode that holds most of the elite and drops the others.  A mode that is *narrow but deep*
(little probability at the intermediate levels, most of it at the failure level) holds 2-4 % of an
elite, one or two points of 30-60; no mixture fitted to such an elite (weighted EM, components chosen
by BIC) gives it a component (uav_encounter's plain rows: 2 of 33 stage-0 elites did), and an
importance sampler that resamples the elite by weight loses it within a stage or two.

1. *Exploration*: subset simulation (``splitting.py``, Au & Beck 2001) with ``p0 = 0.2`` and
   ``budget / 8`` runs per level, at most 75 % of the budget; each seed starts a Markov chain that stays
   in its region (a rejected move keeps the state).  Selection by level alone loses a narrow-but-deep
   mode (a small minority, not lower than the rest at the intermediate levels), so the seeds are chosen
   with a quota per cluster (``quota.py``, ``seed_quota=True``): the ``4 p0 n`` lowest states are cut
   into at most 6 single-linkage clusters in ``z`` and each cluster gets its lowest states first; a
   quota seed above the level's threshold keeps its own score as its chain's threshold.  README,
   two-mode check: mode x lost in 1-5 of 100 seeds against 16-18 by level alone.  The exploration's
   own ``estimate`` is then not a subset-simulation estimate (``exploration.estimate_diagnostic``); it
   stops when a level holds ``p0 n`` failures.
2. *Fit*: the distinct failing points of every level are (approximately) draws of the nominal law given
   failure, the optimal importance density; a Gaussian mixture with diagonal covariances is fitted to
   them by EM, the number of components chosen by BIC (``mixture.py``; Geyer, Papaioannou & Straub,
   Struct. Safety 76, 2019; the idea of sampling from a density built on MCMC failure samples: Au & Beck,
   Struct. Safety 21, 1999).  Sampling shares: each component's share of the points, at least
   ``share_min / K``; standard deviations widened ``inflate`` times, within ``[std_low, 1]`` (a chain's
   failures are correlated, so a fitted spread is often too narrow).
3. *Estimate*: the rest of the budget draws from ``alpha phi + (1 - alpha) g`` (weights ``<= 1 / alpha``)
   in two parts (``refit_share``, then the rest); between them the components' shares, means and spreads
   get a cross-entropy update on the first part's weighted failures.  ``p = sum(w 1{fail}) / N`` with
   ``w = phi / q`` of each part's own proposal, over both parts only: unbiased, whatever the fit.
4. *Missed-mode check*: a failure of the final stage where ``alpha phi > (1 - alpha) g`` (drawn by the
   defensive part, outside every component) is a failure mode the mixture misses; it is counted and a
   warning written: the estimate stays unbiased, but its interval is then not to be trusted.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from corridor.analysis.rare.ce import Z95, missed_mode_warning, scores, stage_rng
from corridor.analysis.rare.mixture import Mixture, ess, fit_bic, log_std_normal, refit_weighted
from corridor.analysis.rare.quota import quota_seeds
from corridor.analysis.rare.splitting import SubsetSimulation


class SplittingImportance:
    TAG = 0x515
    # an exploration (75 %) of 50 nominal runs and two levels of chains (50 runs each), then the
    # importance-sampling stage in two parts (refit, final)
    MIN_BUDGET = 200
    MIN_BUDGET_WHY = "an exploration of 150 runs (50 nominal, two levels of chains) and 50 importance-sampling runs"

    def __init__(self, dim: int, budget: int, seed: int, p0: float = 0.2, alpha: float = 0.1,
                 explore_share: float = 0.75, level_share: float = 0.125, k_max: int = 6, share_min: float = 0.5, inflate: float = 1.5,
                 std_min: float = 0.1, std_low: float = 0.5, refit_share: float = 0.3, seed_quota: bool = True) -> None:
        self.dim, self.budget, self.seed, self.alpha = dim, budget, seed, alpha
        self.k_max, self.share_min, self.inflate, self.std_min = k_max, share_min, inflate, std_min
        self.refit_share, self.std_low = refit_share, std_low
        self.parts: list[tuple[Mixture, np.ndarray, np.ndarray]] = []  # final stage: (proposal, z, fail)
        per = int(round(1 / p0))
        n = max(10 * per, int(level_share * budget) // per * per)
        self.seed_quota = seed_quota
        self.sus = SubsetSimulation(dim, int(explore_share * budget), seed, p0=p0, n_level=n,
                                    select=quota_seeds if seed_quota else None)
        self.proposal: Mixture | None = None
        self.stage, self.used, self.done = 0, 0, False
        self.seen: list[tuple[np.ndarray, np.ndarray]] = []  # (z, score) of every exploration run
        self.fit_info: dict[str, Any] = {}
        self._z: np.ndarray | None = None
        self._result: dict[str, Any] = {}

    def ask(self) -> np.ndarray | None:
        if self.done:
            return None
        if self.proposal is None:
            self._z = self.sus.ask()
            return self._z
        rng = stage_rng(self.seed, self.stage, self.TAG)
        rest = self.budget - self.used
        n = rest if self.parts else max(1, min(rest, int(round(self.refit_share * rest))))
        z = self.proposal.sample(rng, n)
        nominal = rng.random(n) < self.alpha
        z[nominal] = rng.standard_normal((int(nominal.sum()), self.dim))
        self._z = z
        return z

    def tell(self, level: np.ndarray, fail: np.ndarray) -> None:
        z, self._z = self._z, None
        assert z is not None, "tell() without ask()"
        fail = np.asarray(fail, bool)
        self.used += len(z)
        self.stage += 1
        if self.proposal is not None:
            self.parts.append((self.proposal, z, fail))
            if self.used >= self.budget:
                self._finish()
            elif fail.any():  # the cross-entropy update of the components on this part's weighted failures
                w = np.exp(self._log_w(self.proposal, z[fail]))
                mix = refit_weighted(self.proposal, z[fail], w, self.std_min)
                self.proposal = mix.with_floor(self.share_min, self.inflate, self.std_low)
            return
        self.seen.append((z, scores(np.asarray(level, float), fail)))
        self.sus.tell(level, fail)
        if self.sus.done:
            self.proposal = self._fit()

    def _log_w(self, prop: Mixture, z: np.ndarray) -> np.ndarray:
        """``log phi - log q`` for the defensive mixture ``q = alpha phi + (1 - alpha) g``."""
        lphi = log_std_normal(z)
        return lphi - np.logaddexp(math.log(self.alpha) + lphi, math.log1p(-self.alpha) + prop.log_pdf(z))

    def _fit(self) -> Mixture:
        """EM + BIC on the distinct failing points of the exploration (its lowest points if too few)."""
        z = np.concatenate([s[0] for s in self.seen])
        s = np.concatenate([s[1] for s in self.seen])
        pts = np.unique(z[np.isneginf(s)], axis=0)
        if len(pts) < 2 * self.dim:  # not reached: towards failure, still an unbiased proposal
            pts = np.unique(z[np.argsort(s, kind="stable")[: self.sus.n_seeds]], axis=0)
        rng = stage_rng(self.seed, self.stage, self.TAG + 1)
        mix, bics = fit_bic(pts, np.ones(len(pts)), self.k_max, rng, self.std_min)
        self.fit_info = {"fit_points": len(pts), "fit_on_failures": bool(np.isneginf(s).sum() >= 2 * self.dim),
                         "bic": bics, "fit": mix.to_json()}
        return mix.with_floor(self.share_min, self.inflate, self.std_low)

    def _finish(self) -> None:
        """Both parts of the final stage: each ``w 1{fail}`` is unbiased, so is their pooled mean; its
        variance adds the parts' (each part's sample variance, weighted by its size)."""
        x_parts, w_all, f_all = [], [], []
        for prop, z, fail in self.parts:
            w = np.exp(self._log_w(prop, z))
            x_parts.append(w * fail)
            w_all.append(w)
            f_all.append(fail)
        n = sum(len(x) for x in x_parts)
        x, w, fail = np.concatenate(x_parts), np.concatenate(w_all), np.concatenate(f_all)
        p = float(x.sum() / n)
        var = sum(len(xp) * xp.var(ddof=1) for xp in x_parts if len(xp) > 1) / n**2
        se = math.sqrt(var) if n > 1 else math.nan
        wf = w[fail]
        prop, z_last, f_last = self.parts[-1]
        terms = prop.log_terms(z_last)
        owner = np.argmax(terms, axis=1)
        x_last = x_parts[-1]
        modes = [{"component": k, "share": round(float(prop.weights[k]), 4),
                  "failures": int((f_last & (owner == k)).sum()),
                  "estimate": float(x_last[owner == k].sum() / len(x_last)), "mean": prop.means[k].round(3).tolist(),
                  "std": prop.stds[k].round(3).tolist()} for k in range(prop.k)]
        sus = self.sus.result()
        self.done = True
        self._result = {
            "method": "splitting_is", "estimate": p, "std_error": se,
            "ci95": [max(0.0, p - Z95 * se), p + Z95 * se] if p > 0 else [0.0, math.nan],
            "rel_half_width": Z95 * se / p if p > 0 else math.nan,
            "final_runs": n, "final_failures": int(fail.sum()), "converged": bool(sus.get("reached_failure")),
            "ess": ess(w), "ess_failures": ess(wf), "weight_max": float(w.max()),
            "weight_cv": float(w.std() / w.mean()),
            "max_weight_share_failures": float(wf.max() / wf.sum()) if len(wf) else math.nan,
            "components": prop.k, "modes": modes, **missed_mode_warning(w, fail, self.alpha),
            "defensive_alpha": self.alpha, **self.fit_info,
            "exploration": {**sus, "runs": self.sus.used, "seed_quota": self.seed_quota,
                            "estimate_diagnostic": self.seed_quota},  # quota seeds: not a SuS estimate
            "path": [*sus.get("path", []), *({"kind": "final", "runs": len(z), "failures": int(f.sum()),
                                              "components": pr.k} for pr, z, f in self.parts)],
        }

    def result(self) -> dict[str, Any]:
        return self._result

