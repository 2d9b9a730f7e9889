"""WGS-84 geodetic <-> local tangent-plane (ENU / NED) conversions, backed by :mod:`pymap3d`.

Pure maths, no I/O. Used by the mock autopilot (vehicle homes, GLOBAL_POSITION_INT) and by
the ground station (mission frame, readings). Exact ECEF-based conversions, not flat-earth,
so that vehicles with homes hundreds of metres apart agree to the millimetre.

The ellipsoid maths is delegated to :mod:`pymap3d` (``geodetic2ecef``, ``ecef2geodetic``,
``geodetic2enu``, ``enu2geodetic``); this module only adapts its tuple-of-components interface
to the ``(..., 3)`` arrays the rest of the project passes around. Every function is vectorised
over numpy arrays (scalars in, scalars / shape-``(3,)`` arrays out).

Conventions
-----------
* geodetic: ``lat_deg``, ``lon_deg``, ``alt_m`` (height above the WGS-84 ellipsoid; the mock
  and the mission treat it as AMSL, which is what MAVLink's ``alt`` fields carry).
* ENU: east, north, up metres about an origin; NED: north, east, down.
* ``origin`` is a ``(lat_deg, lon_deg, alt_m)`` triple.
"""
from __future__ import annotations

import numpy as np
import pymap3d

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

#: WGS-84 semi-major axis (defining constant), metres. pymap3d's default ellipsoid.
WGS84_A_M = 6378137.0
#: WGS-84 flattening (defining constant ``1 / 298.257223563``).
WGS84_F = 1.0 / 298.257223563


def _origin_floats(origin) -> tuple[float, float, float]:
    """``origin`` as three plain floats ``(lat_deg, lon_deg, alt_m)``."""
    o_lat, o_lon, o_alt = (float(v) for v in origin)
    return o_lat, o_lon, o_alt


def _stack_xyz(a, b, c) -> np.ndarray:
    """Stack three numpy components (pymap3d outputs) on a new last axis.

    Scalars take a fast path (``np.stack`` costs microseconds); components of different
    shapes (e.g. ``z`` does not depend on longitude) are broadcast first.
    """
    if a.shape == b.shape == c.shape:
        return np.array((a, b, c)) if not a.shape else np.stack((a, b, c), axis=-1)
    return np.stack(np.broadcast_arrays(a, b, c), axis=-1)


def geodetic_to_ecef(lat_deg, lon_deg, alt_m):
    """Convert geodetic coordinates to Earth-centred Earth-fixed metres.

    Parameters
    ----------
    lat_deg, lon_deg, alt_m : float or array_like
        Geodetic latitude and longitude in degrees, height in metres (broadcast together).

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: x, y, z in metres.
    """
    x_m, y_m, z_m = pymap3d.geodetic2ecef(np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float),
                                          np.asarray(alt_m, dtype=float))
    return _stack_xyz(x_m, y_m, z_m)


def ecef_to_geodetic(ecef):
    """Convert ECEF metres to geodetic coordinates (closed form, sub-millimetre).

    Parameters
    ----------
    ecef : array_like, shape (..., 3)
        x, y, z in metres.

    Returns
    -------
    tuple of numpy.ndarray
        ``lat_deg, lon_deg, alt_m``, each of shape ``(...)``.
    """
    ecef = np.asarray(ecef, dtype=float)
    return pymap3d.ecef2geodetic(ecef[..., 0], ecef[..., 1], ecef[..., 2])


def geodetic_to_enu(lat_deg, lon_deg, alt_m, origin):
    """Geodetic point(s) to ENU metres about ``origin``.

    Parameters
    ----------
    lat_deg, lon_deg, alt_m : float or array_like
        The point(s), broadcast together.
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the tangent plane's origin.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: east_m, north_m, up_m.
    """
    o_lat, o_lon, o_alt = _origin_floats(origin)
    east_m, north_m, up_m = pymap3d.geodetic2enu(
        np.asarray(lat_deg, dtype=float), np.asarray(lon_deg, dtype=float), np.asarray(alt_m, dtype=float),
        o_lat, o_lon, o_alt)
    return _stack_xyz(east_m, north_m, up_m)


def enu_to_geodetic(enu, origin):
    """ENU metres about ``origin`` to geodetic coordinates.

    Parameters
    ----------
    enu : array_like, shape (..., 3)
        east_m, north_m, up_m.
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the tangent plane's origin.

    Returns
    -------
    tuple of numpy.ndarray
        ``lat_deg, lon_deg, alt_m``, each of shape ``(...)``.
    """
    o_lat, o_lon, o_alt = _origin_floats(origin)
    enu = np.asarray(enu, dtype=float)
    return pymap3d.enu2geodetic(enu[..., 0], enu[..., 1], enu[..., 2], o_lat, o_lon, o_alt)


def enu_to_ned(enu):
    """Swap an ENU vector (or array of them, last axis 3) to NED.

    Parameters
    ----------
    enu : array_like, shape (..., 3)

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: north, east, down.
    """
    enu = np.asarray(enu, dtype=float)
    return np.stack([enu[..., 1], enu[..., 0], -enu[..., 2]], axis=-1)


def ned_to_enu(ned):
    """Swap a NED vector (or array of them, last axis 3) to ENU.

    Parameters
    ----------
    ned : array_like, shape (..., 3)

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)``: east, north, up.
    """
    ned = np.asarray(ned, dtype=float)
    return np.stack([ned[..., 1], ned[..., 0], -ned[..., 2]], axis=-1)
