"""Fidelity as a mode of each aircraft: when a point-mass quadcopter is promoted to JSBSim 6-DOF and
when it is demoted again.

Distances are measured in a cylinder-like metric, as separation is: the vertical axis is stretched
by ``promote_radius_m / promote_vertical_m``, so two aircraft are within the promotion boundary when
sqrt(dh^2 + (dv * radius / vertical)^2) < ``promote_radius_m`` (an ellipsoid of half-height
``promote_vertical_m``; quadcopters in cruise layers farther apart vertically stay point masses). An
aircraft is *close* to another when they are within it, or when, flying on at their current
velocities, their closest approach within ``promote_ttca_s`` is. Both members of a close pair fly 6-DOF (a
piloted aircraft always does). A 6-DOF quadcopter is demoted once no other aircraft is within
``demote_radius_m`` (> the promotion radius: hysteresis; the same vertical stretch) nor predicted
inside it within
``promote_ttca_s``, and it has flown 6-DOF for at least ``min_dwell_s``. Pairs are found with a k-d
tree (``scipy.spatial.cKDTree``), so the test costs O(N log N), not O(N^2).

``promote_on: converging`` counts only the pairs that close on each other: a pair is close when its
range shrinks faster than ``closing_min_mps`` and its closest approach within ``promote_ttca_s`` is
inside the boundary (the promotion radius to promote, the demotion radius to stay 6-DOF). Two
aircraft flying side by side, or apart after their closest approach, stay (or go back to) point
masses; the approach to every closest approach inside the boundary is flown 6-DOF.

``promote_on: encounter`` starts a pair as ``converging`` does (closing, closest approach inside the
promotion boundary) and keeps it, closing or not, until it is beyond the demotion boundary (neither
within it nor predicted inside it within ``promote_ttca_s``): the whole encounter is flown 6-DOF, the
avoidance manoeuvre around the closest approach and the parting included, while pairs that never
closed on each other (side by side) stay point masses. The policy remembers the pairs of the running
encounters between checks (aircraft rows are fixed for a run).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial import cKDTree


class FidelityParams(BaseModel):
    """The fidelity boundaries (a scenario's ``backends.<air>.params.fidelity``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # point_mass: quadcopters stay point masses; jsbsim: every aircraft 6-DOF; multi: switch by proximity
    mode: Literal["point_mass", "jsbsim", "multi"] = "multi"
    promote_radius_m: float = Field(80.0, gt=0.0)  # [m] horizontal
    promote_vertical_m: float = Field(20.0, gt=0.0)  # [m] vertical half-height of the boundary
    promote_ttca_s: float = Field(5.0, ge=0.0)  # [s] look-ahead of the closest-approach test
    demote_radius_m: float = Field(120.0, gt=0.0)  # [m]
    min_dwell_s: float = Field(3.0, ge=0.0)  # [s] shortest 6-DOF spell
    # proximity: every pair inside the boundary (or predicted inside it); converging: closing pairs only;
    # encounter: a closing pair, kept until it is beyond the demotion boundary
    promote_on: Literal["proximity", "converging", "encounter"] = "proximity"
    closing_min_mps: float = Field(0.5, ge=0.0)  # [m/s] converging / encounter: the range shrinks faster than this
    uav_speed_bound_mps: float = Field(20.0, gt=0.0)  # [m/s] bounds the pair search radius of UAVs
    piloted_speed_bound_mps: float = Field(80.0, gt=0.0)  # [m/s] same for piloted aircraft

    @model_validator(mode="after")
    def _hysteresis(self) -> FidelityParams:
        if self.demote_radius_m < self.promote_radius_m:
            raise ValueError(f"demote_radius_m ({self.demote_radius_m}) must be >= promote_radius_m "
                             f"({self.promote_radius_m}): the hysteresis keeps aircraft from switching every step")
        return self


def closest_approach_pairs(pos: np.ndarray, vel: np.ndarray, piloted: np.ndarray, radius_m: float, ttca_s: float,
                           uav_speed_mps: float, piloted_speed_mps: float
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair (K, 2) that can come within ``radius_m`` within ``ttca_s``, its closest approach
    [m] over [0, ttca_s] when both fly straight on at their current velocities, and its closing speed
    [m/s] (minus the range rate: positive while the range shrinks)."""
    tree = cKDTree(pos)
    pairs = [tree.query_pairs(radius_m + 2.0 * uav_speed_mps * ttca_s, output_type="ndarray")]
    reach = radius_m + (uav_speed_mps + piloted_speed_mps) * ttca_s
    for k in np.flatnonzero(piloted):
        js = np.asarray(tree.query_ball_point(pos[k], reach), dtype=int)
        js = js[js != k]
        pairs.append(np.column_stack([np.full(len(js), k), js]))
    ij = np.concatenate(pairs).reshape(-1, 2).astype(int)
    i, j = ij[:, 0], ij[:, 1]
    dp, dv = pos[j] - pos[i], vel[j] - vel[i]
    vv = np.einsum("kd,kd->k", dv, dv)
    pv = np.einsum("kd,kd->k", dp, dv)
    tca = np.clip(-pv / np.maximum(vv, 1e-12), 0.0, ttca_s)
    closing = -pv / np.maximum(np.linalg.norm(dp, axis=1), 1e-9)
    return ij, np.linalg.norm(dp + dv * tca[:, None], axis=1), closing


def close_rows(n: int, ij: np.ndarray, miss: np.ndarray, radius_m: float) -> np.ndarray:
    """Boolean (n,): aircraft in a pair whose closest approach is below ``radius_m``."""
    out = np.zeros(n, dtype=bool)
    hit = miss < radius_m
    out[ij[hit, 0]] = True
    out[ij[hit, 1]] = True
    return out


class FidelityPolicy:
    """Decides the switches at each check (the air backend applies them and logs the events)."""

    def __init__(self, params: FidelityParams) -> None:
        self.p = params
        self.encounters = np.zeros(0, dtype=np.int64)  # encounter: running pairs, keys i * n + j (i < j), sorted

    def decide(self, pos: np.ndarray, vel: np.ndarray, piloted: np.ndarray, six_dof: np.ndarray,
               since_s: np.ndarray, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(rows to promote, rows to demote) given every aircraft's state, which fly 6-DOF and since
        when [s]. Piloted rows are never switched."""
        p = self.p
        if p.mode != "multi":
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        n = len(pos)
        if n < 2:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        stretch = np.array([1.0, 1.0, p.promote_radius_m / p.promote_vertical_m])
        ij, miss, closing = closest_approach_pairs(pos * stretch, vel * stretch, piloted, p.demote_radius_m,
                                                   p.promote_ttca_s, p.uav_speed_bound_mps, p.piloted_speed_bound_mps)
        if p.promote_on == "encounter":
            hot = warm = self._encounter_rows(n, ij, miss, closing)
        else:
            if p.promote_on == "converging":  # side by side or parting: no pair (the miss of the others holds)
                miss = np.where(closing > p.closing_min_mps, miss, np.inf)
            hot, warm = close_rows(n, ij, miss, p.promote_radius_m), close_rows(n, ij, miss, p.demote_radius_m)
        promote = np.flatnonzero(hot & ~six_dof & ~piloted)
        demote = np.flatnonzero(six_dof & ~warm & ~piloted & (t_s - since_s >= p.min_dwell_s))
        return promote, demote

    def _encounter_rows(self, n: int, ij: np.ndarray, miss: np.ndarray, closing: np.ndarray) -> np.ndarray:
        """Rows in a running encounter: pairs that start one now (closing, inside the promotion
        boundary) and the running ones still inside the demotion boundary; remembers them."""
        p = self.p
        lo, hi = np.minimum(ij[:, 0], ij[:, 1]), np.maximum(ij[:, 0], ij[:, 1])
        key = lo.astype(np.int64) * n + hi
        start = (closing > p.closing_min_mps) & (miss < p.promote_radius_m)
        keep = np.isin(key, self.encounters) & (miss < p.demote_radius_m)
        self.encounters = np.unique(key[start | keep])
        return close_rows(n, ij, np.where(start | keep, 0.0, np.inf), 1.0)
