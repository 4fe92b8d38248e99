"""Fusion at the traffic centre: per METANET segment, a Kalman filter on density and space-mean speed
fed by the loop stations and the UAV camera estimates (algorithm only; the engine component is
``corridor.traffic.macro.fusion_component``).

Model: each segment's density rho [veh/km/lane] and speed v [km/h] follow a random walk (process
noise densities ``q_rho``, ``q_v`` per second); filters of different segments are independent.

- A loop station measures the density of the segment it sits on (occupancy x 10 / vehicle length)
  with variance ``loop_sigma^2`` and its speed (q / rho, as the direct mapping) with
  ``loop_speed_sigma^2``.  The station sees one point of a 1.25 km segment, at a merge where the
  queue or the acceleration stretch is, so its error against the segment's mean density is mostly
  representativeness: healthy loops by the direct mapping are ~10 veh/km/lane (RMSE) off the
  segment truth on the beltway (air_ground_watch ``loops``, seed 0: 10.1), hence ``loop_sigma`` 10.
  (It was 4: healthy stations' innovations then averaged well above the gate, and 13 of the 22
  healthy stations of a seed-0 run ended down-weighted as if faulty, mostly the upstream stations
  that see the queues, which biased the fused density low.)
- A camera estimate carries its own variance; its age at fusion (age of information, t_now -
  t_meas) adds ``q x age`` (what the random walk may have moved since it was taken).  The camera's
  variance is mostly counting noise, proportional to the expected count (Poisson, and the
  Horvitz-Thompson miss term), which the camera can only evaluate at what it counted.  Given the
  observed area, the filter re-evaluates it at its own prior density (``update_uav(area_km_lane=)``):
  weights taken from the observed count make a low count look precise and a high count
  imprecise, so inverse-variance fusion drifts low (seed 0: fused density 4.6 veh/km/lane, 18 %,
  below the truth on average, every segment low).
- **Fault down-weighting.** Each station keeps an exponentially weighted mean of its normalised
  innovation squared, ``h <- (1 - a) h + a e^2 / (P + R)``; its variance is inflated by
  ``max(1, h / nis_gate)^2`` (weight = the inverse).  A healthy station's NIS averages ~1; a stuck,
  frozen or biased one keeps disagreeing with what the other station and the cameras say, so its
  weight falls and the filter follows the others.  Without any other source (no UAV over the
  segment) two stations can only out-vote each other, which is why the cameras matter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class FusionParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    q_rho: float = Field(0.5, gt=0.0)  # [(veh/km/lane)^2 / s] random-walk density
    q_v: float = Field(5.0, gt=0.0)  # [(km/h)^2 / s]
    loop_sigma: float = Field(10.0, gt=0.0)  # [veh/km/lane] station -> segment mean density (representativeness)
    loop_speed_sigma_kmh: float = Field(12.0, gt=0.0)  # [km/h]
    uav_min_sigma: float = Field(1.0, gt=0.0)  # [veh/km/lane] floor of a camera estimate's std
    nis_alpha: float = Field(0.3, gt=0.0, le=1.0)  # EWMA weight of a station's newest NIS
    nis_gate: float = Field(3.0, gt=0.0)  # EWMA NIS above which a station is down-weighted
    rho_init: float = Field(10.0, ge=0.0)  # [veh/km/lane] prior before any measurement
    rho_init_sigma: float = Field(50.0, gt=0.0)


@dataclass
class StationHealth:
    nis_ewma: float = 1.0
    updates: int = 0


@dataclass
class SegmentFilter:
    """Independent scalar Kalman filters (density, speed) for ``n_seg`` segments."""

    n_seg: int
    p: FusionParams = field(default_factory=FusionParams)

    def __post_init__(self) -> None:
        self.rho = np.full(self.n_seg, self.p.rho_init)
        self.P_rho = np.full(self.n_seg, self.p.rho_init_sigma**2)
        self.v = np.full(self.n_seg, np.nan)  # [km/h] nan until measured
        self.P_v = np.full(self.n_seg, np.inf)
        self.t_s = 0.0
        self.health: dict[str, StationHealth] = {}
        self.last_uav_s = np.full(self.n_seg, -np.inf)  # [s] measurement time of the newest camera estimate

    def predict(self, t_s: float) -> None:
        dt = max(t_s - self.t_s, 0.0)
        self.P_rho += self.p.q_rho * dt
        self.P_v = np.where(np.isfinite(self.P_v), self.P_v + self.p.q_v * dt, self.P_v)
        self.t_s = max(self.t_s, t_s)

    def _update(self, i: int, z_rho: float, r_rho: float, z_v: float, r_v: float) -> float:
        """Scalar updates of segment i; returns the density innovation's NIS."""
        e = z_rho - self.rho[i]
        s = self.P_rho[i] + r_rho
        k = self.P_rho[i] / s
        self.rho[i] = max(self.rho[i] + k * e, 0.0)
        self.P_rho[i] *= 1.0 - k
        if np.isfinite(z_v) and np.isfinite(r_v):
            if not np.isfinite(self.P_v[i]):
                self.v[i], self.P_v[i] = z_v, r_v
            else:
                kv = self.P_v[i] / (self.P_v[i] + r_v)
                self.v[i] += kv * (z_v - self.v[i])
                self.P_v[i] *= 1.0 - kv
        return e * e / s

    def station_weight(self, station: str) -> float:
        """1 / variance inflation of a loop station (1: trusted as configured)."""
        h = self.health.get(station)
        if h is None:
            return 1.0
        return 1.0 / max(1.0, h.nis_ewma / self.p.nis_gate) ** 2

    def update_loop(self, station: str, i: int, rho: float, v_kmh: float) -> None:
        """One loop station's density [veh/km/lane] and speed [km/h] (nan: none) for segment i."""
        self.update_loops([(station, i, rho, v_kmh)])

    def update_loops(self, readings: list[tuple[str, int, float, float]]) -> None:
        """The stations' readings of one interval, ``(station, segment, rho, v_kmh)``: each station's NIS
        is taken against the same prior (with its nominal variance), so the order of the stations
        within an interval does not matter; the updates use the weights from the earlier intervals."""
        p = self.p
        nis = [(rho - self.rho[i]) ** 2 / (self.P_rho[i] + p.loop_sigma**2) for _, i, rho, _ in readings]
        weights = [self.station_weight(st) for st, *_ in readings]
        for (_, i, rho, v), w in zip(readings, weights, strict=True):
            self._update(i, rho, p.loop_sigma**2 / w, v, p.loop_speed_sigma_kmh**2 / w)
        for (st, *_), e2 in zip(readings, nis, strict=True):
            h = self.health.setdefault(st, StationHealth())
            h.nis_ewma = (1.0 - p.nis_alpha) * h.nis_ewma + p.nis_alpha * e2
            h.updates += 1

    def update_uav(self, i: int, t_meas_s: float, rho: float, rho_var: float, v_kmh: float, v_var_kmh2: float,
                   area_km_lane: float | None = None) -> None:
        """A camera estimate taken at ``t_meas_s`` (its age inflates the variance: random walk).

        With ``area_km_lane`` (observed length x lanes) the camera's counting variance, which it
        computed at its own count (``(misses + N + 1) / A^2``, proportional to N + 1), is rescaled to
        the count the filter expects, ``rho_prior A``: the variance must not depend on the noise of
        the measurement it weighs, or low readings win (see the module docstring)."""
        age = max(self.t_s - t_meas_s, 0.0)
        if area_km_lane is not None and area_km_lane > 0.0:
            rho_var = rho_var * (max(self.rho[i], 0.0) * area_km_lane + 1.0) / (max(rho, 0.0) * area_km_lane + 1.0)
        r_rho = max(rho_var, self.p.uav_min_sigma**2) + self.p.q_rho * age
        r_v = v_var_kmh2 + self.p.q_v * age if np.isfinite(v_var_kmh2) else np.nan
        self._update(i, rho, r_rho, v_kmh, r_v)
        self.last_uav_s[i] = max(self.last_uav_s[i], t_meas_s)
