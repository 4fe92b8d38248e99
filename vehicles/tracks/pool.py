"""Constant-velocity Kalman tracks keyed by (receiver, source) names: the V2X tracks of a merging
controller, where receivers and sources come and go, fused and predicted in stacked passes.

The same filter as :class:`~corridor.vehicles.tracks.table.TrackTable` with ``model="cv"`` and position
plus velocity measurements, one table per receiver (the equations of
:func:`~corridor.vehicles.tracks.stack.cv_fuse`, which ``tests/vehicles/test_veh_track_stack.py``
checks against filterpy). The tracks live in one struct of arrays (rows recycled through a free
list); :meth:`TrackPool.fuse` takes every measurement received in a tick at once and applies them
per pair in the order given (a pair's later messages in later stacked rounds), rejecting
measurements older than their track as ``TrackTable.update`` does. ``tests/vehicles/
test_veh_track_pool.py`` checks it bit for bit against ``TrackTable`` (filterpy) in 1-D.
"""

from __future__ import annotations

import numpy as np

from corridor.vehicles.tracks.stack import cv_fuse, cv_matrices, cv_terms


class TrackPool:
    """CV tracks of named receivers on named sources (see the module docstring).

    ``process_noise`` [m^2/s^3]; ``meas_noise`` [m] / ``vel_noise`` [m/s] measurement std;
    ``stale_after_s`` [s]: :meth:`drop_stale` forgets tracks whose newest measurement is older."""

    def __init__(self, dim: int, process_noise: float, meas_noise: float, vel_noise: float,
                 stale_after_s: float) -> None:
        self.dim, self.q = dim, float(process_noise)
        self.stale_after_s = float(stale_after_s)
        self._r = np.diag(np.r_[np.full(dim, float(meas_noise) ** 2), np.full(dim, float(vel_noise) ** 2)])
        self._rows: dict[str, dict[str, int]] = {}  # receiver -> {source: row}
        self._free: list[int] = []
        self._cap = 0
        self.x = np.zeros((0, 2 * dim))
        self.P = np.zeros((0, 2 * dim, 2 * dim))
        self.t_s = np.zeros(0)  # [s] time of each row's state (= its newest measurement)
        self._mats: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # (F, Q) by dt [ns]: intervals repeat
        self._grow(64)

    # -- receivers ------------------------------------------------------------------------------
    def add_receiver(self, rx: str) -> None:
        self._rows.setdefault(rx, {})

    def remove_receiver(self, rx: str) -> None:
        """Forget a receiver and its tracks."""
        self._free.extend(self._rows.pop(rx, {}).values())

    def __contains__(self, rx: object) -> bool:
        return rx in self._rows

    @property
    def receivers(self) -> list[str]:
        return list(self._rows)

    def has_track(self, rx: str, src: str) -> bool:
        return src in self._rows.get(rx, ())

    def state(self, rx: str, src: str) -> tuple[np.ndarray, np.ndarray]:
        """The fused state ``x`` (positions then velocities [m, m/s]) and covariance ``P`` of the track
        of ``src`` kept by ``rx`` (views into the pool; KeyError if none)."""
        row = self._rows[rx][src]
        return self.x[row], self.P[row]

    def last_update_s(self, rx: str, src: str) -> float:
        """Time [s] of the newest measurement of ``src`` fused by ``rx`` (KeyError if none)."""
        return float(self.t_s[self._rows[rx][src]])

    # -- updates --------------------------------------------------------------------------------
    def fuse(self, rx: list[str], src: list[str], t_s: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Fuse measurements ``z`` (k, 2d) = [position, velocity] taken at ``t_s`` (k,) [s] from
        ``src[i]`` into ``rx[i]``'s track (started if absent; ``rx[i]`` must be a receiver), in the
        given order per pair. Returns which measurements were used (False: older than the track)."""
        t_s, z = np.asarray(t_s, dtype=float), np.asarray(z, dtype=float).reshape(len(rx), 2 * self.dim)
        used = np.zeros(len(rx), dtype=bool)
        rows, new = self._rows_of(rx, src)
        if len(set(rows)) == len(rows):  # every pair once (the usual tick): one stacked pass
            self._fuse_round(np.arange(len(rx)), np.array(rows, dtype=np.int64), np.array(new, dtype=bool),
                             t_s, z, used)
            return used
        rounds: list[list[int]] = []
        seen: dict[int, int] = {}
        for i, row in enumerate(rows):  # a pair's n-th message goes in round n
            n = seen.get(row, 0)
            seen[row] = n + 1
            if n == len(rounds):
                rounds.append([])
            rounds[n].append(i)
        first = np.array(new, dtype=bool)  # only a pair's first message can start its track
        all_rows = np.array(rows, dtype=np.int64)
        for n, idx in enumerate(rounds):
            ix = np.array(idx)
            self._fuse_round(ix, all_rows[ix], first[ix] if n == 0 else np.zeros(ix.size, dtype=bool), t_s, z, used)
        return used

    def _rows_of(self, rx: list[str], src: list[str]) -> tuple[list[int], list[bool]]:
        """The row of each (receiver, source) pair, allocated on its first message (flagged new)."""
        rows: list[int] = []
        new: list[bool] = []
        for r, s in zip(rx, src, strict=True):
            table = self._rows[r]
            row = table.get(s)
            new.append(row is None)
            if row is None:
                row = table[s] = self._alloc()
            rows.append(row)
        return rows, new

    def _fuse_round(self, idx: np.ndarray, rows: np.ndarray, new: np.ndarray, t_s: np.ndarray, z: np.ndarray,
                    used: np.ndarray) -> None:
        """One stacked pass over distinct pairs ``rows`` (messages ``idx``): start the ``new`` tracks,
        update the others."""
        t = t_s[idx]
        if new.any():
            r = rows[new]
            self.x[r], self.P[r], self.t_s[r] = z[idx[new]], self._r, t[new]
        upd = ~new & (t >= self.t_s[rows])
        used[idx] = new | upd
        if upd.any():
            r, tu = rows[upd], t[upd]
            x, p = cv_fuse(self.x[r], self.P[r], tu - self.t_s[r], z[idx[upd]], self._r, self.dim, self.q,
                           self._matrices)
            self.x[r], self.P[r], self.t_s[r] = x, p, tu

    def drop_stale(self, t_s: float) -> None:
        """Forget every track whose newest measurement is older than ``stale_after_s``."""
        if not any(self._rows.values()):
            return
        old = (t_s - self.t_s > self.stale_after_s).tolist()  # a list: one Python test per track
        for table in self._rows.values():
            stale = [s for s, row in table.items() if old[row]]
            for s in stale:
                self._free.append(table.pop(s))

    # -- queries --------------------------------------------------------------------------------
    def predict_states(self, rx: str, sources: list[str], t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States of ``rx``'s tracks of ``sources`` extrapolated to ``t_s`` (never backwards):
        whether each is tracked (k,), states (k, 2d) (zeros where untracked) and ages (k,) [s]
        (``F x`` stacked, as ``TrackTable.predict_arrays``; the tracks are not modified)."""
        table = self._rows.get(rx, {})
        rows = [table.get(s, -1) for s in sources]
        known = np.array([r >= 0 for r in rows], dtype=bool)
        x = np.zeros((len(sources), 2 * self.dim))
        age = np.zeros(len(sources))
        if known.any():
            r = np.array(rows)[known]
            a = np.maximum(0.0, t_s - self.t_s[r])
            if self.dim == 1:  # F x with F = [[1, dt], [0, 1]] as BLAS dgemv rounds it (see cv_kernel)
                dt, xr = cv_terms(a, self.q)[0], self.x[r]
                x[known] = np.column_stack((xr[:, 0] + dt * xr[:, 1], xr[:, 1] + 0.0 * xr[:, 0]))
            else:
                f, _ = self._matrices(a)
                x[known] = (f @ self.x[r][:, :, None])[:, :, 0]
            age[known] = a
        return known, x, age

    def predict_one(self, rx: str, src: str, t_s: float) -> tuple[float, float, float] | None:
        """``predict_states(rx, [src], t_s)`` of a 1-D pool in Python floats (the same operations, the
        same bits, without the stacking): (position [m], velocity [m/s], age [s]), None if untracked."""
        row = self._rows.get(rx, {}).get(src)
        if row is None:
            return None
        age = max(0.0, t_s - float(self.t_s[row]))
        dt = round(age * 1e9) * 1e-9  # cv_terms' rounding (half to even, as np.round)
        x0, x1 = float(self.x[row, 0]), float(self.x[row, 1])
        return x0 + dt * x1, x1 + 0.0 * x0, age

    def _matrices(self, dt_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cv_matrices(dt_s)``, each distinct interval (to the nanosecond, as there) built once."""
        mats = [self._mats.get(key) or self._build(key) for key in np.round(np.asarray(dt_s, float) * 1e9).tolist()]
        return np.array([m[0] for m in mats]), np.array([m[1] for m in mats])

    def _build(self, key_ns: float) -> tuple[np.ndarray, np.ndarray]:
        if len(self._mats) > 4096:
            self._mats.clear()
        f, q = cv_matrices(np.array([key_ns * 1e-9]), self.dim, self.q)
        self._mats[key_ns] = (f[0], q[0])
        return f[0], q[0]

    # -- storage --------------------------------------------------------------------------------
    def _alloc(self) -> int:
        if not self._free:
            self._grow(2 * self._cap)
        return self._free.pop()

    def _grow(self, cap: int) -> None:
        n, m = self._cap, 2 * self.dim
        self.x = np.concatenate([self.x, np.zeros((cap - n, m))])
        self.P = np.concatenate([self.P, np.zeros((cap - n, m, m))])
        self.t_s = np.concatenate([self.t_s, np.zeros(cap - n)])
        self._free.extend(range(cap - 1, n - 1, -1))
        self._cap = cap
