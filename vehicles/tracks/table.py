"""Track table: one filterpy Kalman filter per remote entity, fed by delayed, lossy messages.

Each connected vehicle, the roadside unit and the UAV ground station keep a ``TrackTable`` of what
they have *received*; controllers read ``predict_all(t_now)`` — every track extrapolated to the
current time without touching the filters — so decisions use estimates, never ground truth.

Model: a kinematic chain per axis in ``dim`` dimensions (1-D along-road, 2-D plane, 3-D air),
constant velocity (``model="cv"``, state [p, v]) or constant acceleration (``"ca"``, [p, v, a]).
The state vector is blocked by derivative order: ``[p_1..p_dim, v_1..v_dim, (a_1..a_dim)]``.
Process noise is continuous white noise on the highest derivative with spectral density
``process_noise`` ([m²/s³] for CV — acceleration noise; [m²/s⁵] for CA — jerk noise), discretised
exactly for each interval so irregular message gaps are handled consistently.

Measurements arriving out of order (older than the track's last update) are ignored: a Kalman filter
cannot rewind, and with CAM-rate data the lost information is negligible.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.linalg.lapack import dgesv


@dataclass(frozen=True)
class Track:
    """A track predicted to some time: estimates, full state covariance and information age."""

    pos: np.ndarray  # [m] (dim,)
    vel: np.ndarray  # [m/s] (dim,)
    cov: np.ndarray  # state covariance, layout of the module docstring
    age_s: float  # [s] time since the newest measurement used
    acc: np.ndarray | None = None  # [m/s²] (dim,), constant-acceleration model only

    @property
    def pos_cov(self) -> np.ndarray:
        """Position block of ``cov`` [m²]."""
        d = self.pos.size
        return self.cov[:d, :d]


@lru_cache(maxsize=4096)
def _model_matrices(dt_key: int, order: int, dim: int, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Cached (F, Q) for a time step given in nanoseconds: message intervals repeat (they lie on the
    senders' period grid), so the hot path never rebuilds them."""
    dt_s = dt_key * 1e-9
    f, qm = transition(dt_s, order, dim), process_cov(dt_s, order, dim, q)
    f.flags.writeable = False
    qm.flags.writeable = False
    return f, qm


def model_matrices(dt_s: float, order: int, dim: int, q: float) -> tuple[np.ndarray, np.ndarray]:
    return _model_matrices(round(dt_s * 1e9), order, dim, q)


def transition(dt_s: float, order: int, dim: int) -> np.ndarray:
    """State transition F(dt) of an ``order``-state kinematic chain (2 = CV, 3 = CA) per axis."""
    f1 = np.eye(order)
    for k in range(1, order):
        f1 += np.diag(np.full(order - k, dt_s**k / np.prod(np.arange(1, k + 1))), k)
    return np.kron(f1, np.eye(dim))


def process_cov(dt_s: float, order: int, dim: int, q: float) -> np.ndarray:
    """Exact discretisation of continuous white noise (density ``q``) on the last chain state."""
    # Q1[i, j] = q * dt^(2n-1-i-j) / ((n-1-i)! (n-1-j)! (2n-1-i-j)) with n = order
    n = order
    q1 = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            p = 2 * n - 1 - i - j
            q1[i, j] = q * dt_s**p / (_fact(n - 1 - i) * _fact(n - 1 - j) * p)
    return np.kron(q1, np.eye(dim))


def _fact(k: int) -> float:
    return float(np.prod(np.arange(1, k + 1)))


def _inverse(s: np.ndarray) -> np.ndarray:
    """S^-1 by LAPACK ``gesv`` against the identity (what ``numpy.linalg.inv`` computes), without
    numpy.linalg's per-call wrapper cost (~4x on the 6x6 innovation covariance). Set as the filters'
    ``inv`` (filterpy's hook for the inverse in ``update``); a singular S raises as numpy's does."""
    _, _, x, info = dgesv(s, _eye(s.shape[0]))
    return x if info == 0 else np.linalg.inv(s)


@lru_cache(maxsize=8)
def _eye(n: int) -> np.ndarray:
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


@dataclass
class _Entry:
    kf: KalmanFilter
    t_s: float  # [s] time of the filter state (= last measurement)


class TrackTable:
    """Kalman-filter tracks keyed by entity id (see the module docstring for the model)."""

    def __init__(
        self,
        dim: int,
        process_noise: float,
        meas_noise: float,
        stale_after_s: float,
        model: Literal["cv", "ca"] = "cv",
        vel_noise: float | None = None,
        init_vel_std: float = 10.0,
        init_acc_std: float = 3.0,
    ) -> None:
        """``meas_noise`` / ``vel_noise``: std of position [m] / velocity [m/s] measurements;
        ``init_vel_std`` [m/s], ``init_acc_std`` [m/s²]: prior std of unmeasured derivatives."""
        if dim not in (1, 2, 3):
            raise ValueError("dim must be 1, 2 or 3")
        self.dim = dim
        self.order = {"cv": 2, "ca": 3}[model]
        self.q = float(process_noise)
        self.r_pos = float(meas_noise) ** 2
        self.r_vel = float(vel_noise if vel_noise is not None else meas_noise) ** 2
        self.stale_after_s = float(stale_after_s)
        self._init_std = (init_vel_std, init_acc_std)
        self._tracks: dict[str, _Entry] = {}
        self._hr: dict[bool, tuple[np.ndarray, np.ndarray]] = {}  # measurement model cache

    # -- updates --------------------------------------------------------------------------------
    def update(self, track_id: str, t_s: float, pos: np.ndarray, vel: np.ndarray | None = None) -> bool:
        """Fuse one measurement taken at ``t_s``; returns False if it was older than the track."""
        z_pos = np.asarray(pos, dtype=float).reshape(self.dim)
        z_vel = None if vel is None else np.asarray(vel, dtype=float).reshape(self.dim)
        entry = self._tracks.get(track_id)
        if entry is None:
            self._tracks[track_id] = _Entry(self._new_filter(z_pos, z_vel), float(t_s))
            return True
        if t_s < entry.t_s:
            return False
        kf = entry.kf
        dt_s = t_s - entry.t_s
        if dt_s > 0:
            kf.F, kf.Q = model_matrices(dt_s, self.order, self.dim, self.q)
            kf.predict()
        z, h, r = self._measurement(z_pos, z_vel)
        kf.update(z, R=r, H=h)
        entry.t_s = float(t_s)
        return True

    def _new_filter(self, z_pos: np.ndarray, z_vel: np.ndarray | None) -> KalmanFilter:
        n = self.order * self.dim
        kf = KalmanFilter(dim_x=n, dim_z=self.dim)
        kf.inv = _inverse
        x = np.zeros(n)
        x[: self.dim] = z_pos
        var = np.full(n, self._init_std[0] ** 2)
        var[: self.dim] = self.r_pos
        if z_vel is not None:
            x[self.dim : 2 * self.dim] = z_vel
            var[self.dim : 2 * self.dim] = self.r_vel
        if self.order == 3:
            var[2 * self.dim :] = self._init_std[1] ** 2
        kf.x = x
        kf.P = np.diag(var)
        return kf

    def _measurement(self, z_pos: np.ndarray, z_vel: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """Measurement vector, matrix H and covariance R (position, optionally velocity)."""
        z = z_pos if z_vel is None else np.concatenate([z_pos, z_vel])
        key = z_vel is not None
        if key not in self._hr:
            self._hr[key] = self._measurement_model(key)
        return (z, *self._hr[key])

    def _measurement_model(self, with_vel: bool) -> tuple[np.ndarray, np.ndarray]:
        d, n = self.dim, self.order * self.dim
        rows = 2 * d if with_vel else d
        h = np.zeros((rows, n))
        h[:rows, :rows] = np.eye(rows)
        r_diag = np.r_[np.full(d, self.r_pos), np.full(rows - d, self.r_vel)]
        return h, np.diag(r_diag)

    # -- queries --------------------------------------------------------------------------------
    def predict_all(self, t_s: float) -> dict[str, Track]:
        """Every track extrapolated to ``t_s`` (never backwards); the filters are not modified."""
        ids, x, p, age = self.predict_arrays(t_s)
        d = self.dim
        return {
            tid: Track(pos=x[i, :d].copy(), vel=x[i, d : 2 * d].copy(), cov=p[i], age_s=float(age[i]),
                       acc=x[i, 2 * d :].copy() if self.order == 3 else None)
            for i, tid in enumerate(ids)
        }

    def predict_arrays(self, t_s: float) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """Every track extrapolated to ``t_s`` in one batched pass (struct of arrays): ids, states
        (k, n), covariances (k, n, n) and ages (k,) [s]; layout of the module docstring.

        The same products as :meth:`predict` per track (``F x`` and ``F P F' + Q``), stacked into
        one ``matmul`` each instead of k small ones; the filters are not modified."""
        n = self.order * self.dim
        entries = list(self._tracks.values())
        if not entries:
            return [], np.zeros((0, n)), np.zeros((0, n, n)), np.zeros(0)
        age = [max(0.0, t_s - e.t_s) for e in entries]
        mats = [model_matrices(a, self.order, self.dim, self.q) for a in age]
        f = np.array([m[0] for m in mats])
        q = np.array([m[1] for m in mats])
        x = (f @ np.array([e.kf.x for e in entries])[:, :, None])[:, :, 0]
        p = f @ np.array([e.kf.P for e in entries]) @ f.transpose(0, 2, 1) + q
        return list(self._tracks), x, p, np.array(age)

    def predict(self, track_id: str, t_s: float) -> Track:
        """One track extrapolated to ``t_s`` (KeyError if unknown)."""
        return self._predicted(self._tracks[track_id], t_s)

    def _predicted(self, e: _Entry, t_s: float) -> Track:
        age_s = max(0.0, t_s - e.t_s)
        f, q = model_matrices(age_s, self.order, self.dim, self.q)
        x = f @ e.kf.x
        p = f @ e.kf.P @ f.T + q
        d = self.dim
        acc = x[2 * d :].copy() if self.order == 3 else None
        return Track(pos=x[:d].copy(), vel=x[d : 2 * d].copy(), cov=p, age_s=age_s, acc=acc)

    def drop_stale(self, t_s: float) -> list[str]:
        """Remove tracks whose newest measurement is older than ``stale_after_s``; returns their ids."""
        stale = [tid for tid, e in self._tracks.items() if t_s - e.t_s > self.stale_after_s]
        for tid in stale:
            del self._tracks[tid]
        return stale

    def remove(self, track_id: str) -> None:
        """Forget one track (e.g. the entity left the scenario)."""
        self._tracks.pop(track_id, None)

    def last_update_s(self, track_id: str) -> float:
        """Time [s] of the newest measurement of a track."""
        return self._tracks[track_id].t_s

    def __contains__(self, track_id: object) -> bool:
        return track_id in self._tracks

    def __len__(self) -> int:
        return len(self._tracks)

    @property
    def ids(self) -> list[str]:
        return list(self._tracks)
