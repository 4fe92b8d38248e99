"""Geodetic <-> local ENU conversions around a scenario origin, and unit helpers.

The world snapshot lives in one local East-North-Up frame (metres) anchored at the scenario's geodetic
``origin`` (lat0 [deg], lon0 [deg], h0 [m above the WGS-84 ellipsoid]). JSBSim works in geodetic
latitude / longitude / height in feet, so the flight layer converts at its boundary. The maths is
pymap3d's (WGS-84, exact, vectorised over numpy arrays); this module only fixes the conventions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pymap3d

FT_PER_M = 1.0 / 0.3048  # [ft/m], exact by definition of the international foot
M_PER_FT = 0.3048  # [m/ft]
KT_PER_MPS = 3600.0 / 1852.0  # [kt/(m/s)]


def ft_to_m(x_ft: float | np.ndarray) -> float | np.ndarray:
    """Feet to metres."""
    return x_ft * M_PER_FT


def m_to_ft(x_m: float | np.ndarray) -> float | np.ndarray:
    """Metres to feet."""
    return x_m * FT_PER_M


def enu_yaw_from_heading(psi_rad: float | np.ndarray) -> float | np.ndarray:
    """Compass heading (clockwise from north) -> ENU yaw (counter-clockwise from east), both [rad].

    The result is wrapped to (-pi, pi].
    """
    return wrap_pi(0.5 * np.pi - psi_rad)


def heading_from_enu_yaw(yaw_rad: float | np.ndarray) -> float | np.ndarray:
    """ENU yaw (CCW from east) -> compass heading (CW from north) in [0, 2 pi) [rad]."""
    return np.mod(0.5 * np.pi - yaw_rad, 2.0 * np.pi)


def wrap_pi(a_rad: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle to (-pi, pi] [rad]."""
    return np.pi - np.mod(np.pi - a_rad, 2.0 * np.pi)


@dataclass(frozen=True)
class Origin:
    """Geodetic anchor of the local ENU frame: latitude, longitude [deg] and ellipsoidal height [m]."""

    lat_deg: float
    lon_deg: float
    h_m: float = 0.0

    def to_enu(
        self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float, h_m: np.ndarray | float
    ) -> np.ndarray:
        """Geodetic -> ENU metres; returns shape (..., 3) (a (3,) array for scalars).

        pymap3d's ``geodetic2enu`` formulas, operation for operation (so the result is bit-identical),
        with the origin's ECEF point and trigonometry computed once: the flight layer converts the
        whole fleet at every 120 Hz sub-step, where pymap3d's per-call overhead dominated.
        """
        lat = np.radians(lat_deg)
        lon = np.radians(lon_deg)
        a, b, (x0, y0, z0), (sin_lat0, cos_lat0, sin_lon0, cos_lon0) = self._frame
        cos_lat = np.cos(lat)
        sin_lat = np.sin(lat)
        n = a**2 / np.hypot(a * cos_lat, b * sin_lat)  # prime-vertical radius of curvature
        u = (n + h_m) * cos_lat * np.cos(lon) - x0
        v = (n + h_m) * cos_lat * np.sin(lon) - y0
        w = (n * (b / a) ** 2 + h_m) * sin_lat - z0
        t = cos_lon0 * u + sin_lon0 * v
        east = -sin_lon0 * u + cos_lon0 * v
        up = cos_lat0 * t + sin_lat0 * w
        north = -sin_lat0 * t + cos_lat0 * w
        return np.stack([np.asarray(east, float), np.asarray(north, float), np.asarray(up, float)], axis=-1)

    @cached_property
    def _frame(self) -> tuple[float, float, tuple[float, float, float], tuple[float, ...]]:
        """WGS-84 axes [m], the origin in ECEF [m] and sin/cos of its latitude and longitude."""
        ell = pymap3d.Ellipsoid.from_name("wgs84")
        lat0, lon0 = np.radians(self.lat_deg), np.radians(self.lon_deg)
        ecef0 = pymap3d.geodetic2ecef(self.lat_deg, self.lon_deg, self.h_m)
        trig = (np.sin(lat0), np.cos(lat0), np.sin(lon0), np.cos(lon0))
        return ell.semimajor_axis, ell.semiminor_axis, ecef0, trig

    def to_geodetic(self, enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ENU metres (shape (..., 3)) -> (lat [deg], lon [deg], h [m]) arrays of shape (...)."""
        enu = np.asarray(enu_m, dtype=float)
        lat, lon, h = pymap3d.enu2geodetic(
            enu[..., 0], enu[..., 1], enu[..., 2], self.lat_deg, self.lon_deg, self.h_m
        )
        return np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float)


def ned_to_enu(v_ned: np.ndarray) -> np.ndarray:
    """Swap a local North-East-Down vector (..., 3) to East-North-Up (the same map is its inverse)."""
    v = np.asarray(v_ned, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


enu_to_ned = ned_to_enu


def metres_per_degree(lat_deg: np.ndarray, h_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local scale of WGS-84 geodetic coordinates at (``lat_deg``, ``h_m``): metres north per degree
    of latitude ((M + h) pi / 180, M the meridian radius of curvature) and metres east per degree of
    longitude ((N + h) cos(lat) pi / 180, N the prime-vertical radius)."""
    a, b = 6378137.0, 6356752.314245179  # [m] WGS-84 semi-axes
    e2 = 1.0 - (b / a) ** 2
    lat = np.radians(lat_deg)
    w = np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    m = a * (1.0 - e2) / w**3
    n = a / w
    rad = np.pi / 180.0
    return (m + h_m) * rad, (n + h_m) * np.cos(lat) * rad
