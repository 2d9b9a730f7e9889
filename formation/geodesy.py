"""WGS-84 geodetic <-> local tangent-plane (ENU / NED) conversions.

Pure maths, no I/O. Used by the mock autopilot (vehicle homes, GLOBAL_POSITION_INT) and by
the ground station (mission frame, readings). Exact ECEF-based conversions, not flat-earth,
so that vehicles with homes hundreds of metres apart agree to the millimetre.

Conventions
-----------
* geodetic: ``lat_deg``, ``lon_deg``, ``alt_m`` (height above the WGS-84 ellipsoid; the mock
  and the mission treat it as AMSL, which is what MAVLink's ``alt`` fields carry).
* ENU: east, north, up metres about an origin; NED: north, east, down.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "WGS84_A_M",
    "WGS84_F",
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "geodetic_to_enu",
    "enu_to_geodetic",
    "enu_to_ned",
    "ned_to_enu",
]

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)


def geodetic_to_ecef(lat_deg, lon_deg, alt_m):
    """Convert geodetic coordinates to Earth-centred Earth-fixed metres.

    Parameters
    ----------
    lat_deg, lon_deg, alt_m : float or array_like
        Geodetic latitude and longitude in degrees, height in metres.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: x, y, z in metres.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    alt = np.asarray(alt_m, dtype=float)
    sin_lat = np.sin(lat)
    n = WGS84_A_M / np.sqrt(1.0 - _E2 * sin_lat**2)
    x = (n + alt) * np.cos(lat) * np.cos(lon)
    y = (n + alt) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - _E2) + alt) * sin_lat
    return np.stack([x, y, z], axis=-1)


def ecef_to_geodetic(ecef):
    """Convert ECEF metres to geodetic ``(lat_deg, lon_deg, alt_m)`` (iterative, mm-exact).

    Parameters
    ----------
    ecef : array_like, shape (..., 3)

    Returns
    -------
    tuple of numpy.ndarray
        ``lat_deg, lon_deg, alt_m``.
    """
    ecef = np.asarray(ecef, dtype=float)
    x, y, z = ecef[..., 0], ecef[..., 1], ecef[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - _E2))
    alt = np.zeros_like(p)
    for _ in range(8):
        sin_lat = np.sin(lat)
        n = WGS84_A_M / np.sqrt(1.0 - _E2 * sin_lat**2)
        alt = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - _E2 * n / (n + alt)))
    return np.degrees(lat), np.degrees(lon), alt


def _enu_rotation(lat_deg, lon_deg):
    lat = np.radians(lat_deg)
    lon = np.radians(lon_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    # rows: east, north, up expressed in ECEF
    return np.array([
        [-so, co, 0.0],
        [-sl * co, -sl * so, cl],
        [cl * co, cl * so, sl],
    ])


def geodetic_to_enu(lat_deg, lon_deg, alt_m, origin):
    """Geodetic point(s) to ENU metres about ``origin = (lat_deg, lon_deg, alt_m)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: east_m, north_m, up_m.
    """
    o_lat, o_lon, o_alt = (float(v) for v in origin)
    d = geodetic_to_ecef(lat_deg, lon_deg, alt_m) - geodetic_to_ecef(o_lat, o_lon, o_alt)
    return d @ _enu_rotation(o_lat, o_lon).T


def enu_to_geodetic(enu, origin):
    """ENU metres about ``origin`` to geodetic ``(lat_deg, lon_deg, alt_m)``."""
    o_lat, o_lon, o_alt = (float(v) for v in origin)
    enu = np.asarray(enu, dtype=float)
    ecef = geodetic_to_ecef(o_lat, o_lon, o_alt) + enu @ _enu_rotation(o_lat, o_lon)
    return ecef_to_geodetic(ecef)


def enu_to_ned(enu):
    """Swap an ENU vector (or array of them, last axis 3) to NED."""
    enu = np.asarray(enu, dtype=float)
    return np.stack([enu[..., 1], enu[..., 0], -enu[..., 2]], axis=-1)


def ned_to_enu(ned):
    """Swap a NED vector (or array of them, last axis 3) to ENU."""
    ned = np.asarray(ned, dtype=float)
    return np.stack([ned[..., 1], ned[..., 0], -ned[..., 2]], axis=-1)
