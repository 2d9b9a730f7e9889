"""Fast scalar conversions between one vehicle's LOCAL_NED frame and geodetic coordinates.

The mock converts positions to latitude / longitude / altitude thousands of times a second
(GLOBAL_POSITION_INT, GPS_RAW_INT, sensor readings). :mod:`formation.geodesy` is exact but
array-based, which costs tens of microseconds per scalar point; :class:`LocalFrame` does the same
exact WGS-84 maths (tangent plane -> ECEF -> geodetic, iterated to convergence) on plain floats.
Tests check it against :mod:`formation.geodesy` to well under a millimetre.
"""
from __future__ import annotations

import math

from formation.geodesy import WGS84_A_M, WGS84_F

__all__ = ["LocalFrame"]

_E2 = WGS84_F * (2.0 - WGS84_F)
_MAX_ITER = 10
_TOL_RAD = 1e-13


class LocalFrame:
    """A LOCAL_NED frame (tangent plane at ``origin``) with scalar geodetic conversions.

    Parameters
    ----------
    origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the frame's origin.
    """

    def __init__(self, origin):
        lat0, lon0, alt0 = (float(v) for v in origin)
        self.origin = (lat0, lon0, alt0)
        sl, cl = math.sin(math.radians(lat0)), math.cos(math.radians(lat0))
        so, co = math.sin(math.radians(lon0)), math.cos(math.radians(lon0))
        n = WGS84_A_M / math.sqrt(1.0 - _E2 * sl * sl)
        self._x0 = (n + alt0) * cl * co
        self._y0 = (n + alt0) * cl * so
        self._z0 = (n * (1.0 - _E2) + alt0) * sl
        # ECEF components of the east, north and up unit vectors
        self._east = (-so, co, 0.0)
        self._north = (-sl * co, -sl * so, cl)
        self._up = (cl * co, cl * so, sl)

    def ned_to_geodetic(self, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, alt_m)`` of a LOCAL_NED point."""
        e, nn, u = self._east, self._north, self._up
        up_m = -down_m
        x = self._x0 + e[0] * east_m + nn[0] * north_m + u[0] * up_m
        y = self._y0 + e[1] * east_m + nn[1] * north_m + u[1] * up_m
        z = self._z0 + e[2] * east_m + nn[2] * north_m + u[2] * up_m
        return _ecef_to_geodetic(x, y, z)


def _ecef_to_geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - _E2))
    alt = 0.0
    for _ in range(_MAX_ITER):
        sin_lat = math.sin(lat)
        n = WGS84_A_M / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
        alt = p / math.cos(lat) - n
        new_lat = math.atan2(z, p * (1.0 - _E2 * n / (n + alt)))
        if abs(new_lat - lat) < _TOL_RAD:
            lat = new_lat
            break
        lat = new_lat
    sin_lat = math.sin(lat)
    n = WGS84_A_M / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
    alt = p / math.cos(lat) - n
    return math.degrees(lat), math.degrees(lon), alt
