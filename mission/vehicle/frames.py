"""Frames and flight-mode tables for :mod:`mission.vehicle.vehicle_link`.

* :class:`MissionToLocal`: the exact affine map between the mission ENU frame (about the mission
  origin) and one vehicle's LOCAL_NED frame (about that vehicle's local origin), precomputed so
  that converting a setpoint is a few float operations (no numpy on the 20 Hz path).
* Mode tables: ArduCopter custom modes and PX4 (main, sub) modes, with the aliases the mission
  uses (``"HOLD"``, ``"LAND"``, ``"RTL"`` ...) resolved per flavour.
"""
from __future__ import annotations

import numpy as np
from pymavlink import mavutil

from formation.geodesy import enu_to_geodetic, geodetic_to_enu, ned_to_enu

__all__ = [
    "MissionToLocal",
    "ARDUCOPTER_MODES",
    "PX4_MODES",
    "mode_name",
    "resolve_mode",
]

#: ArduCopter custom_mode number -> name (pymavlink's table)
ARDUCOPTER_MODES: dict[int, str] = dict(mavutil.mode_mapping_acm)

#: PX4 (main_mode, sub_mode) -> name; custom_mode = main << 16 | sub << 24
PX4_MODES: dict[tuple[int, int], str] = {
    (1, 0): "MANUAL", (2, 0): "ALTCTL", (3, 0): "POSCTL",
    (4, 1): "AUTO.READY", (4, 2): "AUTO.TAKEOFF", (4, 3): "AUTO.LOITER", (4, 4): "AUTO.MISSION",
    (4, 5): "AUTO.RTL", (4, 6): "AUTO.LAND", (4, 7): "AUTO.RTGS", (4, 8): "AUTO.FOLLOW_TARGET",
    (4, 9): "AUTO.PRECLAND", (5, 0): "ACRO", (6, 0): "OFFBOARD", (7, 0): "STABILIZED",
}

_ARDUPILOT_ALIASES = {"HOLD": "LOITER", "POSHOLD": "POSHOLD"}
_PX4_ALIASES = {
    "HOLD": "AUTO.LOITER", "LOITER": "AUTO.LOITER", "LAND": "AUTO.LAND", "RTL": "AUTO.RTL",
    "TAKEOFF": "AUTO.TAKEOFF", "MISSION": "AUTO.MISSION", "AUTO": "AUTO.MISSION",
    "POSITION": "POSCTL", "ALTITUDE": "ALTCTL", "STABILIZE": "STABILIZED",
}


def mode_name(flavour: str, custom_mode: int) -> str:
    """Name of a HEARTBEAT ``custom_mode`` for ``flavour`` (``"MODE(n)"`` when unknown)."""
    if flavour == "ardupilot":
        return ARDUCOPTER_MODES.get(custom_mode, f"MODE({custom_mode})")
    if flavour == "px4":
        key = ((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)
        name = PX4_MODES.get(key)
        if name is None:
            name = PX4_MODES.get((key[0], 0), f"MODE({key[0]}.{key[1]})")
        return name
    return f"MODE({custom_mode})"


def resolve_mode(flavour: str, name: str) -> tuple[str, float, float]:
    """Resolve a mode name (or alias) to ``(canonical_name, param2, param3)`` of DO_SET_MODE.

    ArduPilot: param2 is the custom mode number. PX4: param2 the main mode, param3 the sub mode.

    Raises
    ------
    ValueError
        Unknown mode for that flavour (the message lists the known ones).
    """
    key = str(name).strip().upper()
    if flavour == "ardupilot":
        key = _ARDUPILOT_ALIASES.get(key, key)
        for number, mode in ARDUCOPTER_MODES.items():
            if mode == key:
                return mode, float(number), 0.0
        known = sorted(ARDUCOPTER_MODES.values())
    elif flavour == "px4":
        key = _PX4_ALIASES.get(key, key)
        for (main, sub), mode in PX4_MODES.items():
            if mode == key:
                return mode, float(main), float(sub)
        known = sorted(PX4_MODES.values()) + sorted(_PX4_ALIASES)
    else:
        raise ValueError(f"cannot set modes on a {flavour!r} autopilot")
    raise ValueError(f"unknown {flavour} mode {name!r}; known: {', '.join(known)}")


class MissionToLocal:
    """Exact affine map between the mission ENU frame and one vehicle's LOCAL_NED frame.

    Both frames are tangent planes of the WGS-84 ellipsoid at different points, so the map is
    ``local_enu = A @ mission_enu + b`` with a rotation ``A`` (nearly the identity) and ``b`` the
    mission origin in the local frame; it is computed once from the two origins.

    Parameters
    ----------
    mission_origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the mission frame's origin.
    local_origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the vehicle's LOCAL_NED origin.
    """

    def __init__(self, mission_origin, local_origin) -> None:
        self.mission_origin = tuple(float(v) for v in mission_origin)
        self.local_origin = tuple(float(v) for v in local_origin)
        probe = np.array([[0.0, 0.0, 0.0], [1000.0, 0, 0], [0, 1000.0, 0], [0, 0, 1000.0]])
        lat, lon, alt = enu_to_geodetic(probe, self.mission_origin)
        mapped = geodetic_to_enu(lat, lon, alt, self.local_origin)
        b = mapped[0]
        a = (mapped[1:] - b).T / 1000.0
        self.matrix = a
        self.offset_m = b
        inv = np.linalg.inv(a)
        self._a = [float(v) for v in a.ravel()]
        self._b = [float(v) for v in b]
        self._inv = [float(v) for v in inv.ravel()]

    @classmethod
    def from_home(cls, mission_origin, home, home_local_ned_m=(0.0, 0.0, 0.0)) -> "MissionToLocal":
        """Build from a HOME_POSITION: home geodetic and home in the local frame (x, y, z NED).

        The local origin is the home moved back by its local coordinates, so the map is right
        even when the autopilot's local origin (EKF origin) is not its home.
        """
        home_enu_local = ned_to_enu(np.asarray(home_local_ned_m, dtype=float))
        lat, lon, alt = enu_to_geodetic(-home_enu_local, home)
        return cls(mission_origin, (float(lat), float(lon), float(alt)))

    def mission_enu_to_local_ned(self, east_m: float, north_m: float, up_m: float) -> tuple[float, float, float]:
        """Mission ENU point -> local NED ``(north_m, east_m, down_m)`` (plain floats)."""
        a = self._a
        b = self._b
        e = a[0] * east_m + a[1] * north_m + a[2] * up_m + b[0]
        n = a[3] * east_m + a[4] * north_m + a[5] * up_m + b[1]
        u = a[6] * east_m + a[7] * north_m + a[8] * up_m + b[2]
        return n, e, -u

    def local_ned_to_mission_enu(self, north_m: float, east_m: float, down_m: float) -> np.ndarray:
        """Local NED point -> mission ENU ``array([east_m, north_m, up_m])``."""
        b = self._b
        de, dn, du = east_m - b[0], north_m - b[1], -down_m - b[2]
        m = self._inv
        return np.array([
            m[0] * de + m[1] * dn + m[2] * du,
            m[3] * de + m[4] * dn + m[5] * du,
            m[6] * de + m[7] * dn + m[8] * du,
        ])

    def local_velocity_ned_to_mission_enu(self, vn: float, ve: float, vd: float) -> np.ndarray:
        """Rotate a local NED vector (e.g. a velocity) into the mission ENU frame."""
        m = self._inv
        de, dn, du = ve, vn, -vd
        return np.array([
            m[0] * de + m[1] * dn + m[2] * du,
            m[3] * de + m[4] * dn + m[5] * du,
            m[6] * de + m[7] * dn + m[8] * du,
        ])
