"""Statistics the kernel's batch summary needs (``corridor.analysis.stats`` re-exports them)."""

from __future__ import annotations

import math


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper–Pearson) confidence interval for a binomial proportion k/n."""
    if n <= 0:
        return (math.nan, math.nan)
    from scipy import stats  # here, not at import: scipy.stats costs ~0.4 s, and a run never needs it

    alpha = 1.0 - confidence
    lo = 0.0 if k == 0 else float(stats.beta.ppf(alpha / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - alpha / 2, k + 1, n - k))
    return lo, hi
