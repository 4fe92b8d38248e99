"""Gaussian mixtures with diagonal covariances in the standard-normal space of the inputs: density,
sampling, weighted EM and the choice of the number of components by BIC.

Used by ``splitting_is`` (the final stage's proposal).  Weighted EM maximises ``sum_i w_i log f(z_i)``
(the cross-entropy objective of importance-weighted samples: Kurtz & Song, Struct. Safety 42, 2013;
Geyer, Papaioannou & Straub, Struct. Safety 76, 2019).  Diagonal covariances keep ``2 d + 1`` parameters
per component, which a few dozen elite points can carry in 7 dimensions; a floor on the standard
deviations keeps a component on a discrete input's cell (all its points equal) finite.  BIC uses the
weights' effective sample size as the sample count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

LOG_2PI = math.log(2 * math.pi)


def log_std_normal(z: np.ndarray) -> np.ndarray:
    """``log phi(z)`` of the standard normal in ``d`` dimensions, rows of ``z``."""
    z = np.atleast_2d(z)
    return -0.5 * np.sum(z**2, axis=1) - 0.5 * z.shape[1] * LOG_2PI


@dataclass(frozen=True)
class Mixture:
    """``sum_k weights[k] N(means[k], diag(stds[k]^2))``."""

    weights: np.ndarray  # (K,)
    means: np.ndarray  # (K, d)
    stds: np.ndarray  # (K, d)

    @property
    def k(self) -> int:
        return len(self.weights)

    def log_terms(self, z: np.ndarray) -> np.ndarray:
        """``log(weights[k] N_k(z_i))``, shape (n, K)."""
        z = np.atleast_2d(z)
        u = (z[:, None, :] - self.means[None]) / self.stds[None]
        log_n = -0.5 * np.sum(u**2, axis=2) - np.sum(np.log(self.stds), axis=1)[None] - 0.5 * z.shape[1] * LOG_2PI
        with np.errstate(divide="ignore"):
            return log_n + np.log(self.weights)[None]

    def log_pdf(self, z: np.ndarray) -> np.ndarray:
        return logsumexp(self.log_terms(z), axis=1)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        labels = rng.choice(self.k, size=n, p=self.weights)
        return self.means[labels] + self.stds[labels] * rng.standard_normal((n, self.means.shape[1]))

    def with_floor(self, share_min: float, inflate: float, std_low: float = 0.0, std_max: float = 1.0) -> Mixture:
        """The sampling mixture: every component gets at least ``share_min / K`` of the draws, stds
        widened by ``inflate`` and kept within ``[std_low, std_max]`` (a larger fitted std is kept).  The
        likelihood ratios use the mixture actually sampled, so neither change biases an estimate."""
        w = np.maximum(self.weights, share_min / self.k)
        stds = np.minimum(np.maximum(self.stds * inflate, std_low), np.maximum(std_max, self.stds))
        return Mixture(w / w.sum(), self.means.copy(), stds)

    def to_json(self) -> list[dict[str, Any]]:
        return [{"weight": round(float(a), 4), "mean": m.round(3).tolist(), "std": s.round(3).tolist()}
                for a, m, s in zip(self.weights, self.means, self.stds, strict=True)]


def ess(w: np.ndarray) -> float:
    """Effective sample size ``(sum w)^2 / sum w^2`` of weights."""
    return float(w.sum() ** 2 / (w**2).sum()) if len(w) and w.sum() > 0 else 0.0


def _init(z: np.ndarray, w: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Weighted k-means++ centres."""
    p = w / w.sum()
    centres = [z[rng.choice(len(z), p=p)]]
    for _ in range(1, k):
        d2 = np.min(((z[:, None, :] - np.array(centres)[None]) ** 2).sum(axis=2), axis=1)
        q = p * d2
        if q.sum() <= 0:
            break
        centres.append(z[rng.choice(len(z), p=q / q.sum())])
    return np.array(centres)


def fit_em(z: np.ndarray, w: np.ndarray, k: int, rng: np.random.Generator, std_min: float,
           iters: int = 300, tol: float = 1e-9) -> tuple[Mixture, float]:
    """Weighted EM from a k-means++ start; returns the mixture and ``sum_i w~_i log f(z_i)`` (normalised
    weights ``w~``).  Components whose weight vanishes are dropped."""
    wn = w / w.sum()
    means = _init(z, wn, k, rng)
    spread = np.sqrt(np.maximum(wn @ (z - wn @ z) ** 2, std_min**2))
    mix = Mixture(np.full(len(means), 1 / len(means)), means, np.tile(spread, (len(means), 1)))
    prev = -math.inf
    for _ in range(iters):
        terms = mix.log_terms(z)
        ll_i = logsumexp(terms, axis=1)
        ll = float(wn @ ll_i)
        resp = np.exp(terms - ll_i[:, None]) * wn[:, None]  # (n, K) weighted responsibilities
        mass = resp.sum(axis=0)
        keep = mass > 1e-9
        resp, mass = resp[:, keep], mass[keep]
        means = (resp.T @ z) / mass[:, None]
        var = np.stack([resp[:, j] @ (z - means[j]) ** 2 for j in range(len(mass))]) / mass[:, None]
        mix = Mixture(mass / mass.sum(), means, np.sqrt(np.maximum(var, std_min**2)))
        if ll - prev < tol * max(1.0, abs(ll)):
            break
        prev = ll
    return mix, float(wn @ mix.log_pdf(z))


def fit_bic(z: np.ndarray, w: np.ndarray, k_max: int, rng: np.random.Generator, std_min: float,
            starts: int = 3) -> tuple[Mixture, list[float]]:
    """The mixture with the smallest BIC over ``K = 1..k_max`` (``starts`` EM starts each), where the
    sample count is the effective sample size of the weights; returns it and the BIC per ``K``."""
    n_eff = ess(w)
    d = z.shape[1]
    best: tuple[float, Mixture] | None = None
    bics = []
    for k in range(1, max(1, min(k_max, len(z) // 2)) + 1):
        fits = [fit_em(z, w, k, rng, std_min) for _ in range(1 if k == 1 else starts)]
        mix, ll = max(fits, key=lambda f: f[1])
        bic = -2 * n_eff * ll + (mix.k * (2 * d + 1) - 1) * math.log(max(n_eff, 2.0))
        bics.append(round(bic, 3))
        if best is None or bic < best[0]:
            best = (bic, mix)
    assert best is not None
    return best[1], bics


def refit_weighted(mix: Mixture, z: np.ndarray, w: np.ndarray, std_min: float) -> Mixture:
    """One weighted EM step from ``mix``: each component's share, mean and spread refitted to the points
    it is responsible for, weighted by ``w`` (the cross-entropy update of a mixture with fixed ``K``)."""
    terms = mix.log_terms(z)
    resp = np.exp(terms - logsumexp(terms, axis=1)[:, None]) * (w / w.sum())[:, None]
    mass = resp.sum(axis=0)
    keep = mass > 1e-12
    resp, mass = resp[:, keep], mass[keep]
    means = (resp.T @ z) / mass[:, None]
    var = np.stack([resp[:, j] @ (z - means[j]) ** 2 for j in range(len(mass))]) / mass[:, None]
    return Mixture(mass / mass.sum(), means, np.sqrt(np.maximum(var, std_min**2)))
