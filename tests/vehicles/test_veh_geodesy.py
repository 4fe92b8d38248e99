"""Geodetic <-> ENU conversions: round trips, closed forms and angle conventions."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.vehicles.geodesy import (
    Origin,
    enu_yaw_from_heading,
    ft_to_m,
    heading_from_enu_yaw,
    m_to_ft,
    ned_to_enu,
    wrap_pi,
)

ORIGIN = Origin(47.3769, 8.5417, 408.0)


def test_origin_is_zero_and_round_trip_is_exact_vectorised() -> None:
    assert np.allclose(ORIGIN.to_enu(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.h_m), 0.0, atol=1e-6)
    rng = np.random.default_rng(1)
    enu = rng.uniform([-5000, -5000, 0], [5000, 5000, 3000], size=(200, 3))
    lat, lon, h = ORIGIN.to_geodetic(enu)
    assert lat.shape == (200,)
    back = ORIGIN.to_enu(lat, lon, h)
    assert back.shape == (200, 3)
    assert np.abs(back - enu).max() < 1e-6


def test_north_offset_matches_meridian_radius() -> None:
    """1 km north moves latitude by 1000 / M(lat) rad, M the WGS-84 meridional radius of curvature."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    phi = np.radians(ORIGIN.lat_deg)
    m_radius = a * (1 - e2) / (1 - e2 * np.sin(phi) ** 2) ** 1.5
    lat, lon, h = ORIGIN.to_geodetic(np.array([0.0, 1000.0, 0.0]))
    assert np.degrees(1000.0 / m_radius) == pytest.approx(float(lat) - ORIGIN.lat_deg, rel=1e-4)
    assert float(lon) == pytest.approx(ORIGIN.lon_deg, abs=1e-12)
    # the tangent plane drops below the curved ellipsoid: h - h0 = d^2 / (2 R) ~ 7.8 cm at 1 km
    assert float(h) - ORIGIN.h_m == pytest.approx(1000.0**2 / (2 * 6.37e6), rel=0.02)


def test_heading_yaw_conventions() -> None:
    # compass north = ENU +y = yaw pi/2; compass east = yaw 0; compass 270 (west) = yaw pi
    assert enu_yaw_from_heading(0.0) == pytest.approx(np.pi / 2)
    assert enu_yaw_from_heading(np.pi / 2) == pytest.approx(0.0)
    assert abs(enu_yaw_from_heading(1.5 * np.pi)) == pytest.approx(np.pi)
    psi = np.linspace(0, 2 * np.pi, 37, endpoint=False)
    assert np.allclose(heading_from_enu_yaw(enu_yaw_from_heading(psi)), psi)
    assert np.allclose(wrap_pi(np.array([3 * np.pi, -3 * np.pi + 0.1])), [np.pi, -np.pi + 0.1])


def test_units_and_ned() -> None:
    assert ft_to_m(1000.0) == pytest.approx(304.8)
    assert m_to_ft(ft_to_m(123.4)) == pytest.approx(123.4)
    assert np.allclose(ned_to_enu(np.array([1.0, 2.0, 3.0])), [2.0, 1.0, -3.0])
    assert np.allclose(ned_to_enu(ned_to_enu(np.eye(3))), np.eye(3))


def test_fast_to_enu_is_bit_identical_to_pymap3d() -> None:
    """Origin.to_enu caches the origin's ECEF point and trigonometry but keeps pymap3d's formulas
    operation for operation, so the flight layer's numbers do not change (scalars and arrays)."""
    import pymap3d

    rng = np.random.default_rng(7)
    lat = ORIGIN.lat_deg + rng.normal(0.0, 0.05, 500)
    lon = ORIGIN.lon_deg + rng.normal(0.0, 0.05, 500)
    h = ORIGIN.h_m + rng.uniform(-50.0, 3000.0, 500)
    ref = np.stack(pymap3d.geodetic2enu(lat, lon, h, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.h_m), axis=-1)
    assert np.array_equal(ORIGIN.to_enu(lat, lon, h), ref)
    one = ORIGIN.to_enu(float(lat[0]), float(lon[0]), float(h[0]))
    assert one.shape == (3,) and np.array_equal(one, ref[0])
