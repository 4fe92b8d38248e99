"""Constant-velocity Kalman tracks for every (receiver, source) pair at once: stacked predict/update.

The same filter as :class:`~corridor.vehicles.tracks.table.TrackTable` with ``model="cv"`` and position
plus velocity measurements (what every MAVLink / ADS-B report carries): state ``[p_1..p_d,
v_1..v_d]``, exact discretisation of white acceleration noise ``q``, measurement matrix H = I. One
call fuses a whole set of pairs with stacked ``matmul`` / ``inv`` instead of one filterpy call per
pair; ``tests/vehicles/test_veh_track_stack.py`` checks it against filterpy (``TrackTable``).

Per pair: ``x`` (2d,), ``P`` (2d, 2d), ``t_s`` (time of the filter state = last fused measurement),
``alive`` and ``order`` (creation order; a receiver's tracks are listed in it, as a ``TrackTable``'s
dict keeps them). Measurements older than a track are rejected, as ``TrackTable.update`` does.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from corridor.vehicles.tracks.cv_kernel import cv_fuse_1d


def cv_matrices(dt_s: np.ndarray, dim: int, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Stacked F(dt) and Q(dt) (k, 2d, 2d) of the constant-velocity chain per axis for times ``dt_s``
    (k,) [s], rounded to the nanosecond like ``tracking.model_matrices``."""
    dt = np.round(np.asarray(dt_s, float) * 1e9) * 1e-9
    k, eye = dt.size, np.eye(dim)
    f = np.broadcast_to(np.eye(2 * dim), (k, 2 * dim, 2 * dim)).copy()
    f[:, :dim, dim:] = dt[:, None, None] * eye
    q11, q12, q22 = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    qm = np.empty((k, 2 * dim, 2 * dim))
    qm[:, :dim, :dim] = q11[:, None, None] * eye
    qm[:, :dim, dim:] = q12[:, None, None] * eye
    qm[:, dim:, :dim] = q12[:, None, None] * eye
    qm[:, dim:, dim:] = q22[:, None, None] * eye
    return f, qm


def cv_terms(dt_s: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The entries of :func:`cv_matrices` in 1-D, computed the same way (the same bits): F = [[1, dt],
    [0, 1]] and Q = [[q11, q12], [q12, q22]] for times ``dt_s`` (k,) [s] -> (dt, q11, q12, q22)."""
    dt = np.round(np.asarray(dt_s, float) * 1e9) * 1e-9
    return dt, q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt


def cv_fuse(x: np.ndarray, p: np.ndarray, dt_s: np.ndarray, z: np.ndarray, r: np.ndarray, dim: int,
            q: float, matrices: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Stacked predict by ``dt_s`` (k,) [s] (where > 0) and update with ``z`` (k, 2d) = [position,
    velocity], measurement covariance ``r`` (2d, 2d): the equations of filterpy's
    ``KalmanFilter.predict`` / ``update`` (Joseph form) with H = I. Returns the new (x, P).
    ``matrices(dt_s)``: the stacked (F, Q) (default :func:`cv_matrices`; a cache of it may be given)."""
    ahead = dt_s > 0.0
    if dim == 1:  # compiled: the same bits (see cv_kernel), without ~20 numpy calls per stack
        x, p = np.array(x, dtype=float), np.array(p, dtype=float)
        dt, q11, q12, q22 = cv_terms(dt_s[ahead], q)
        cv_fuse_1d(x, p, ahead, dt, q11, q12, q22, np.asarray(z, dtype=float), np.asarray(r, dtype=float))
        return x, p
    return cv_fuse_stacked(x, p, dt_s, z, r, dim, q, matrices)


def cv_fuse_stacked(x: np.ndarray, p: np.ndarray, dt_s: np.ndarray, z: np.ndarray, r: np.ndarray, dim: int,
                    q: float, matrices: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cv_fuse` in stacked numpy products (any ``dim``; the reference of the compiled 1-D fuse)."""
    ahead = dt_s > 0.0
    if ahead.any():
        f, qm = matrices(dt_s[ahead]) if matrices is not None else cv_matrices(dt_s[ahead], dim, q)
        x[ahead] = (f @ x[ahead][:, :, None])[:, :, 0]
        p[ahead] = f @ p[ahead] @ f.transpose(0, 2, 1) + qm
    k = p @ np.linalg.inv(p + r)
    x = x + (k @ (z - x)[:, :, None])[:, :, 0]
    i_k = np.eye(2 * dim) - k
    p = i_k @ p @ i_k.transpose(0, 2, 1) + k @ r @ k.transpose(0, 2, 1)
    return x, p


class TrackStack:
    """CV tracks of ``n_rx`` receivers x ``n_src`` sources (struct of arrays, see the module doc).

    ``process_noise`` [m^2/s^3], ``meas_noise`` [m] / ``vel_noise`` [m/s] measurement std."""

    def __init__(self, n_rx: int, n_src: int, dim: int, process_noise: float, meas_noise: float,
                 vel_noise: float) -> None:
        n = 2 * dim
        self.dim, self.q = dim, float(process_noise)
        self.x = np.zeros((n_rx, n_src, n))
        self.P = np.zeros((n_rx, n_src, n, n))
        self.t_s = np.zeros((n_rx, n_src))
        self.alive = np.zeros((n_rx, n_src), dtype=bool)
        self.order = np.zeros((n_rx, n_src), dtype=np.int64)
        r = np.r_[np.full(dim, float(meas_noise) ** 2), np.full(dim, float(vel_noise) ** 2)]
        self._r = np.diag(r)

    def fuse(self, rows: np.ndarray, cols: np.ndarray, t_s: np.ndarray, z: np.ndarray, order: np.ndarray) -> np.ndarray:
        """Fuse measurement ``z`` (k, 2d) = [position, velocity] taken at ``t_s`` (k,) into pairs
        (``rows``, ``cols``) (each pair at most once); a pair without a track starts one with
        creation ``order``. Returns which measurements were used (False: older than the track)."""
        alive = self.alive[rows, cols]
        new = ~alive
        if new.any():
            r, c = rows[new], cols[new]
            self.x[r, c] = z[new]
            self.P[r, c] = self._r
            self.t_s[r, c] = t_s[new]
            self.alive[r, c] = True
            self.order[r, c] = order[new]
        used = new | (t_s >= self.t_s[rows, cols])
        upd = alive & used
        if upd.any():
            self._update(rows[upd], cols[upd], t_s[upd], z[upd])
        return used

    def _update(self, r: np.ndarray, c: np.ndarray, t_s: np.ndarray, z: np.ndarray) -> None:
        """Predict to ``t_s`` (where later than the track) and update (see :func:`cv_fuse`)."""
        x, p = cv_fuse(self.x[r, c], self.P[r, c], t_s - self.t_s[r, c], z, self._r, self.dim, self.q)
        self.x[r, c], self.P[r, c], self.t_s[r, c] = x, p, t_s

    def kill(self, mask: np.ndarray) -> None:
        """Drop the tracks where ``mask`` (n_rx, n_src) is True."""
        self.alive &= ~mask

    def drop_stale(self, rows: np.ndarray, t_s: float, stale_after_s: float) -> None:
        """Drop the tracks of ``rows`` whose newest measurement is older than ``stale_after_s``."""
        sub = self.alive[rows] & (t_s - self.t_s[rows] > stale_after_s)
        self.alive[rows] = self.alive[rows] & ~sub

    def predict(self, rows: np.ndarray, cols: np.ndarray, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """States (k, 2d) and covariances (k, 2d, 2d) of pairs (``rows``, ``cols``) extrapolated to
        ``t_s`` (never backwards); the tracks are not modified."""
        age = np.maximum(0.0, t_s - self.t_s[rows, cols])
        f, q = cv_matrices(age, self.dim, self.q)
        x = (f @ self.x[rows, cols][:, :, None])[:, :, 0]
        p = f @ self.P[rows, cols] @ f.transpose(0, 2, 1) + q
        return x, p
