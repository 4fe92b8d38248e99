"""Time parametrisation of a path of constant-curvature segments that meets every limit exactly.

The car stops wherever the curvature or the direction changes and turns its wheels at the maximum
steering rate while standing; along each segment the speed follows a trapezoid (or triangle) within
the speed and acceleration limits. Slow, but feasible by construction: the planner's fallback when
the optimisation fails, and a reference for how much the optimisation gains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from corridor.controllers.parking import reeds_shepp as rs
from corridor.controllers.parking.geometry import VehicleGeometry
from corridor.controllers.parking.search import Segment


@dataclass(frozen=True)
class Phase:
    t0_s: float
    duration_s: float
    segment: Segment | None  # None: standing, turning the wheels
    steer0_rad: float
    steer1_rad: float
    v_peak_mps: float = 0.0  # for moving phases
    ramp_s: float = 0.0  # acceleration (= deceleration) time


def _move_phase(t0: float, seg: Segment, steer: float, veh: VehicleGeometry) -> Phase:
    L, a, vmax = abs(seg.length_m), veh.max_accel_mps2, veh.max_speed_mps
    if L <= vmax ** 2 / a:  # triangle
        vp = float(np.sqrt(L * a))
        ramp, dur = vp / a, 2 * vp / a
    else:
        vp, ramp = vmax, vmax / a
        dur = 2 * ramp + (L - vmax ** 2 / a) / vmax
    return Phase(t0, dur, seg, steer, steer, vp, ramp)


def phases(segments: list[Segment], veh: VehicleGeometry, steer0_rad: float = 0.0) -> list[Phase]:
    out: list[Phase] = []
    t, steer = 0.0, steer0_rad
    for seg in segments:
        target = float(np.arctan(seg.kappa * veh.wheelbase_m))
        if abs(target - steer) > 1e-12:
            dur = abs(target - steer) / veh.max_steer_rate_rps
            out.append(Phase(t, dur, None, steer, target))
            t += dur
            steer = target
        ph = _move_phase(t, seg, steer, veh)
        out.append(ph)
        t += ph.duration_s
    return out


def _distance(ph: Phase, tau: np.ndarray, accel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance travelled, speed and acceleration magnitude-signed at local times tau of a move."""
    T, r, vp = ph.duration_s, ph.ramp_s, ph.v_peak_mps
    up, down = tau < r, tau > T - r
    s = np.where(up, 0.5 * accel * tau ** 2,
                 np.where(down, abs(ph.segment.length_m) - 0.5 * accel * (T - tau) ** 2,
                          0.5 * accel * r ** 2 + vp * (tau - r)))
    v = np.where(up, accel * tau, np.where(down, accel * (T - tau), vp))
    a = np.where(up, accel, np.where(down, -accel, 0.0))
    return s, v, a


def sample(phase_list: list[Phase], start: tuple[float, float, float], veh: VehicleGeometry,
           dt_s: float) -> dict[str, np.ndarray]:
    """States t, x, y, theta, v, a, steer every ≤ ``dt_s`` from the start to the end of the last phase."""
    total = phase_list[-1].t0_s + phase_list[-1].duration_s if phase_list else 0.0
    n = max(1, int(np.ceil(total / dt_s - 1e-9)))
    t = np.linspace(0.0, total, n + 1)
    out = {k: np.zeros_like(t) for k in ("x", "y", "theta", "v", "a", "steer")}
    out["x"][:], out["y"][:], out["theta"][:] = start
    starts = np.array([ph.t0_s for ph in phase_list])
    idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(phase_list) - 1)
    for i, ph in enumerate(phase_list):
        m = idx == i
        if not m.any():
            continue
        tau = np.clip(t[m] - ph.t0_s, 0.0, ph.duration_s)
        if ph.segment is None:
            pose = _pose_before(phase_list, i, start)
            out["x"][m], out["y"][m], out["theta"][m] = pose
            out["steer"][m] = ph.steer0_rad + (ph.steer1_rad - ph.steer0_rad) * tau / ph.duration_s
            continue
        seg = ph.segment
        sgn = np.sign(seg.length_m)
        s, v, a = _distance(ph, tau, veh.max_accel_mps2)
        pose = rs.arc(*seg.start, sgn * s, seg.kappa)
        out["x"][m], out["y"][m], out["theta"][m] = pose[:, 0], pose[:, 1], pose[:, 2]
        out["v"][m], out["a"][m], out["steer"][m] = sgn * v, sgn * a, ph.steer0_rad
    return {"t": t, **out}


def _pose_before(phase_list: list[Phase], i: int, start: tuple[float, float, float]) -> tuple[float, ...]:
    for ph in reversed(phase_list[:i]):
        if ph.segment is not None:
            return ph.segment.end
    return start
