"""A downward camera on a UAV that counts road vehicles: footprint, detection, per-segment estimates.

Pure numpy (no engine code).  The camera looks along the body's down axis; its footprint is the
ground inside the cone of half-angle ``fov_deg / 2`` around that axis, so it follows the UAV's
altitude and attitude (a quad pitched forward to accelerate looks behind its nadir point).  A
vehicle in the footprint is detected with probability

    p = p_max * cos(off_nadir) ** off_nadir_exp * 0.5 ** (slant_range / half_range_m)

(falling with range and with the angle from the vertical); a detection carries a position with
Gaussian noise ``pos_sigma_m`` per axis and a speed with noise ``speed_sigma_mps``.

Per road segment the camera reports what it saw of it: the observed length ``L`` (carriageway arc
points inside the footprint), the Horvitz-Thompson count ``N = sum_j 1 / p_j`` of the detections
whose measured position falls on the segment, the density ``N / (L lanes)`` [veh/km/lane] with
variance ``(sum_j (1 - p_j) / p_j^2 + N + 1) / (L lanes)^2`` (detection misses, plus the Poisson
variance of how many vehicles a stretch of length L holds; the +1 keeps an empty stretch from
claiming certainty), and the space-mean speed (mean of the measured speeds) with variance
``(sample variance + speed_sigma^2) / n``.  With ``p_max = 1``, no fall-off and no noise the count is
exact, so the density equals the ground truth of the observed stretch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class CameraParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    fov_deg: float = Field(100.0, gt=0.0, lt=170.0)  # [deg] full cone angle
    p_max: float = Field(0.95, gt=0.0, le=1.0)  # detection probability at nadir, short range
    off_nadir_exp: float = Field(1.0, ge=0.0)  # exponent of cos(off-nadir)
    half_range_m: float | None = Field(400.0, gt=0.0)  # [m] slant range halving p (None: no fall-off)
    pos_sigma_m: float = Field(2.0, ge=0.0)  # [m] per horizontal axis
    speed_sigma_mps: float = Field(1.0, ge=0.0)  # [m/s]
    min_observed_m: float = Field(50.0, ge=0.0)  # [m] report a segment only if this much of it is seen


def optical_axis(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """World (ENU) direction of the body's down axis for JSBSim's roll (right wing down +) and pitch
    (nose up +) and the ENU yaw (CCW from east)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(-pitch_rad), np.sin(-pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    down = np.array([0.0, 0.0, -1.0])
    v = np.array([down[0], cr * down[1] - sr * down[2], sr * down[1] + cr * down[2]])  # R_x(roll), FLU
    v = np.array([cp * v[0] + sp * v[2], v[1], -sp * v[0] + cp * v[2]])  # R_y(-pitch)
    return np.array([cy * v[0] - sy * v[1], sy * v[0] + cy * v[1], v[2]])  # R_z(yaw)


def in_footprint(cam_pos: np.ndarray, axis: np.ndarray, ground_xy: np.ndarray, fov_deg: float,
                 ground_z: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inside [P] bool, slant range [P] m, cos(off-nadir) [P]) of ground points seen from ``cam_pos``."""
    ray = np.column_stack([ground_xy - cam_pos[:2], np.full(len(ground_xy), ground_z - cam_pos[2])])
    rng = np.linalg.norm(ray, axis=1)
    rng = np.maximum(rng, 1e-9)
    cos_axis = ray @ axis / rng
    inside = cos_axis >= np.cos(np.radians(fov_deg / 2.0))
    return inside, rng, -ray[:, 2] / rng


def detection_probability(p: CameraParams, slant_m: np.ndarray, cos_off: np.ndarray) -> np.ndarray:
    out = p.p_max * np.clip(cos_off, 0.0, 1.0) ** p.off_nadir_exp
    if p.half_range_m is not None:
        out = out * 0.5 ** (slant_m / p.half_range_m)
    return out


@dataclass(frozen=True)
class SegmentEstimate:
    """What one camera frame says about one segment."""

    segment: int
    direction: int  # 0 ccw, 1 cw
    density: float  # [veh/km/lane]
    density_var: float
    speed_mps: float  # nan: no vehicle detected
    speed_var: float
    observed_m: float  # [m]
    n_detected: int


@dataclass(frozen=True)
class Frame:
    """One camera frame: the estimates and the observed length of every segment [m]."""

    estimates: tuple[SegmentEstimate, ...]
    observed_m: np.ndarray  # [n_seg]
    footprint_xy: np.ndarray  # [2] ground point of the optical axis (nan when it misses the ground)


def observe(p: CameraParams, cam_pos: np.ndarray, axis: np.ndarray, arc_xy: np.ndarray, arc_seg: np.ndarray,
            arc_spacing_m: float, veh_xy: np.ndarray, veh_dirn: np.ndarray, veh_speed_mps: np.ndarray,
            segment_of: object, n_seg: int, n_per_dir: int, lanes: int,
            rng: np.random.Generator) -> Frame:
    """One frame: ``segment_of(xy, dirn)`` maps measured positions to segments (RingSegments)."""
    inside, _, _ = in_footprint(cam_pos, axis, arc_xy, p.fov_deg)
    observed = np.bincount(arc_seg[inside], minlength=n_seg).astype(float) * arc_spacing_m
    seen, slant, cos_off = in_footprint(cam_pos, axis, veh_xy, p.fov_deg)
    pd = detection_probability(p, slant, cos_off)
    det = seen & (rng.random(len(veh_xy)) < pd)
    xy = veh_xy[det] + rng.normal(0.0, p.pos_sigma_m, size=(int(det.sum()), 2)) if p.pos_sigma_m > 0 else veh_xy[det]
    speed = veh_speed_mps[det] + (rng.normal(0.0, p.speed_sigma_mps, int(det.sum())) if p.speed_sigma_mps > 0 else 0.0)
    w = 1.0 / pd[det]
    seg = segment_of(xy, veh_dirn[det]) if len(xy) else np.zeros(0, dtype=np.int64)  # type: ignore[operator]
    est = []
    for i in np.flatnonzero(observed >= max(p.min_observed_m, 1e-9)):
        on = seg == i
        n_ht = float(w[on].sum())
        area = observed[i] / 1000.0 * lanes  # [km lane]
        miss_var = float(np.sum((1.0 - pd[det][on]) * w[on] ** 2))
        sp = speed[on]
        n = int(on.sum())
        v_mean = float(sp.mean()) if n else float("nan")
        v_var = float((np.var(sp, ddof=1) if n > 1 else 0.0) + p.speed_sigma_mps**2) / n if n else float("nan")
        est.append(SegmentEstimate(int(i), int(i) // n_per_dir, n_ht / area, (miss_var + n_ht + 1.0) / area**2,
                                   v_mean, v_var, float(observed[i]), n))
    centre = np.full(2, np.nan)
    if axis[2] < -1e-6:
        centre = cam_pos[:2] + axis[:2] * (cam_pos[2] / -axis[2])
    return Frame(tuple(est), observed, centre)
