"""Wave-dampening speed law of a connected vehicle, and gap creation ahead of a merging vehicle (pure).

``follower_stopper`` is the FollowerStopper of Stern et al. (2018), *Dissipation of stop-and-go waves
via control of autonomous vehicles: field experiments*, Transp. Res. C 89: the vehicle drives at a
reference speed ``U`` when the gap to its leader is large, at the leader's speed (no faster than U)
inside a band of gaps, and slows towards standstill below it; the band widens with the square of the
closing speed:

    dx_j = dx0_j + (1 / (2 d_j)) * min(v_lead - v, 0)^2,  j = 1, 2, 3
    v_cmd = 0                                           if gap <= dx_1
          = v_ (gap - dx_1) / (dx_2 - dx_1)             if dx_1 < gap <= dx_2
          = v_ + (U - v_) (gap - dx_2) / (dx_3 - dx_2)  if dx_2 < gap <= dx_3
          = U                                           if gap > dx_3,       v_ = min(max(v_lead, 0), U)

Jam absorption (Nishi et al. 2013, *Theory of jam-absorption driving*, Transp. Res. B 50): the
reference ``U`` is not the vehicle's desired speed but the speed of the traffic ahead as the roadside
unit measures it and broadcasts it over V2X (``downstream_speed``): the connected vehicle slows early
and gently to the speed of the wave it is about to meet, and the gap it opens absorbs the wave instead
of passing it on.

``gap_speed_cap`` creates a gap ahead of a merging vehicle: a connected highway vehicle that would
reach the merge within ``headway_s`` of a ramp vehicle's announced arrival (and behind it) slows so as
to arrive ``headway_s`` after it.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class StopperParams(BaseModel):
    """FollowerStopper bands (Stern et al. 2018's values)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    dx0_m: tuple[float, float, float] = (4.5, 5.25, 6.0)  # [m]
    d_mps2: tuple[float, float, float] = (1.5, 1.0, 0.5)  # [m/s²]
    time_gap_s: float = Field(0.5, ge=0)  # [s] added to every band x own speed (highway speeds)


def follower_stopper(gap_m: float, v_mps: float, v_lead_mps: float, u_mps: float, p: StopperParams) -> float:
    """The FollowerStopper's commanded speed [m/s]."""
    closing = min(v_lead_mps - v_mps, 0.0)
    dx = [x0 + closing * closing / (2.0 * d) + p.time_gap_s * v_mps for x0, d in zip(p.dx0_m, p.d_mps2)]
    v_ = min(max(v_lead_mps, 0.0), u_mps)
    if gap_m <= dx[0]:
        return 0.0
    if gap_m <= dx[1]:
        return v_ * (gap_m - dx[0]) / (dx[1] - dx[0])
    if gap_m <= dx[2]:
        return v_ + (u_mps - v_) * (gap_m - dx[1]) / (dx[2] - dx[1])
    return u_mps


def downstream_speed(x_m: float, cell_x_m: np.ndarray, cell_speed_mps: np.ndarray, horizon_m: float,
                     default_mps: float) -> float:
    """Mean broadcast speed of the cells whose centre lies in (x, x + horizon] ([m/s]; nan cells are
    skipped; ``default_mps`` when none ahead is known)."""
    ahead = (cell_x_m > x_m) & (cell_x_m <= x_m + horizon_m) & np.isfinite(cell_speed_mps)
    return float(cell_speed_mps[ahead].mean()) if ahead.any() else default_mps


def gap_speed_cap(dist_m: float, v_mps: float, t_s: float, ramp_eta_s: np.ndarray, headway_s: float,
                  v_min_mps: float) -> float:
    """Highest speed [m/s] that lets the ramp vehicles announced to arrive at ``ramp_eta_s`` merge
    ``headway_s`` ahead of this vehicle (``dist_m`` from the merge); inf when none is in conflict."""
    if dist_m <= 0 or not len(ramp_eta_s):
        return math.inf
    eta = t_s + dist_m / max(v_mps, 0.1)
    conflict = ramp_eta_s[(ramp_eta_s > eta - headway_s) & (ramp_eta_s < eta + 0.5 * headway_s)]
    if not len(conflict):
        return math.inf
    arrive = float(conflict.max()) + headway_s  # [s] a headway behind the last conflicting ramp vehicle
    return max(v_min_mps, dist_m / max(arrive - t_s, 1e-3))
