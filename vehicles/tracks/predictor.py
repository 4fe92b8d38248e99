"""Prediction of sensed road vehicles along the road axis with one filterpy Kalman filter per track.

Each sensed vehicle is a 1-D track along the road (the road frame's x axis): a constant-velocity
state ``(x, v)`` or a constant-acceleration state ``(x, v, a)``, updated from sensed position and
speed (both noisy) and predicted forward over an MPC horizon.  Why a filter and not the raw sensed
speed: a human driver's speed noise would otherwise make the planned gaps jitter from one control
period to the next, which defeats event-triggered re-planning.

Speeds are signed along +x (oncoming traffic has v < 0).  Predicted speeds never change sign: a car
that is predicted to decelerate stops rather than reversing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter
from pydantic import BaseModel, ConfigDict, Field


class PredictorParams(BaseModel):
    """Noise model and bookkeeping of the along-road predictor."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    model: Literal["cv", "ca"] = "cv"
    pos_noise_m: float = Field(0.5, gt=0.0)  # [m] 1-sigma sensing noise of position
    speed_noise_mps: float = Field(0.5, gt=0.0)  # [m/s] 1-sigma sensing noise of speed
    accel_psd: float = Field(0.1, gt=0.0)  # [m^2/s^3] (cv; [m^2/s^5] ca) white-noise acceleration / jerk psd
    stale_after_s: float = Field(2.0, gt=0.0)  # [s] tracks not updated for this long are dropped
    accel_decay_s: float = Field(2.0, gt=0.0)  # [s] ca model: predicted accel fades with this time constant


@dataclass
class _Track:
    kf: KalmanFilter
    t_s: float  # [s] time of the filter's state


def _make_filter(params: PredictorParams, x_m: float, v_mps: float) -> KalmanFilter:
    dim = 2 if params.model == "cv" else 3
    kf = KalmanFilter(dim_x=dim, dim_z=2)
    kf.x = np.zeros(dim)
    kf.x[0], kf.x[1] = x_m, v_mps
    kf.H = np.zeros((2, dim))
    kf.H[0, 0] = kf.H[1, 1] = 1.0
    kf.R = np.diag([params.pos_noise_m**2, params.speed_noise_mps**2])
    kf.P = np.diag([params.pos_noise_m**2, params.speed_noise_mps**2, 1.0][:dim])
    return kf


def _set_transition(kf: KalmanFilter, params: PredictorParams, dt_s: float) -> None:
    dim = kf.dim_x
    F = np.eye(dim)
    F[0, 1] = dt_s
    if dim == 3:
        F[0, 2], F[1, 2] = 0.5 * dt_s**2, dt_s
    kf.F = F
    kf.Q = Q_continuous_white_noise(dim=dim, dt=dt_s, spectral_density=params.accel_psd)


class RoadVehiclePredictor:
    """Kalman tracks of sensed vehicles keyed by id; ``update`` on measurements, ``predict`` ahead."""

    def __init__(self, params: PredictorParams | None = None) -> None:
        self.params = params or PredictorParams()
        self._tracks: dict[str, _Track] = {}

    def reset(self) -> None:
        self._tracks.clear()

    @property
    def ids(self) -> list[str]:
        return list(self._tracks)

    def update(self, t_s: float, vid: str, x_m: float, v_mps: float) -> None:
        """Fuse one measurement of vehicle ``vid`` taken at time ``t_s``."""
        tr = self._tracks.get(vid)
        if tr is None:
            self._tracks[vid] = _Track(_make_filter(self.params, x_m, v_mps), t_s)
            return
        dt = t_s - tr.t_s
        if dt > 0.0:
            _set_transition(tr.kf, self.params, dt)
            tr.kf.predict()
        tr.kf.update(np.array([x_m, v_mps]))
        tr.t_s = max(tr.t_s, t_s)

    def forget_stale(self, t_s: float) -> list[str]:
        """Drop tracks without a measurement for ``stale_after_s``; returns the dropped ids."""
        dropped = [k for k, tr in self._tracks.items() if t_s - tr.t_s > self.params.stale_after_s]
        for k in dropped:
            del self._tracks[k]
        return dropped

    def state(self, vid: str) -> tuple[float, float, float]:
        """Filtered ``(x [m], v [m/s], a [m/s^2])`` at the track's last update."""
        x = self._tracks[vid].kf.x
        return float(x[0]), float(x[1]), float(x[2]) if len(x) > 2 else 0.0

    def predict(self, vid: str, t_now_s: float, offsets_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean position [m] and speed [m/s] of ``vid`` at ``t_now_s + offsets_s`` (offsets >= 0)."""
        x0, v0, a0 = self.state(vid)
        tau = np.asarray(offsets_s, dtype=float) + (t_now_s - self._tracks[vid].t_s)
        if self.params.model == "ca" and a0 != 0.0:
            # acceleration fading with time constant T: v = v0 + a0 T (1 - e^{-t/T})
            T = self.params.accel_decay_s
            dv = a0 * T * (1.0 - np.exp(-tau / T))
            dx = a0 * T * (tau - T * (1.0 - np.exp(-tau / T)))
        else:
            dv = np.zeros_like(tau)
            dx = np.zeros_like(tau)
        v = v0 + dv
        x = x0 + v0 * tau + dx
        return _no_reversal(x, v, x0, v0, tau)

    def position_std(self, vid: str, t_now_s: float, offsets_s: np.ndarray) -> np.ndarray:
        """1-sigma position uncertainty [m] propagated by the filter's own model (for margins).

        Closed form of ``(F P F^T + Q)[0, 0]`` with the continuous white-noise ``Q`` of filterpy's
        ``Q_continuous_white_noise`` (``q dt^3 / 3`` for cv, ``q dt^5 / 20`` for ca), vectorised.
        """
        tr = self._tracks[vid]
        dt = np.maximum(np.asarray(offsets_s, dtype=float) + (t_now_s - tr.t_s), 0.0)
        P, q = tr.kf.P, self.params.accel_psd
        if tr.kf.dim_x == 2:
            rows = np.stack([np.ones_like(dt), dt], axis=1)
            q00 = q * dt**3 / 3.0
        else:
            rows = np.stack([np.ones_like(dt), dt, 0.5 * dt**2], axis=1)
            q00 = q * dt**5 / 20.0
        var = np.einsum("ki,ij,kj->k", rows, P, rows) + q00
        return np.sqrt(var)

def _no_reversal(x: np.ndarray, v: np.ndarray, x0: float, v0: float,
                 tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clamp predictions so the speed never changes sign (a decelerating car stops, it does not reverse)."""
    flipped = np.sign(v) * np.sign(v0) < 0
    if not flipped.any():
        return x, v
    k = int(np.argmax(flipped))
    v = v.copy()
    x = x.copy()
    v[k:] = 0.0
    x[k:] = x[k - 1] if k > 0 else x0
    return x, v
