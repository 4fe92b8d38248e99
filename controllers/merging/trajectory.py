"""Energy-optimal unconstrained merging trajectory (decentralized optimal merging).

Rios-Torres & Malikopoulos, "Automated and cooperative vehicle merging at highway on-ramps",
IEEE T-ITS 18(4), 2017: each vehicle in the control zone minimises ``∫ ½ u² dt`` subject to the
double integrator ``ẋ = v, v̇ = u``, its current state ``x(t0)=x0, v(t0)=v0`` and the assigned merge
crossing ``x(tf) = L``.  Pontryagin gives a linear control ``u(t) = a t + b`` and a cubic position
``x(t) = a t³/6 + b t²/2 + c t + d``; the four coefficients solve a 4×4 linear system built from
the boundary conditions.  Two terminal variants:

- fixed terminal speed ``v(tf) = vf`` (e.g. the speed of the mainline at the merge);
- free terminal speed: the transversality condition gives ``u(tf) = 0``.

The unconstrained solution is what the paper applies while no state/control constraint is active.
Here limits are *checked* in closed form (``u`` is linear, so its extremes are at the ends; ``v`` is
quadratic, so its extreme is at ``t* = -b/a``).  A plan that violates them is reported infeasible
together with the window of crossing times ``[earliest_s, latest_s]`` whose unconstrained solution
respects every limit, so the coordinator can re-assign; its ``accel`` command is saturated to the
acceleration limits.  The vehicle controller re-plans from its measured state every tick
(receding horizon), which is how the open-loop solution is applied in closed loop.

Time is shifted to ``τ = t - t0`` inside the solution (the system matrix is then well conditioned).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class MotionLimits(BaseModel):
    """Speed and acceleration limits of a controlled vehicle."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    v_min_mps: float = Field(0.0, ge=0.0)  # [m/s]
    v_max_mps: float = Field(33.3, gt=0.0)  # [m/s]
    a_min_mps2: float = Field(-3.0, lt=0.0)  # [m/s²] strongest planned deceleration
    a_max_mps2: float = Field(2.0, gt=0.0)  # [m/s²]


_TOL = 1e-9  # numerical slack of the limit checks


def boundary_system(
    x0: float, v0: float, horizon_s: float, dist_m: float, vf: float | None
) -> tuple[np.ndarray, ...]:
    """The 4×4 linear system M·(a, b, c, d) = r of the boundary conditions (paper form, τ0 = 0).

    Rows: x(0) = x0, v(0) = v0, x(T) = x0 + dist, and v(T) = vf (fixed) or u(T) = 0 (free speed).
    """
    t = horizon_s
    m = np.array(
        [
            [0.0, 0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
            [t**3 / 6.0, t**2 / 2.0, t, 1.0],
            [t**2 / 2.0, t, 1.0, 0.0] if vf is not None else [t, 1.0, 0.0, 0.0],
        ]
    )
    return m, np.array([x0, v0, x0 + dist_m, vf if vf is not None else 0.0])


def cubic_coefficients(x0: float, v0: float, horizon_s: float, dist_m: float, vf: float | None) -> np.ndarray:
    """Coefficients (a, b, c, d) of x(τ) = aτ³/6 + bτ²/2 + cτ + d on τ ∈ [0, T].

    The solution of ``boundary_system``: at τ0 = 0 it is block triangular (d = x0, c = v0) and the
    remaining 2×2 block is solved in closed form, which is exact where a generic solver loses ~1e-9
    to the T³-vs-1 scaling (enough to flip a limit check at the edge of the feasible window).
    """
    a, b = _closed_form_ab(v0, np.asarray(horizon_s, dtype=float), dist_m, vf)
    return np.array([float(a), float(b), v0, x0])


def _closed_form_ab(
    v0: float, horizon_s: np.ndarray, dist_m: float, vf: float | None
) -> tuple[np.ndarray, ...]:
    """Vectorised (a, b) over many horizons T (same solution as ``cubic_coefficients``)."""
    t = horizon_s
    dx = dist_m - v0 * t  # distance beyond coasting
    if vf is None:
        a = -3.0 * dx / t**3
        return a, -a * t
    a = (6.0 * (vf - v0) * t - 12.0 * dx) / t**3
    return a, (vf - v0 - a * t**2 / 2.0) / t


def _within_limits(v0: float, a: np.ndarray, b: np.ndarray, t: np.ndarray, lim: MotionLimits) -> np.ndarray:
    """True where u = aτ + b and v = v0 + bτ + aτ²/2 respect the limits on [0, T]."""
    u_end = a * t + b
    v_end = v0 + b * t + a * t**2 / 2.0
    safe_a = np.where(np.abs(a) > 1e-12, a, 1.0)
    t_star = np.where(np.abs(a) > 1e-12, -b / safe_a, 0.0)
    inner = (t_star > 0.0) & (t_star < t)
    v_star = np.where(inner, v0 - b**2 / (2.0 * safe_a), v0)
    v_lo = np.minimum(np.minimum(v0, v_end), v_star)
    v_hi = np.maximum(np.maximum(v0, v_end), v_star)
    return (
        (np.minimum(b, u_end) >= lim.a_min_mps2 - _TOL)
        & (np.maximum(b, u_end) <= lim.a_max_mps2 + _TOL)
        & (v_lo >= lim.v_min_mps - _TOL)
        & (v_hi <= lim.v_max_mps + _TOL)
    )


def feasible_horizon(
    v0: float,
    dist_m: float,
    lim: MotionLimits,
    vf: float | None = None,
    t_max_s: float = 300.0,
    n_grid: int = 600,
) -> tuple[float, float] | None:
    """Shortest and longest horizon T [s] whose unconstrained solution respects the limits.

    Grid search on T (geometric grid up to ``t_max_s``) for the first feasible run, edges refined
    by bisection; ``None`` if no horizon up to ``t_max_s`` is feasible.  If the run reaches
    ``t_max_s`` the returned upper end is ``t_max_s`` (the true window may be longer).
    """
    grid = np.geomspace(1e-2, t_max_s, n_grid)
    ok = _within_limits(v0, *_closed_form_ab(v0, grid, dist_m, vf), grid, lim)
    if not ok.any():
        return None
    i0 = int(np.argmax(ok))
    i1 = i0 + int(np.argmin(ok[i0:])) - 1 if not ok[i0:].all() else n_grid - 1

    def check(t: float) -> bool:
        ts = np.array([t])
        return bool(_within_limits(v0, *_closed_form_ab(v0, ts, dist_m, vf), ts, lim)[0])

    lo = grid[i0] if i0 == 0 else _bisect(check, grid[i0 - 1], grid[i0], want_first=True)
    hi = grid[i1] if i1 == n_grid - 1 else _bisect(check, grid[i1], grid[i1 + 1], want_first=False)
    return float(lo), float(hi)


def _bisect(
    check: Callable[[float], bool], lo: float, hi: float, want_first: bool, n_iter: int = 50
) -> float:
    """Boundary between infeasible and feasible horizons in [lo, hi].

    want_first: lo is infeasible, hi feasible -> the first feasible T; else the last feasible T.
    """
    for _ in range(n_iter):
        mid = 0.5 * (lo + hi)
        if check(mid) == want_first:
            hi = mid
        else:
            lo = mid
    return hi if want_first else lo


@dataclass(frozen=True)
class Trajectory:
    """A planned cubic on [t0, tf]; after tf it continues at the terminal speed (u = 0)."""

    t0_s: float
    tf_s: float
    coef: np.ndarray  # (a, b, c, d) in τ = t - t0
    limits: MotionLimits
    feasible: bool
    earliest_s: float  # [s] earliest crossing time with a limit-respecting solution (nan: none)
    latest_s: float  # [s] latest one (nan: none)

    def _tau(self, t_s: float | np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(t_s, dtype=float) - self.t0_s, 0.0, self.tf_s - self.t0_s)

    def accel_unconstrained(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """u(t) = aτ + b of the unconstrained optimum [m/s²] (0 after tf)."""
        a, b, _, _ = self.coef
        u = a * self._tau(t_s) + b
        return np.where(np.asarray(t_s) > self.tf_s, 0.0, u)[()]

    def accel(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """Commanded acceleration [m/s²]: the optimum saturated to the acceleration limits."""
        return np.clip(self.accel_unconstrained(t_s), self.limits.a_min_mps2, self.limits.a_max_mps2)[()]

    def vel(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """Planned speed [m/s] (constant after tf)."""
        a, b, c, _ = self.coef
        tau = self._tau(t_s)
        return (a * tau**2 / 2.0 + b * tau + c)[()]

    def pos(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """Planned position [m] (extended linearly after tf)."""
        a, b, c, d = self.coef
        tau = self._tau(t_s)
        x = a * tau**3 / 6.0 + b * tau**2 / 2.0 + c * tau + d
        extra = np.maximum(np.asarray(t_s, dtype=float) - self.tf_s, 0.0)
        return (x + self.vel(self.tf_s) * extra)[()]

    def energy(self) -> float:
        """∫_{t0}^{tf} ½ u² dt of the unconstrained optimum [m²/s³], closed form."""
        a, b, _, _ = self.coef
        t = self.tf_s - self.t0_s
        return 0.5 * (a**2 * t**3 / 3.0 + a * b * t**2 + b**2 * t)


def plan(
    x0: float,
    v0: float,
    t0: float,
    tf: float,
    L: float,  # noqa: N803 — the paper's name of the merge-point position
    vf: float | None = None,
    limits: MotionLimits | None = None,
) -> Trajectory:
    """Energy-optimal trajectory from (x0, v0) at t0 to position L at tf (terminal speed vf or free)."""
    if tf <= t0:
        raise ValueError(f"tf ({tf}) must be after t0 ({t0})")
    lim = limits or MotionLimits()
    horizon = tf - t0
    coef = cubic_coefficients(x0, v0, horizon, L - x0, vf)
    a_b = (np.array([coef[0]]), np.array([coef[1]]))
    feasible = bool(_within_limits(v0, *a_b, np.array([horizon]), lim)[0])
    window = feasible_horizon(v0, L - x0, lim, vf, t_max_s=max(300.0, 2.0 * horizon))
    earliest, latest = (t0 + window[0], t0 + window[1]) if window else (np.nan, np.nan)
    return Trajectory(t0, tf, coef, lim, feasible, earliest, latest)


def merge_accel(
    x0: float,
    v0: float,
    t0: float,
    tf: float,
    L: float,
    vf: float | None = None,  # noqa: N803
    limits: MotionLimits | None = None,
    min_horizon_s: float = 0.3,
) -> float:
    """Receding-horizon command: re-plan from the measured state and apply u(t0).

    Within ``min_horizon_s`` of the crossing (or past the merge point) the cubic degenerates, so the
    command is then a proportional speed hold towards ``vf`` (or the current speed when free).

    A fixed terminal speed is capped at ``2·d/T − v0``, the speed a uniform acceleration over the
    remaining distance ``d`` and time ``T`` ends with: a higher ``vf`` makes the cubic slow down first
    (below zero speed when the vehicle is close and slow — it would then never start) only to speed
    up again.
    """
    lim = limits or MotionLimits()
    if tf - t0 < min_horizon_s or x0 >= L:
        target = v0 if vf is None else vf
        return float(min(max((target - v0) / max(min_horizon_s, 1e-3), lim.a_min_mps2), lim.a_max_mps2))  # np.clip
    if vf is not None:
        vf = min(vf, max(2.0 * (L - x0) / (tf - t0) - v0, 0.0))
    b = start_accel(v0, tf - t0, L - x0, vf)
    return float(min(max(b, lim.a_min_mps2), lim.a_max_mps2))  # np.clip's value, without its ~5 us


def start_accel(v0: float, horizon_s: float, dist_m: float, vf: float | None) -> float:
    """u(0) = b of ``cubic_coefficients(x0, v0, horizon_s, dist_m, vf)`` (the same bits) in Python floats
    but for T³: numpy's ``T ** 3`` (on an array) is not ``math.pow``'s nor ``T * T * T``'s bits; T² is
    numpy's ``square``, which is T * T."""
    t = horizon_s
    t3 = float(np.asarray(t, dtype=float) ** 3)
    dx = dist_m - v0 * t  # distance beyond coasting
    if vf is None:
        return -(-3.0 * dx / t3) * t
    a = (6.0 * (vf - v0) * t - 12.0 * dx) / t3
    return (vf - v0 - a * (t * t) / 2.0) / t


def min_time_to_go(dist_m: float, v0: float, lim: MotionLimits) -> float:
    """Shortest time [s] to cover ``dist_m`` from speed v0 under the limits (full throttle, then v_max).

    The physical lower bound of the crossing time, e.g. for ``ZoneVehicle.earliest_arrival_s``.
    """
    return time_to_go(dist_m, v0, lim.v_max_mps, lim.a_max_mps2)


def time_to_go(dist_m: float, v0: float, v_max: float, a_max: float) -> float:
    """Time [s] to cover ``dist_m`` from v0 accelerating at ``a_max`` up to ``v_max``, then cruising."""
    if dist_m <= 0:
        return 0.0
    v0 = min(v0, v_max)
    t_acc = (v_max - v0) / a_max
    d_acc = v0 * t_acc + 0.5 * a_max * t_acc**2
    if d_acc >= dist_m:
        return float((-v0 + math.sqrt(v0**2 + 2.0 * a_max * dist_m)) / a_max)  # IEEE sqrt: np.sqrt's bits
    return float(t_acc + (dist_m - d_acc) / v_max)
