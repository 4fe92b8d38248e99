"""Seed selection with a quota per cluster, for the exploration of ``splitting_is``.

Subset simulation keeps the ``p0 n`` lowest states of a level as the next level's seeds.  A failure
mode that is narrow but deep is a small minority at the intermediate levels and not lower there than
the rest, so selection by level alone culls its chains before the levels where it dominates.  Here
the candidates are the ``4 p0 n`` lowest states; they are clustered by single linkage on their
distance in ``z`` (cut into at most ``k_max`` clusters at the largest gaps of the minimum spanning
tree), every cluster gets its ``quota`` lowest states as seeds (all of them if fewer), and the rest
of the ``p0 n`` seeds are the lowest remaining candidates.

A quota seed above the level's threshold keeps its own score as its chain's threshold
(``SubsetSimulation``), so its chain moves within its region at no higher level.  Why ``4 p0 n``
candidates (80 % of a level at ``p0 = 0.2``): such a chain's states stay near its seed's score, above
the next threshold, and a region is kept only while one of its states is a candidate; on the README's
two-mode check (seeds 0-99) ``2 p0 n`` lost the deep mode in 8 of 100 estimates, ``3 p0 n`` in 5,
``4 p0 n`` in 1 (seeds 100-199, not used to choose it: 5, against 18 without the quota).

Why single linkage: it separates groups by the gaps between them, whatever their sizes, and a small
group is exactly what has to be kept; k-means and EM/BIC split by mass, so they merge a group of a
few points into a large neighbour (the README: EM/BIC gave the early mode of uav_encounter a component
in 2 of 33 elites).  Outliers of one point may take a cluster each; over-splitting costs only seeds
that the fill by score would otherwise place, never a region.

This changes which states are seeds, so the exploration's own product of conditional probabilities
is no longer a subset-simulation estimate (it is kept as a diagnostic); the importance-sampling
stage that gives ``splitting_is``'s estimate is unbiased whatever the seeds.
"""

from __future__ import annotations

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage


def quota_seeds(z: np.ndarray, s: np.ndarray, n_seeds: int, k_max: int = 6, quota: int | None = None,
                candidates: float = 4.0) -> np.ndarray:
    """Indices of ``n_seeds`` states of ``z`` (rows) with scores ``s``, lowest first within the
    selection: every single-linkage cluster of the ``candidates * n_seeds`` lowest gets its ``quota``
    lowest (default ``n_seeds // (2 k_max)``, at least 1), the rest by score."""
    order = np.argsort(s, kind="stable")
    cand = order[: min(len(order), int(round(candidates * n_seeds)))]
    if len(cand) <= n_seeds or len(np.unique(z[cand], axis=0)) < 2:
        return order[:n_seeds]
    labels = fcluster(linkage(z[cand], method="single"), t=k_max, criterion="maxclust")
    m = quota if quota is not None else max(1, n_seeds // (2 * k_max))
    chosen = np.zeros(len(cand), bool)
    for lab in np.unique(labels):
        chosen[np.flatnonzero(labels == lab)[:m]] = True  # cand is sorted by score
    extra = n_seeds - int(chosen.sum())
    if extra > 0:
        chosen[np.flatnonzero(~chosen)[:extra]] = True
    elif extra < 0:  # more quota seeds than n_seeds (k_max * quota > n_seeds): the lowest of them
        chosen[np.flatnonzero(chosen)[n_seeds:]] = False
    return cand[chosen]
