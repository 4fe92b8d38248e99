"""ALINEA local ramp-metering feedback with a queue override.

ALINEA (Papageorgiou, Hadj-Salem & Blosseville 1991) is an integral controller on the mainline
occupancy just downstream of the merge:

    r(k) = r(k-1) + K_R (o_set - o_meas(k))            [veh/h], K_R ~ 70 veh/h per % occupancy

clipped to [r_min, r_max]. The stored r(k-1) is the rate actually applied (after clipping and the
override), which is the standard anti-windup for ALINEA. Queue override (Smaragdis &
Papageorgiou 2003 style): once the ramp queue passes ``override_frac x storage``, the rate is raised
to at least ``demand + (queue - target)/period`` so the queue is driven back to the target within
one period and never exceeds storage; without a demand estimate the meter opens fully.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AlineaConfig:
    """Parameters of one ALINEA meter."""

    gain_vph_per_pct: float = 70.0  # K_R [veh/h per % occupancy]
    setpoint_pct: float = 20.0  # o_set, near critical occupancy [%]
    rate_min_vph: float = 200.0  # [veh/h]
    rate_max_vph: float = 1800.0  # [veh/h]
    storage_veh: float = math.inf  # ramp queue storage [veh]
    override_frac: float = 0.8  # queue override starts at this share of storage [-]
    period_s: float = 60.0  # control period [s]

    def __post_init__(self) -> None:
        if self.rate_min_vph > self.rate_max_vph:
            raise ValueError("AlineaConfig: rate_min_vph must be <= rate_max_vph")
        if not 0.0 < self.override_frac <= 1.0:
            raise ValueError("AlineaConfig: override_frac must be in (0, 1]")


class Alinea:
    """One ALINEA meter: ``step(occupancy_pct, queue_veh, demand_vph) -> rate_vph``."""

    def __init__(self, cfg: AlineaConfig | None = None) -> None:
        self.cfg = cfg or AlineaConfig()
        self.period = self.cfg.period_s
        self.rate_vph = self.cfg.rate_max_vph
        self.override_active = False

    def reset(self, rng: np.random.Generator | None = None, rate_vph: float | None = None) -> None:
        """Start from an open meter (or the given rate); ALINEA is deterministic, rng is unused."""
        del rng
        self.rate_vph = self.cfg.rate_max_vph if rate_vph is None else float(rate_vph)
        self.override_active = False

    def feedback_rate(self, occupancy_pct: float) -> float:
        """The pure ALINEA law r(k-1) + K_R (o_set - o), clipped [veh/h]."""
        c = self.cfg
        r = self.rate_vph + c.gain_vph_per_pct * (c.setpoint_pct - occupancy_pct)
        return float(np.clip(r, c.rate_min_vph, c.rate_max_vph))

    def queue_rate(self, queue_veh: float, demand_vph: float | None) -> float | None:
        """Least rate that keeps the queue at its override target, or None below the target [veh/h]."""
        c = self.cfg
        target_veh = c.override_frac * c.storage_veh
        if not math.isfinite(target_veh) or queue_veh < target_veh:
            return None
        if demand_vph is None:
            return c.rate_max_vph
        return demand_vph + (queue_veh - target_veh) / (c.period_s / 3600.0)

    def step(self, occupancy_pct: float, queue_veh: float = 0.0, demand_vph: float | None = None) -> float:
        """New metering rate [veh/h] from the downstream occupancy [%] and ramp queue [veh]."""
        c = self.cfg
        r = self.feedback_rate(occupancy_pct)
        r_q = self.queue_rate(queue_veh, demand_vph)
        self.override_active = r_q is not None and r_q > r
        if r_q is not None:
            r = max(r, r_q)
        self.rate_vph = float(np.clip(r, c.rate_min_vph, c.rate_max_vph))
        return self.rate_vph


def occupancy_from_density(rho_veh_km_lane: float | np.ndarray, eff_length_m: float = 7.0) -> float | np.ndarray:
    """Loop occupancy [%] from density: o = rho l_eff / 10 (l_eff = vehicle + detector length [m])."""
    return rho_veh_km_lane * eff_length_m / 10.0
