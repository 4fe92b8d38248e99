"""Warm starts for the optimisation: the search path (constant-curvature segments) sampled at N+1
uniform times, as (N+1, 5) states x, y, θ, v, δ and the total time T [s].

- `by_runs`: a trapezoidal speed profile over each run between direction changes, standing at each
  cusp long enough to turn the wheels to the next run's first steering angle. Fast, close to what
  the optimiser ends with; it ignores the steering rate inside a run.
- `by_profile`: the stop-and-steer time parametrisation (`profile`), which meets every limit, so the
  corridors around its nodes leave time for every steering change. Slower, the robust second try.
"""

from __future__ import annotations

import numpy as np

from corridor.controllers.parking import profile
from corridor.controllers.parking import reeds_shepp as rs
from corridor.controllers.parking.geometry import VehicleGeometry
from corridor.controllers.parking.search import Segment

RUN_SPEED_MPS = 1.5  # cruise speed of the run-based warm start
RUN_ACCEL_SHARE = 0.5  # of the acceleration limit


def node_count(T: float, node_dt_s: float, lo: int, hi: int) -> int:
    n = int(np.clip(np.ceil(T / node_dt_s), lo, hi))
    return int(np.ceil(n / 10) * 10)  # fewer distinct sizes: cached NLPs are reused more


def _runs(segments: list[Segment]) -> list[list[Segment]]:
    runs: list[list[Segment]] = []
    for seg in segments:
        if runs and np.sign(runs[-1][-1].length_m) == np.sign(seg.length_m):
            runs[-1].append(seg)
        else:
            runs.append([seg])
    return runs


def by_runs(segments: list[Segment], veh: VehicleGeometry, node_dt_s: float, lo: int,
            hi: int) -> tuple[np.ndarray, float]:
    acc = RUN_ACCEL_SHARE * veh.max_accel_mps2
    plan = []  # (run or None, duration, steer while standing from, to)
    steer = 0.0
    for run in _runs(segments):
        first = float(np.arctan(run[0].kappa * veh.wheelbase_m))
        plan.append((None, abs(first - steer) / veh.max_steer_rate_rps, steer, first))
        L = sum(abs(s.length_m) for s in run)
        vp = min(RUN_SPEED_MPS, float(np.sqrt(L * acc)))
        plan.append((run, 2 * vp / acc + max(0.0, L - vp ** 2 / acc) / vp, vp, L))
        steer = float(np.arctan(run[-1].kappa * veh.wheelbase_m))
    T = float(sum(p[1] for p in plan))
    n = node_count(T, node_dt_s, lo, hi)
    t = np.linspace(0.0, T, n + 1)
    out = np.zeros((n + 1, 5))
    out[:, :3] = segments[0].start
    t0, pose = 0.0, np.asarray(segments[0].start, float)
    for run, dur, a0, a1 in plan:
        m = (t >= t0 - 1e-12) & (t <= t0 + dur + 1e-12)
        tau = np.clip(t[m] - t0, 0.0, dur)
        if run is None:
            out[m, :3] = pose
            out[m, 3] = 0.0
            out[m, 4] = a0 + (a1 - a0) * tau / dur if dur > 0 else a1
        else:
            vp, L, r = a0, a1, a0 / acc
            s = np.where(tau < r, 0.5 * acc * tau ** 2,
                         np.where(tau > dur - r, L - 0.5 * acc * (dur - tau) ** 2, 0.5 * acc * r ** 2 + vp * (tau - r)))
            v = np.where(tau < r, acc * tau, np.where(tau > dur - r, acc * (dur - tau), vp))
            out[m] = _along(run, s, np.sign(run[0].length_m) * v, veh)
            pose = np.asarray(run[-1].end, float)
        t0 += dur
    out[0, 3:] = 0.0
    out[-1, 3] = 0.0
    out[-1, :3] = segments[-1].end
    return out, T


def by_profile(segments: list[Segment], veh: VehicleGeometry, node_dt_s: float, lo: int,
               hi: int) -> tuple[np.ndarray, float]:
    phases = profile.phases(segments, veh)
    T = phases[-1].t0_s + phases[-1].duration_s
    n = node_count(T, node_dt_s, lo, hi)
    st = profile.sample(phases, segments[0].start, veh, T / n)
    out = np.column_stack([st["x"], st["y"], st["theta"], st["v"], st["steer"]])
    return out[:n + 1], T


def _along(run: list[Segment], s: np.ndarray, v: np.ndarray, veh: VehicleGeometry) -> np.ndarray:
    """States at distances s along one run of same-direction segments."""
    ends = np.cumsum([abs(seg.length_m) for seg in run])
    idx = np.clip(np.searchsorted(ends, s, side="left"), 0, len(run) - 1)
    out = np.zeros((len(s), 5))
    for i, seg in enumerate(run):
        m = idx == i
        if m.any():
            local = s[m] - (ends[i] - abs(seg.length_m))
            out[m, :3] = rs.arc(*seg.start, np.sign(seg.length_m) * local, seg.kappa)
            out[m, 4] = np.arctan(seg.kappa * veh.wheelbase_m)
    out[:, 3] = v
    return out
