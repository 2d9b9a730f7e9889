"""One vehicle of a mock fleet: its autopilot, dynamics, faults, links and sensor, and its frames.

:class:`MockVehicle` is the read-only view a :class:`~sitl_mock.fleet.MockFleet` gives of each
vehicle, with the exact map from the vehicle's own LOCAL_NED frame (tangent plane at its home)
to the mission frame (ENU metres about the fleet origin).
"""
from __future__ import annotations

import math

import numpy as np

from formation.geodesy import enu_to_geodetic, geodetic_to_enu, ned_to_enu

__all__ = ["MockVehicle", "default_home_offsets", "per_vehicle", "per_vehicle_params"]

_HOME_SPACING_M = 5.0


class MockVehicle:
    """One vehicle of a :class:`MockFleet` (read-only view plus its parts).

    Attributes
    ----------
    sysid : int
    autopilot : MockAutopilot
    dynamics : Multicopter
    faults : FaultSet
    home_enu : numpy.ndarray
        Home (its LOCAL_NED origin) in the mission frame, ENU metres about the fleet origin.
    home_geodetic : tuple
        ``(lat_deg, lon_deg, alt_m)`` of home.
    udp_bind_port, udp_send_port, tcp_port : int
        Its ports (0 when disabled).
    sensor : SignalSensor or None
    """

    def __init__(self, index, autopilot, dynamics, faults, home_enu, home_geodetic, origin, links,
                 sensor):
        self.index = index
        self.autopilot = autopilot
        self.dynamics = dynamics
        self.faults = faults
        self.home_enu = np.asarray(home_enu, dtype=float)
        self.home_geodetic = tuple(float(v) for v in home_geodetic)
        self.links = links
        self.sensor = sensor
        self.next_sample_s = -math.inf
        # exact affine map from this vehicle's local ENU (tangent plane at home) to mission ENU
        b = geodetic_to_enu(*self.home_geodetic, origin)
        cols = [geodetic_to_enu(*enu_to_geodetic(e, self.home_geodetic), origin) - b
                for e in np.eye(3)]
        self._to_mission = np.array(cols).T
        self._mission_offset = b

    @property
    def sysid(self) -> int:
        """MAVLink system id."""
        return self.autopilot.sysid

    @property
    def mode_name(self) -> str:
        """Current flight mode name (e.g. ``GUIDED``, ``OFFBOARD``)."""
        return self.autopilot.mode_name

    @property
    def armed(self) -> bool:
        """True while armed."""
        return self.autopilot.armed

    @property
    def params(self):
        """The autopilot's :class:`~sitl_mock.ap_params.ParamTable`."""
        return self.autopilot.params

    @property
    def counters(self) -> dict:
        """A snapshot of the receive / transmit / protocol counters."""
        return dict(self.autopilot.counters)

    @property
    def udp_bind_port(self) -> int:
        """UDP port the vehicle listens on."""
        return self.links.udp_bind_port

    @property
    def udp_send_port(self) -> int:
        """UDP port the vehicle streams to."""
        return self.links.udp_send_port

    @property
    def tcp_port(self) -> int:
        """TCP port of the vehicle's MAVLink server."""
        return self.links.tcp_port

    def true_position_ned(self) -> np.ndarray:
        """True position in the vehicle's own LOCAL_NED frame."""
        return self.dynamics.position_ned_m

    def true_position_enu(self) -> np.ndarray:
        """True position in the mission frame (ENU metres about the fleet origin)."""
        return self.to_mission_enu(self.dynamics.position_ned_m)

    def to_mission_enu(self, ned) -> np.ndarray:
        """Convert a point of this vehicle's LOCAL_NED frame to the mission frame (exact)."""
        return self._to_mission @ ned_to_enu(ned) + self._mission_offset

    def mission_enu_of(self, north_m: float, east_m: float, down_m: float) -> np.ndarray:
        """:meth:`to_mission_enu` of one point given as floats (the same operations on the same
        array, without ``ned_to_enu``'s stacking: the fleet calls it for every sensor sample)."""
        return self._to_mission @ np.array((east_m, north_m, -down_m)) + self._mission_offset

    def __repr__(self) -> str:
        return (f"MockVehicle(sysid={self.sysid}, {self.autopilot.personality.name}, "
                f"mode={self.mode_name}, udp={self.udp_bind_port}->{self.udp_send_port}, "
                f"tcp={self.tcp_port})")

def default_home_offsets(n: int, spacing_m: float = _HOME_SPACING_M) -> np.ndarray:
    """Homes on a square grid ``spacing_m`` apart (ENU metres from the fleet origin), shape (n, 3)."""
    cols = max(1, math.ceil(math.sqrt(n)))
    return np.array([((i % cols) * spacing_m, (i // cols) * spacing_m, 0.0) for i in range(n)])


def per_vehicle(n: int, personality, home_offsets_enu, sensor_noise_std):
    """Expand the fleet's per-vehicle settings to one value per vehicle, checked.

    Returns
    -------
    tuple
        ``(personalities, home_offsets_enu (n, 3), sensor_noise_std)``, each of length ``n``.

    Raises
    ------
    ValueError
        When a list has the wrong length or an offset is not a finite ENU triple.
    """
    personalities = [personality] * n if isinstance(personality, str) else list(personality)
    if len(personalities) != n:
        raise ValueError(f"{len(personalities)} personalities given for {n} vehicles")
    offsets = default_home_offsets(n) if home_offsets_enu is None \
        else np.asarray(home_offsets_enu, dtype=float)
    if offsets.shape != (n, 3) or not np.all(np.isfinite(offsets)):
        raise ValueError(f"home_offsets_enu must be {n} finite ENU triples, got shape {offsets.shape}")
    noise = [float(sensor_noise_std)] * n if np.isscalar(sensor_noise_std) \
        else [float(v) for v in sensor_noise_std]
    if len(noise) != n:
        raise ValueError(f"{len(noise)} sensor noise levels given for {n} vehicles")
    return personalities, offsets, noise


def per_vehicle_params(n: int, params) -> list:
    """Autopilot parameter overrides, one dict per vehicle (``params``: one dict, or a list)."""
    overrides = [params or {}] * n if not isinstance(params, (list, tuple)) else list(params)
    if len(overrides) != n:
        raise ValueError(f"{len(overrides)} parameter override sets given for {n} vehicles")
    return overrides
