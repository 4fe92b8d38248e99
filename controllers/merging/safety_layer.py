"""Safety layer for longitudinal commands: a Gipps/RSS safe-gap bound and an IDM fallback.

``safe_accel`` caps any commanded acceleration (from the merging trajectory, an MPC, a human model)
so that the ego can always stop behind its leader even if the leader brakes at its maximum from now
on.  The bound is the responsibility-sensitive-safety (RSS, Shalev-Shwartz et al. 2017) / Gipps
(1981) condition: the ego applies ``a`` during its reaction time ``τ`` and then brakes at ``b_ego``;
the leader brakes at ``b_lead`` at once; the ego's stopping point must stay ``s0`` behind the
leader's:

    v τ + ½ a τ² + (v + a τ)² / (2 b_ego)  <=  gap - s0 + v_lead² / (2 b_lead)

which, solved for ``v1 = v + a τ``, is Gipps' safe speed
``v1 <= -b τ/2 + sqrt(b² τ²/4 + b (2 (gap - s0 + v_lead²/(2 b_lead)) - v τ))``.

Comparing stopping points is sufficient only if the ego does not brake harder than the leader
(otherwise the closest approach happens before both stop), so the bound uses
``min(b_ego, b_lead)``.  Invariance: if the condition held at the previous decision, full braking
satisfies it now, so the bound is never below ``-b_ego`` for a state reached under the layer; when it
is (an unsafe initial state), the layer commands ``-b_ego``.  ``τ`` must be at least the period at
which the command is held.

Stale information: ``worst_case_leader`` advances the last received leader state with maximum
braking up to now — the leader cannot be further back nor stop sooner than that — so the bound stays
valid when every message is lost; ``idm_accel`` (Treiber's Intelligent Driver Model) is the
car-following command to use towards that worst-case leader.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class SafetyParams(BaseModel):
    """Parameters of the safe-gap bound."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    reaction_s: float = Field(0.3, gt=0.0)  # [s] τ: command hold time + actuation delay
    b_ego_mps2: float = Field(6.0, gt=0.0)  # [m/s²] braking the ego counts on
    b_lead_mps2: float = Field(8.0, gt=0.0)  # [m/s²] worst-case braking of the leader
    s0_m: float = Field(2.0, ge=0.0)  # [m] standstill gap kept at the end


class IdmParams(BaseModel):
    """Intelligent Driver Model (Treiber, Hennecke & Helbing 2000)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    v0_mps: float = Field(30.0, gt=0.0)  # [m/s] desired speed
    time_headway_s: float = Field(1.5, gt=0.0)  # [s] T
    s0_m: float = Field(2.0, ge=0.0)  # [m] jam distance
    a_mps2: float = Field(1.5, gt=0.0)  # [m/s²] maximum acceleration
    b_mps2: float = Field(2.0, gt=0.0)  # [m/s²] comfortable deceleration
    delta: float = Field(4.0, gt=0.0)  # acceleration exponent


def safe_speed(gap_m: float, v_ego: float, v_lead: float, p: SafetyParams) -> float:
    """Highest ego speed [m/s] allowed after the reaction time (Gipps' bound); < 0 means 'stop now'."""
    b = min(p.b_ego_mps2, p.b_lead_mps2)
    tau = p.reaction_s
    reach_m = gap_m - p.s0_m + v_lead**2 / (2.0 * p.b_lead_mps2)  # where the ego must be able to stop
    disc = b * b * tau * tau / 4.0 + b * (2.0 * reach_m - v_ego * tau)
    if disc < 0.0:
        return -math.inf
    return -b * tau / 2.0 + math.sqrt(disc)


def safe_accel(gap_m: float, v_ego: float, v_lead: float, a_cmd: float, params: SafetyParams) -> float:
    """``a_cmd`` capped so the ego can still stop behind a leader braking at its maximum [m/s²].

    ``gap_m`` is bumper to bumper; ``math.inf`` means no leader.  Never returns more than ``a_cmd``.
    """
    if math.isinf(gap_m):
        return a_cmd
    v1_max = safe_speed(gap_m, v_ego, v_lead, params)
    if v1_max < 0.0:
        return min(a_cmd, -params.b_ego_mps2)
    a_safe = (v1_max - v_ego) / params.reaction_s
    return min(a_cmd, max(a_safe, -params.b_ego_mps2))


def lane_leaders(lane: np.ndarray, lane_pos: np.ndarray) -> np.ndarray:
    """Per vehicle, the index of the next vehicle ahead on the same lane (-1: none on that lane)."""
    order = np.lexsort((lane_pos, lane))
    out = np.full(len(lane), -1, dtype=np.int64)
    same = lane[order[:-1]] == lane[order[1:]]
    out[order[:-1][same]] = order[1:][same]
    return out


def worst_case_leader(
    x_lead_m: float, v_lead_mps: float, age_s: float, b_lead_mps2: float
) -> tuple[float, float]:
    """Last known leader state (position [m], speed [m/s]) advanced ``age_s`` with maximum braking."""
    t_stop = v_lead_mps / b_lead_mps2
    t = min(max(age_s, 0.0), t_stop)
    return x_lead_m + v_lead_mps * t - 0.5 * b_lead_mps2 * t * t, v_lead_mps - b_lead_mps2 * t


def idm_accel(gap_m: float, v: float, v_lead: float, params: IdmParams) -> float:
    """IDM acceleration [m/s²] towards a leader ``gap_m`` ahead (``math.inf``: free road)."""
    p = params
    free = 1.0 - (v / p.v0_mps) ** p.delta
    if math.isinf(gap_m):
        return p.a_mps2 * free
    s_star = p.s0_m + max(
        0.0, v * p.time_headway_s + v * (v - v_lead) / (2.0 * math.sqrt(p.a_mps2 * p.b_mps2))
    )
    return p.a_mps2 * (free - (s_star / max(gap_m, 1e-3)) ** 2)
