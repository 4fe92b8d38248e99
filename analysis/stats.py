"""Monte Carlo statistics: exact binomial intervals and summary statistics with spread."""

from __future__ import annotations

import math

import numpy as np

from corridor.stats import clopper_pearson  # the kernel's summary needs it too

__all__ = ["clopper_pearson", "mean_ci", "jain_index"]


def mean_ci(x: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean and Student-t confidence interval of the mean (nan-aware)."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return (math.nan, math.nan, math.nan)
    m = float(x.mean())
    if len(x) < 2:
        return (m, math.nan, math.nan)
    from scipy import stats  # here, not at import: scipy.stats costs ~0.4 s, which a run's monitors
    #   (jain_index) would pay in every fresh worker process

    h = float(stats.t.ppf(0.5 + confidence / 2, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x)))
    return (m, m - h, m + h)


def jain_index(x: np.ndarray) -> float:
    """Jain's fairness index (Σx)² / (n Σx²), 1 = perfectly fair."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0 or not np.any(x):
        return math.nan
    return float(x.sum() ** 2 / (len(x) * np.square(x).sum()))
