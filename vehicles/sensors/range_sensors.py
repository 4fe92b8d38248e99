"""Side-looking range sensors (ultrasonic / short-range radar) on a car: beam geometry and errors.

Each sensor sits on one side of the car (``side`` +1 left, -1 right) at ``x_m`` ahead of the rear axle
and looks perpendicular to the heading.  Its beam is a cone of half-angle ``half_angle_rad`` sampled by
``rays`` rays; the first echo is the nearest intersection of any ray with an obstacle edge within
``max_range_m`` (an ultrasonic sensor reports the nearest echo in its cone).  Errors, each drawn from
the caller's generator:

* range noise: Gaussian, ``noise_m`` (1-sigma) on every echo;
* dropouts: with probability ``dropout`` an echo is lost (reported as no return, ``nan``);
* spurious returns: with probability ``spurious`` a sensor reports a range uniform in
  ``[0.2, max_range_m]`` whatever is there (ghost echoes, cross-talk).

``scan`` is vectorised over sensors x rays x obstacle edges (one numpy pass per scan).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class RangeSensorParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    x_m: tuple[float, ...] = (0.0, 2.5, 5.0)  # [m] mounting positions ahead of the rear axle
    sides: tuple[int, ...] = (1, -1)  # +1 left, -1 right (every x_m on every side)
    lateral_m: float = Field(1.0, ge=0.0)  # [m] mounting offset from the centre line (half width)
    half_angle_rad: float = Field(0.12, ge=0.0, le=0.8)  # [rad] beam half-angle
    rays: int = Field(5, ge=1, le=31)  # rays sampling the cone
    max_range_m: float = Field(6.0, gt=0.0)  # [m]
    noise_m: float = Field(0.03, ge=0.0)  # [m] 1-sigma range noise
    dropout: float = Field(0.0, ge=0.0, le=1.0)  # probability of a lost echo
    spurious: float = Field(0.0, ge=0.0, le=1.0)  # probability of a ghost echo


@dataclass(frozen=True)
class Scan:
    """One scan: per sensor the origin (x, y) [m], beam axis unit vector, side and range [m] (nan: no echo)."""

    origin: np.ndarray  # (n, 2)
    axis: np.ndarray  # (n, 2)
    side: np.ndarray  # (n,)
    range_m: np.ndarray  # (n,)
    max_range_m: float

    @property
    def hits(self) -> np.ndarray:
        """(k, 2) echo points of the sensors that returned one."""
        ok = np.isfinite(self.range_m)
        return self.origin[ok] + self.range_m[ok, None] * self.axis[ok]


def sensor_layout(p: RangeSensorParams, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origins (n, 2), beam axes (n, 2) and sides (n,) of the sensors for the rear-axle ``pose``."""
    x, y, th = pose[:3]
    fwd = np.array([math.cos(th), math.sin(th)])
    left = np.array([-fwd[1], fwd[0]])
    xs, sides = np.meshgrid(np.asarray(p.x_m, dtype=float), np.asarray(p.sides, dtype=float))
    xs, sides = xs.ravel(), sides.ravel()
    origin = np.array([x, y]) + xs[:, None] * fwd + (sides * p.lateral_m)[:, None] * left
    return origin, sides[:, None] * left, sides


def ray_cast(origin: np.ndarray, direction: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray) -> np.ndarray:
    """Distance along each ray (R, 2 origins, R, 2 unit directions) to the nearest segment (E, 2 ends);
    inf where a ray hits nothing."""
    if len(seg_a) == 0:
        return np.full(len(origin), np.inf)
    e = seg_b - seg_a  # (E, 2)
    w = seg_a[None, :, :] - origin[:, None, :]  # (R, E, 2)
    den = direction[:, None, 0] * e[None, :, 1] - direction[:, None, 1] * e[None, :, 0]  # (R, E)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        s = (w[..., 0] * direction[:, None, 1] - w[..., 1] * direction[:, None, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t >= 0.0) & (s >= 0.0) & (s <= 1.0)
    return np.where(ok, t, np.inf).min(axis=1)


def scan(p: RangeSensorParams, pose: np.ndarray, polygons: np.ndarray, rng: np.random.Generator | None) -> Scan:
    """One scan of every sensor against the obstacle ``polygons`` (m, k, 2); ``rng`` None: no errors."""
    origin, axis, side = sensor_layout(p, pose)
    n = len(origin)
    offsets = np.linspace(-p.half_angle_rad, p.half_angle_rad, p.rays) if p.rays > 1 else np.zeros(1)
    ang = np.arctan2(axis[:, 1], axis[:, 0])[:, None] + offsets[None, :]  # (n, rays)
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=-1).reshape(-1, 2)
    starts = np.repeat(origin, len(offsets), axis=0)
    polys = np.asarray(polygons, dtype=float).reshape(-1, np.shape(polygons)[1] if len(polygons) else 1, 2)
    seg_a = polys.reshape(-1, 2)
    seg_b = np.roll(polys, -1, axis=1).reshape(-1, 2)
    dist = ray_cast(starts, dirs, seg_a, seg_b).reshape(n, len(offsets))
    # the echo of a cone: nearest hit; as a range along the beam axis (ultrasonic time of flight)
    r = dist.min(axis=1)
    r = np.where(r <= p.max_range_m, r, np.nan)
    if rng is not None:
        r = r + rng.normal(0.0, p.noise_m, n) if p.noise_m > 0 else r
        drop = rng.random(n) < p.dropout
        ghost = rng.random(n) < p.spurious
        ghost_r = rng.uniform(0.2, p.max_range_m, n)
        r = np.where(drop, np.nan, r)
        r = np.where(ghost, ghost_r, r)
    return Scan(origin, axis, side, r, p.max_range_m)
