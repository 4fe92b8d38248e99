"""Falsification: minimise the level (a spec's robustness) over the randomized inputs with CMA-ES.

Why CMA-ES (Hansen's ``cma`` package, pure Python over numpy): robustness of a simulated run is a
black box, noisy (SUMO's and the components' own randomness) and often flat in some inputs and
discontinuous in others (a discrete encounter geometry).  CMA-ES is invariant to monotone transforms
of the objective (it uses ranks only, so a robustness in metres or seconds needs no scaling), adapts
its step sizes and correlations, asks for a whole population at once (one stage of parallel runs) and
needs no gradient: the falsification tools of the field use it for the same reasons (Breach's
default global solver; S-TaLiRo and VerifAI offer it).  It runs in the standard-normal space of the
inputs, where every distribution is a Gaussian: the search starts at the nominal median with step 1
(one nominal standard deviation), unbounded, and bounded or discrete inputs are reached through
their inverse CDF.  Without the package, scipy's differential evolution would be the fallback, but it
cannot be driven stage by stage (ask/tell), so corridor asks for ``cma`` (a dependency).

The search stops after the first generation with a violation (robustness < 0) or when the budget of
runs is spent; the lowest robustness reached is reported either way.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from corridor.analysis.rare.ce import stage_rng

Z_MAX = 8.0  # [standard deviations] the search box in the standard-normal space


class Falsifier:
    TAG = 0xFA
    KIND = "search"  # not an estimator of P(EVENT): ``--falsify``, never ``--method``

    def __init__(self, dim: int, budget: int, seed: int, sigma0: float = 1.0) -> None:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # cma warns when matplotlib is missing (plots only)
            import cma
        self.budget, self.seed = budget, seed
        self.used = self.stage = 0
        self._rng = stage_rng(seed, 0, self.TAG)
        self.es = cma.CMAEvolutionStrategy(np.zeros(dim), sigma0, {
            "seed": seed % (2**31 - 1) + 1, "verbose": -9, "randn": lambda *shape: self._rng.standard_normal(shape),
            "popsize": max(6, 4 + int(3 * math.log(dim)))})
        self.best_level, self.best_z = math.inf, np.zeros(dim)
        self.path: list[dict[str, Any]] = []
        self.found = False
        self._z: np.ndarray | None = None

    def ask(self) -> np.ndarray | None:
        if self.found or self.used >= self.budget:
            return None
        n = min(self.es.popsize, self.budget - self.used)
        self._rng = stage_rng(self.seed, self.stage, self.TAG)
        self._asked = np.array(self.es.ask())
        self._z = self._asked[:n]
        return np.clip(self._z, -Z_MAX, Z_MAX)  # within 8 sigma of the nominal: probabilities ~1e-15

    def tell(self, level: np.ndarray, fail: np.ndarray) -> None:
        z, self._z = self._z, None
        assert z is not None, "tell() without ask()"
        level = np.where(np.isnan(level), np.inf, np.asarray(level, float))
        self.used += len(z)
        self.stage += 1
        i = int(np.argmin(level))
        if level[i] < self.best_level:
            self.best_level, self.best_z = float(level[i]), np.clip(z[i], -Z_MAX, Z_MAX)
        self.found = bool(np.any(np.asarray(fail, bool)))
        self.path.append({"stage": self.stage - 1, "runs": len(z), "min_level": float(level[i]),
                          "best_level": self.best_level, "sigma": float(self.es.sigma)})
        if len(z) == self.es.popsize:  # a cut-off last generation is not told (CMA needs a whole one)
            self.es.tell(list(self._asked), [float(v) if math.isfinite(v) else 1e300 for v in level])

    def result(self) -> dict[str, Any]:
        return {"method": "cma-es", "found": self.found, "lowest_level": self.best_level,
                "best_z": self.best_z.tolist(), "runs": self.used, "path": self.path}
