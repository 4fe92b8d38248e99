"""Path following of a planned parking trajectory: rear-wheel feedback steering and a speed profile.

Why this and not an MPC: at parking speeds (<= 2.5 m/s) the kinematic bicycle *is* the vehicle (it is
highway-env's model and corridor's ego model), the plan is already dynamically feasible (the
optimiser's bicycle, limits and clearances), and what is left is rejecting small deviations.  The
rear-wheel feedback law of Samson (1993) does that with a Lyapunov function ``V = k_e e^2 / 2 +
e_th^2 / 2`` whose derivative is ``-k_th |v| e_th^2 <= 0`` *for either sign of v*, so one law follows
forward and reverse segments; it costs microseconds per step (an MPC re-solve every 0.1 s on a
loaded 2-core machine does not), and it never fails to return a command.

The plan is split into segments of one direction (cusps where the planned speed changes sign).
Per step, on the current segment: the nearest path point, lateral error ``e`` (left of the path
tangent, the tangent along the vehicle's heading), heading error ``e_th``, and the signed distance
left to the segment's end.  Curvature command (speed independent, so it is defined at standstill)::

    kappa_cmd = kappa cos(e_th) / (1 - kappa e) - k_e e sin(e_th)/e_th - k_th d e_th,   d = +-1

and ``steer = atan(L kappa_cmd)``.  Speed: ``min(cruise, sqrt(2 a_brake s_left), sqrt(a_lat / |kappa|),
slow-down near obstacles)`` towards the segment's end (overshoot gives a negative ``s_left``: the
car backs up to it), tracked with a proportional acceleration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TrackingParams:
    wheelbase_m: float = 2.8  # [m]
    max_steer_rad: float = 0.75  # [rad]
    max_accel_mps2: float = 1.5  # [m/s^2] command limit (both signs)
    cruise_mps: float = 2.0  # [m/s]
    brake_mps2: float = 0.8  # [m/s^2] planned deceleration towards a segment's end (stop point)
    lat_accel_mps2: float = 0.8  # [m/s^2] curvature speed limit v <= sqrt(a_lat / |kappa|)
    min_speed_mps: float = 0.3  # [m/s] floor of the curvature and clearance limits (keeps moving)
    slow_clearance_m: float = 1.5  # [m] below this clearance the speed limit drops linearly ...
    stop_clearance_m: float = 0.15  # [m] ... to zero at this clearance
    k_e: float = 0.6  # [1/m^2] lateral-error gain
    k_th: float = 1.5  # [1/m] heading-error gain
    k_v: float = 2.5  # [1/s] speed-error gain
    end_tol_m: float = 0.08  # [m] a segment is done within this distance of its end ...
    stop_mps: float = 0.12  # [m/s] ... at a standstill below this speed


@dataclass(frozen=True)
class Segment:
    """One direction of travel: rear-axle poses, arc length from its start, curvature, direction."""

    xy: np.ndarray  # (n, 2) [m]
    theta: np.ndarray  # (n,) [rad]
    s: np.ndarray  # (n,) [m]
    kappa: np.ndarray  # (n,) [1/m]
    direction: int  # +1 forward, -1 reverse

    @property
    def length_m(self) -> float:
        return float(self.s[-1])


def wrap(a: float | np.ndarray) -> float | np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def split_segments(x: np.ndarray, y: np.ndarray, theta: np.ndarray, v: np.ndarray, steer: np.ndarray,
                   wheelbase_m: float, min_len_m: float = 0.05) -> list[Segment]:
    """Cut a trajectory at its cusps (sign changes of the motion along the heading; standstill steps
    take the direction before them).  Runs shorter than ``min_len_m`` are dropped (an optimiser's
    shuffle while it turns the wheels standing) and the runs of one direction around them joined."""
    xy = np.column_stack([x, y])
    step = np.diff(xy, axis=0)
    heading = np.column_stack([np.cos(theta[:-1]), np.sin(theta[:-1])])
    moved = np.einsum("ij,ij->i", step, heading)  # signed travel per step along the heading
    sign = np.where(np.abs(moved) > 1e-6, np.sign(moved), 0.0)
    if not np.any(sign):
        sign = np.sign(v[:-1])
    for k in range(len(sign)):  # standstill steps inherit the previous direction
        if sign[k] == 0:
            sign[k] = sign[k - 1] if k else 0
    first = sign[np.flatnonzero(sign)[0]] if np.any(sign) else 1.0
    sign[sign == 0] = first
    kappa = np.tan(steer) / wheelbase_m
    runs: list[tuple[int, int, int]] = []  # (direction, first index, last index)
    start = 0
    for k in range(1, len(sign) + 1):
        if k == len(sign) or sign[k] != sign[start]:
            runs.append((int(sign[start]), start, k))
            start = k
    ds_all = np.concatenate([[0.0], np.cumsum(np.hypot(*step.T))])
    runs = [r for r in runs if ds_all[r[2]] - ds_all[r[1]] >= min_len_m]  # a shuffle is no manoeuvre
    merged: list[tuple[int, int, int]] = []
    for r in runs:  # neighbours of one direction (a dropped shuffle between them) become one segment
        if merged and merged[-1][0] == r[0]:
            merged[-1] = (r[0], merged[-1][1], r[2])
        else:
            merged.append(r)
    segs: list[Segment] = []
    for direction, a, b in merged:
        idx = np.arange(a, b + 1)
        ds = np.hypot(*np.diff(xy[idx], axis=0).T)
        segs.append(Segment(xy[idx], theta[idx], np.concatenate([[0.0], np.cumsum(ds)]), kappa[idx], direction))
    return segs


@dataclass(frozen=True)
class TrackState:
    index: int  # nearest path point
    e_lat_m: float  # [m] left of the path tangent
    e_heading_rad: float  # [rad]
    s_left_m: float  # [m] signed distance to the segment's end along the direction of travel
    kappa: float  # [1/m] path curvature at the nearest point


def track_errors(seg: Segment, pose: np.ndarray, hint: int = 0, window: int = 60) -> TrackState:
    """Errors of the rear-axle ``pose`` (x, y, theta) relative to ``seg`` (nearest point searched
    from ``hint`` forward in a window, so a path that crosses itself is not confused)."""
    lo = max(0, hint - 5)
    hi = min(len(seg.s), hint + window)
    d = np.hypot(seg.xy[lo:hi, 0] - pose[0], seg.xy[lo:hi, 1] - pose[1])
    k = lo + int(np.argmin(d))
    th = float(seg.theta[k])
    t = np.array([math.cos(th), math.sin(th)])
    rel = pose[:2] - seg.xy[k]
    e = float(-rel[0] * t[1] + rel[1] * t[0])
    along = float(rel @ t) * seg.direction  # ahead of point k in the direction of travel
    end = seg.xy[-1] - pose[:2]
    t_end = np.array([math.cos(seg.theta[-1]), math.sin(seg.theta[-1])]) * seg.direction
    if k >= len(seg.s) - 2:
        s_left = float(end @ t_end)
    else:
        s_left = float(seg.s[-1] - seg.s[k] - along)
    return TrackState(k, e, float(wrap(pose[2] - th)), s_left, float(seg.kappa[k]))


def steer_command(seg: Segment, st: TrackState, p: TrackingParams) -> float:
    """Rear-wheel feedback curvature -> steering angle [rad] (saturated)."""
    eth = st.e_heading_rad
    sinc = math.sin(eth) / eth if abs(eth) > 1e-6 else 1.0
    denom = max(1.0 - st.kappa * st.e_lat_m, 0.2)
    kap = st.kappa * math.cos(eth) / denom - p.k_e * st.e_lat_m * sinc - p.k_th * seg.direction * eth
    return float(np.clip(math.atan(p.wheelbase_m * kap), -p.max_steer_rad, p.max_steer_rad))


def speed_limit(st: TrackState, clearance_m: float, p: TrackingParams) -> float:
    """Speed limit [m/s] (>= 0): cruise, stop at the segment's end, curvature, clearance."""
    v_end = math.sqrt(2.0 * p.brake_mps2 * abs(st.s_left_m))
    v_curv = max(math.sqrt(p.lat_accel_mps2 / max(abs(st.kappa), 1e-6)), p.min_speed_mps)
    span = p.slow_clearance_m - p.stop_clearance_m
    frac = np.clip((clearance_m - p.stop_clearance_m) / span, 0.0, 1.0)
    v_clear = p.cruise_mps * frac if frac >= 1.0 else max(p.cruise_mps * frac, p.min_speed_mps * (frac > 0))
    return float(min(p.cruise_mps, v_end, v_curv, v_clear))


def speed_command(seg: Segment, st: TrackState, v_mps: float, clearance_m: float, p: TrackingParams) -> float:
    """Acceleration [m/s^2] towards the signed speed limit (backs up after an overshoot).  While the
    stopping profile ``sqrt(2 a_brake s_left)`` is the binding limit, its own deceleration is fed
    forward (a proportional loop alone lags it by ``a_brake / k_v`` and overshoots the stop point)."""
    direction = seg.direction if st.s_left_m >= 0.0 else -seg.direction
    limit = speed_limit(st, clearance_m, p)
    v_ref = direction * limit
    braking = limit >= math.sqrt(2.0 * p.brake_mps2 * abs(st.s_left_m)) - 1e-9 and direction * v_mps > 0.0
    a_ff = -direction * p.brake_mps2 if braking and abs(st.s_left_m) > p.end_tol_m else 0.0
    return float(np.clip(a_ff + p.k_v * (v_ref - v_mps), -p.max_accel_mps2, p.max_accel_mps2))


def segment_done(st: TrackState, v_mps: float, p: TrackingParams) -> bool:
    return abs(st.s_left_m) <= p.end_tol_m and abs(v_mps) <= p.stop_mps
