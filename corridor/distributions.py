"""Densities of the ``randomize`` distributions and their map from the standard normal.

Rare-event estimators (``--estimate``, ``--falsify``) work in the *standard-normal space* of the
inputs: every randomized field is ``x = F^-1(Phi(z))`` with ``z ~ N(0, 1)`` under the nominal
scenario, so a proposal over ``z`` (a shifted Gaussian, an MCMC move) is a proposal over the inputs,
and its likelihood ratio against the nominal is the same in both spaces (the Jacobian cancels).
Discrete kinds (``integers``, ``choice``) map by their inverse CDF too; their ratio is still exact,
because the event depends on ``z`` only through ``x``.

``logpdf`` gives the nominal density of a value (a probability mass for the discrete kinds), backed
by ``scipy.stats``.  The nominal sampler stays ``Distribution.draw`` (a run's numbers are unchanged).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import special

from corridor.scenario import Distribution


def frozen(d: Distribution) -> Any:
    """The scipy.stats distribution of a continuous kind (``Distribution.frozen``)."""
    return d.frozen()


def _ppf(dist: Any, z: float) -> float:
    """``F^-1(Phi(z))`` accurate in both tails (the upper tail through the survival function)."""
    return float(dist.ppf(special.ndtr(z))) if z <= 0 else float(dist.isf(special.ndtr(-z)))


def from_normal(d: Distribution, z: float) -> Any:
    """The value of ``d`` at standard-normal coordinate ``z`` (``z ~ N(0, 1)`` gives ``d``'s law)."""
    z = float(z)
    if d.normal is not None:
        return float(d.normal[0] + d.normal[1] * z)
    if d.uniform is not None:
        lo, hi = d.uniform
        return float(lo + (hi - lo) * special.ndtr(z))
    if d.integers is not None:
        n = d.integers[1] - d.integers[0] + 1
        return int(d.integers[0] + min(n - 1, int(math.floor(special.ndtr(z) * n))))
    if d.choice is not None:
        n = len(d.choice)
        return d.choice[min(n - 1, int(math.floor(special.ndtr(z) * n)))]
    return _ppf(frozen(d), z)


def to_normal(d: Distribution, x: Any) -> float:
    """The standard-normal coordinate of value ``x`` (the middle of its cell for discrete kinds)."""
    if d.normal is not None:
        return (float(x) - d.normal[0]) / d.normal[1] if d.normal[1] > 0 else 0.0
    if d.integers is not None:
        return float(special.ndtri((int(x) - d.integers[0] + 0.5) / (d.integers[1] - d.integers[0] + 1)))
    if d.choice is not None:
        return float(special.ndtri((d.choice.index(x) + 0.5) / len(d.choice)))
    dist = frozen(d)
    u = float(dist.cdf(x))
    return float(special.ndtri(u)) if u <= 0.5 else -float(special.ndtri(float(dist.sf(x))))


def logpdf(d: Distribution, x: Any) -> float:
    """Log density (log probability for the discrete kinds) of ``x`` under the nominal ``d``."""
    if d.integers is not None:
        lo, hi = d.integers
        return -math.log(hi - lo + 1) if float(x) == int(x) and lo <= int(x) <= hi else -math.inf
    if d.choice is not None:
        hits = sum(1 for c in d.choice if c == x)
        return math.log(hits / len(d.choice)) if hits else -math.inf
    if d.normal is not None and d.normal[1] == 0:
        return math.inf if float(x) == d.normal[0] else -math.inf
    if d.uniform is not None and d.uniform[0] == d.uniform[1]:
        return math.inf if float(x) == d.uniform[0] else -math.inf
    return float(frozen(d).logpdf(x))


def draws_from_normal(randomize: dict[str, Distribution], z: np.ndarray) -> dict[str, Any]:
    """The draws of one run at standard-normal point ``z`` (one coordinate per field, paths sorted)."""
    return {path: from_normal(d, zi) for (path, d), zi in zip(sorted(randomize.items()), z, strict=True)}


def log_ratio_normal(z: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """``log phi(z) - log q(z)`` for a diagonal Gaussian proposal ``q = N(mean, std^2)``, rows of ``z``."""
    z = np.atleast_2d(z)
    log_ratio: np.ndarray = (-0.5 * np.sum(z**2, axis=1)
                             + 0.5 * np.sum(((z - mean) / std) ** 2, axis=1) + np.sum(np.log(std)))
    return log_ratio
