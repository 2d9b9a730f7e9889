"""WGS-84 geodetic <-> local tangent-plane (ENU / NED) conversions, backed by :mod:`pymap3d`.

Pure maths, no I/O, and the project's one home for geodesy: used by the mock autopilot
(vehicle homes, GLOBAL_POSITION_INT) and by the ground station (mission frame, readings). Exact ECEF-based conversions, not flat-earth,
so that vehicles with homes hundreds of metres apart agree to the millimetre.

The ellipsoid maths is delegated to :mod:`pymap3d` (``geodetic2ecef``, ``ecef2geodetic``,
``geodetic2enu``, ``enu2geodetic``); this module only adapts its tuple-of-components interface
to the ``(..., 3)`` arrays the rest of the project passes around. Every function is vectorised
over numpy arrays (scalars in, scalars / shape-``(3,)`` arrays out); :class:`TangentFrame` is
the same maths on plain floats for the per-point hot paths, bit-identical to pymap3d.

Conventions
-----------
* geodetic: ``lat_deg``, ``lon_deg``, ``alt_m`` (height above the WGS-84 ellipsoid; the mock
  and the mission treat it as AMSL, which is what MAVLink's ``alt`` fields carry).
* ENU: east, north, up metres about an origin; NED: north, east, down.
* ``origin`` is a ``(lat_deg, lon_deg, alt_m)`` triple.
"""
from __future__ import annotations

import math

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
    "TangentFrame",
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


class TangentFrame:
    """A local tangent plane at ``origin`` with scalar conversions, pymap3d's maths on plain floats.

    The ground station converts every sensor reading (N vehicles at 10-20 Hz) and the mock
    autopilot every reported position (50 Hz per vehicle) one point at a time; the array
    functions above cost 12 us (geodetic -> ENU) and 88 us (ENU -> geodetic) per scalar point,
    these methods about 1.3 us and 4 us (``python benchmarks/bench_geodesy.py``). Each method is
    ``pymap3d.geodetic2enu`` / ``pymap3d.enu2geodetic`` written out on floats with the same
    operations in the same order, so the result is bit-identical to theirs
    (``tests/formation/test_geodesy.py`` checks it on random points and on a grid): :func:`math.radians`,
    :func:`math.degrees`, :func:`math.sin`, :func:`math.cos` and :func:`math.sqrt` give numpy's
    float64 results, while ``hypot``, ``arctan``, ``arctan2`` and ``tan`` stay numpy's (with
    SIMD loops they may differ from :mod:`math`'s in the last bit). The origin's ECEF position and
    the sines and cosines of its latitude and longitude are computed once.

    Parameters
    ----------
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the plane's origin.
    """

    def __init__(self, origin):
        lat0_deg, lon0_deg, alt0_m = _origin_floats(origin)
        self.origin = (lat0_deg, lon0_deg, alt0_m)
        ell = pymap3d.Ellipsoid.from_name("wgs84")
        self._a_m, self._b_m = ell.semimajor_axis, ell.semiminor_axis
        self._a2_m2 = self._a_m ** 2
        self._ba2 = (self._b_m / self._a_m) ** 2
        self._e_m = math.sqrt(self._a_m ** 2 - self._b_m ** 2)
        lat0_rad, lon0_rad = math.radians(lat0_deg), math.radians(lon0_deg)
        self._sin_lat0, self._cos_lat0 = float(np.sin(lat0_rad)), float(np.cos(lat0_rad))
        self._sin_lon0, self._cos_lon0 = float(np.sin(lon0_rad)), float(np.cos(lon0_rad))
        self._origin_ecef_m = tuple(float(v) for v in geodetic_to_ecef(lat0_deg, lon0_deg, alt0_m))

    def geodetic_to_ecef_m(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """``pymap3d.geodetic2ecef`` (WGS-84, degrees) of one point: ``(x_m, y_m, z_m)``."""
        lat_rad, lon_rad = math.radians(lat_deg), math.radians(lon_deg)
        cos_lat, sin_lat = math.cos(lat_rad), math.sin(lat_rad)
        cos_lon, sin_lon = math.cos(lon_rad), math.sin(lon_rad)
        n_m = self._a2_m2 / float(np.hypot(self._a_m * cos_lat, self._b_m * sin_lat))
        return ((n_m + alt_m) * cos_lat * cos_lon, (n_m + alt_m) * cos_lat * sin_lon,
                (n_m * self._ba2 + alt_m) * sin_lat)

    def geodetic_to_enu_m(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """``(east_m, north_m, up_m)`` of one geodetic point (``pymap3d.geodetic2enu``)."""
        x_m, y_m, z_m = self.geodetic_to_ecef_m(lat_deg, lon_deg, alt_m)
        x0_m, y0_m, z0_m = self._origin_ecef_m
        u_m, v_m, w_m = x_m - x0_m, y_m - y0_m, z_m - z0_m
        t_m = self._cos_lon0 * u_m + self._sin_lon0 * v_m
        east_m = -self._sin_lon0 * u_m + self._cos_lon0 * v_m
        up_m = self._cos_lat0 * t_m + self._sin_lat0 * w_m
        north_m = -self._sin_lat0 * t_m + self._cos_lat0 * w_m
        return east_m, north_m, up_m

    def enu_to_geodetic(self, east_m: float, north_m: float, up_m: float) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, alt_m)`` of one ENU point (``pymap3d.enu2geodetic``)."""
        t_m = self._cos_lat0 * up_m - self._sin_lat0 * north_m
        w_m = self._sin_lat0 * up_m + self._cos_lat0 * north_m
        u_m = self._cos_lon0 * t_m - self._sin_lon0 * east_m
        v_m = self._sin_lon0 * t_m + self._cos_lon0 * east_m
        x0_m, y0_m, z0_m = self._origin_ecef_m
        return self.ecef_to_geodetic(x0_m + u_m, y0_m + v_m, z0_m + w_m)

    def ned_to_geodetic(self, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, alt_m)`` of one NED point (a LOCAL_NED frame at the origin)."""
        return self.enu_to_geodetic(east_m, north_m, -down_m)

    def ecef_to_geodetic(self, x_m: float, y_m: float, z_m: float) -> tuple[float, float, float]:
        """``pymap3d.ecef2geodetic`` (You 2000, no iteration) of one point, in degrees.

        A point at the Earth's centre or on its axis (pymap3d's special cases) is handed to
        pymap3d itself.
        """
        a_m, b_m, e_m = self._a_m, self._b_m, self._e_m
        r_m = math.sqrt(x_m * x_m + y_m * y_m + z_m * z_m)
        r2_e2 = r_m * r_m - e_m ** 2   # pymap3d: r**2 on an array (a product), E**2 on a float (pow)
        u_m = math.sqrt(0.5 * r2_e2 + 0.5 * float(np.hypot(r2_e2, 2 * e_m * z_m)))
        hxy_m = float(np.hypot(x_m, y_m))
        if abs(u_m) <= _ISCLOSE_ZERO_M or abs(hxy_m) <= _ISCLOSE_ZERO_M:
            lat, lon, alt = pymap3d.ecef2geodetic(np.asarray(x_m), np.asarray(y_m), np.asarray(z_m))
            return float(lat), float(lon), float(alt)
        hue_m = float(np.hypot(u_m, e_m))
        beta = float(np.arctan(hue_m / u_m * z_m / hxy_m))
        cos_beta, sin_beta = math.cos(beta), math.sin(beta)
        beta += ((b_m * u_m - a_m * hue_m + e_m ** 2) * sin_beta) / (a_m * hue_m * 1 / cos_beta
                                                                     - e_m ** 2 * cos_beta)
        lat = float(np.arctan(a_m / b_m * float(np.tan(beta))))
        cos_beta = math.cos(beta)
        if beta >= _LIM_PI2:
            lat, cos_beta = math.pi / 2, 0.0
        elif beta <= -_LIM_PI2:
            lat, cos_beta = -math.pi / 2, 0.0
        alt_m = float(np.hypot(z_m - b_m * math.sin(beta), hxy_m - a_m * cos_beta))
        if x_m * x_m / a_m ** 2 + y_m * y_m / a_m ** 2 + z_m * z_m / b_m ** 2 < 1:
            alt_m = -alt_m
        return math.degrees(lat), math.degrees(float(np.arctan2(y_m, x_m))), alt_m


#: ``numpy.isclose(v, 0)``'s bound (its default ``atol``), pymap3d's test for a special case
_ISCLOSE_ZERO_M = 1e-8
#: pymap3d's float32 patch of latitudes within one float64 epsilon of a pole
_LIM_PI2 = math.pi / 2 - float(np.finfo(np.float64).eps)
