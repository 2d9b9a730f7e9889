"""Vehicle state and telemetry handling for :mod:`mission.vehicle.vehicle_link` (split out to keep modules small).

:class:`VehicleTelemetry` is the part of :class:`mission.vehicle.vehicle_link.VehicleLink` that turns received
messages into :class:`VehicleState`; :class:`CommandError` is the error every vehicle operation
raises. Import both from :mod:`mission.vehicle.vehicle_link`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from formation.geodesy import geodetic_to_enu
from mission.core.clock import wait_on_clock
from mission.link.endpoint_registry import LinkError
from mission.vehicle.frames import MissionToLocal, mode_name
from mission.vehicle.wind import WindEstimate, decode_wind, decode_wind_cov

__all__ = ["CommandError", "VehicleState", "VehicleTelemetry", "command_name", "result_name"]

_M = mavlink
_LANDED = {_M.MAV_LANDED_STATE_ON_GROUND: True, _M.MAV_LANDED_STATE_IN_AIR: False,
           _M.MAV_LANDED_STATE_TAKEOFF: False, _M.MAV_LANDED_STATE_LANDING: False}
_POSITION_FRESH_S = 3.0
#: local coordinates beyond this (100 km) cannot belong to a multicopter's local frame
_MAX_LOCAL_M = 1e5

def command_name(command: int) -> str:
    """``MAV_CMD_*`` name of a command number (``"MAV_CMD(n)"`` when unknown)."""
    entry = _M.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"MAV_CMD({command})"


def result_name(result: int) -> str:
    """Short name of a MAV_RESULT (``"DENIED"``...)."""
    entry = _M.enums["MAV_RESULT"].get(result)
    return entry.name.replace("MAV_RESULT_", "") if entry is not None else f"RESULT({result})"


class CommandError(RuntimeError):
    """A command failed or timed out; the message names the vehicle and the command.

    Attributes
    ----------
    sysid : int
    command : int or None
    result : int or None
        The MAV_RESULT, or None for a timeout.
    """

    def __init__(self, message: str, *, sysid: int, command: int | None = None, result: int | None = None):
        super().__init__(message)
        self.sysid = sysid
        self.command = command
        self.result = result


@dataclass
class VehicleState:
    """The latest known state of a vehicle (replace-on-update; copy with :meth:`snapshot`).

    Attributes
    ----------
    sysid : int
    flavour : str
        ``"ardupilot"``, ``"px4"`` or ``"generic"``.
    mode : str
        Mode name (ArduCopter names; PX4 names like ``"OFFBOARD"``, ``"AUTO.LAND"``).
    armed : bool
    landed : bool or None
        From EXTENDED_SYS_STATE; None until known.
    lat_deg, lon_deg, alt_m, relative_alt_m : float or None
        From GLOBAL_POSITION_INT (alt AMSL; relative to home).
    position_ned_m, velocity_ned_m_s : numpy.ndarray or None
        From LOCAL_POSITION_NED (the vehicle's own local frame).
    home : tuple of float or None
        ``(lat_deg, lon_deg, alt_m)`` from HOME_POSITION.
    battery_remaining_pct : float or None
    battery_voltage_v : float or None
    last_heartbeat_s : float or None
        Clock time of the last autopilot HEARTBEAT.
    last_position_s : float or None
        Clock time of the last position message.
    position_ok : bool
        A fresh position and (if reported) a healthy GPS.
    system_status : int
        HEARTBEAT ``system_status`` (MAV_STATE).
    wind : WindEstimate or None
        The autopilot's latest wind estimate (WIND_COV on PX4, WIND on ArduPilot); None until one
        arrived. See :mod:`mission.vehicle.wind` for the conventions.
    """

    sysid: int
    flavour: str
    mode: str = "UNKNOWN"
    armed: bool = False
    landed: bool | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    relative_alt_m: float | None = None
    position_ned_m: np.ndarray | None = None
    velocity_ned_m_s: np.ndarray | None = None
    home: tuple[float, float, float] | None = None
    battery_remaining_pct: float | None = None
    battery_voltage_v: float | None = None
    last_heartbeat_s: float | None = None
    last_position_s: float | None = None
    position_ok: bool = False
    system_status: int = 0
    gps_healthy: bool | None = None
    wind: WindEstimate | None = None

    def snapshot(self) -> "VehicleState":
        """A copy that later telemetry does not change."""
        return dataclasses.replace(self)



class VehicleTelemetry:
    """Telemetry half of :class:`mission.vehicle.vehicle_link.VehicleLink`: message handlers and waits.

    Expects the attributes set by ``VehicleLink.__init__`` (``clock``, ``state``, ``flavour``,
    ``compid``, ``mission_origin``, ``endpoint``, ``frame_map``...).
    """

    def _on_message(self, msg) -> None:
        self._last_rx_s = self.clock.time()
        # not msg.id: messages with a field named "id" (BATTERY_STATUS...) shadow the class id
        handler = self._handlers.get(msg.get_header().msgId)
        if handler is not None:
            handler(msg)

    def _on_link_error(self, exc: LinkError) -> None:
        self.errors.append(exc)

    def _on_heartbeat(self, msg) -> None:
        if msg.get_srcComponent() != self.compid:
            return
        st = self.state
        now = self.clock.time()
        armed = bool(msg.base_mode & _M.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = mode_name(self.flavour, msg.custom_mode)
        if self.status_heartbeats and (mode, armed) == (st.mode, st.armed):
            self.status_heartbeats += 1
        else:
            self.status_heartbeats, self.status_since_s = 1, now
        st.armed = armed
        st.mode = mode
        st.system_status = msg.system_status
        st.last_heartbeat_s = now
        self._events["update"].set()

    def _reject(self, msg, why: str) -> None:
        """Count a telemetry message whose values cannot be true (state unchanged)."""
        name = msg.get_type()
        self.rejected[name] = self.rejected.get(name, 0) + 1
        self.last_rejection = f"{name}: {why}"

    def _on_global_position(self, msg) -> None:
        st = self.state
        if msg.lat == 0 and msg.lon == 0:
            return
        if not (-900_000_000 <= msg.lat <= 900_000_000 and -1_800_000_000 <= msg.lon <= 1_800_000_000):
            self._reject(msg, f"lat/lon {msg.lat}, {msg.lon} (1e-7 deg) out of range")
            return
        st.lat_deg = msg.lat * 1e-7
        st.lon_deg = msg.lon * 1e-7
        st.alt_m = msg.alt * 1e-3
        st.relative_alt_m = msg.relative_alt * 1e-3
        if st.velocity_ned_m_s is None or self._local_stale():
            st.velocity_ned_m_s = np.array([msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01])
        self._position_update()

    def _local_stale(self) -> bool:
        return self._local_s is None or self.clock.time() - self._local_s > _POSITION_FRESH_S

    def _on_local_position(self, msg) -> None:
        st = self.state
        x, y, z, vx, vy, vz = msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz
        # abs(v) < _MAX_LOCAL_M is False for NaN and infinities: finite and plausible in one test
        if not (abs(x) < _MAX_LOCAL_M and abs(y) < _MAX_LOCAL_M and abs(z) < _MAX_LOCAL_M
                and math.isfinite(vx) and math.isfinite(vy) and math.isfinite(vz)):
            self._reject(msg, f"non-finite or absurd position/velocity {msg.x}, {msg.y}, {msg.z}")
            return
        st.position_ned_m = np.array([x, y, z])
        st.velocity_ned_m_s = np.array([vx, vy, vz])
        if st.home is not None:   # kept current between (slower) GLOBAL_POSITION_INT messages
            st.relative_alt_m = self._home_local[2] - msg.z
        self._local_s = self.clock.time()
        self._position_update()

    def _position_update(self) -> None:
        st = self.state
        st.last_position_s = self.clock.time()
        st.position_ok = st.gps_healthy is not False
        self._events["update"].set()

    def _on_sys_status(self, msg) -> None:
        st = self.state
        if msg.battery_remaining >= 0:
            st.battery_remaining_pct = float(msg.battery_remaining)
        if msg.voltage_battery != 0xFFFF:
            st.battery_voltage_v = msg.voltage_battery * 1e-3
        gps = _M.MAV_SYS_STATUS_SENSOR_GPS
        if msg.onboard_control_sensors_present & gps:
            st.gps_healthy = bool(msg.onboard_control_sensors_health & gps)
            if not st.gps_healthy:
                st.position_ok = False

    def _on_battery(self, msg) -> None:
        if msg.battery_remaining >= 0:
            self.state.battery_remaining_pct = float(msg.battery_remaining)

    def _on_extended_state(self, msg) -> None:
        self.state.landed = _LANDED.get(msg.landed_state)
        self._events["update"].set()

    def _on_home(self, msg) -> None:
        home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        local = (float(msg.x), float(msg.y), float(msg.z))
        if not (abs(home[0]) <= 90.0 and abs(home[1]) <= 180.0 and abs(home[2]) < _MAX_LOCAL_M):
            self._reject(msg, f"home {home} out of range")
            return
        if not all(math.isfinite(v) and abs(v) < _MAX_LOCAL_M for v in local):
            self._reject(msg, f"home local position {local} non-finite or absurd")
            return
        if home != self.state.home or local != self._home_local or self.frame_map is None:
            try:
                frame_map = MissionToLocal.from_home(self.mission_origin, home, local)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                self._reject(msg, f"no frame from home {home}, local {local}: {exc}")
                return
            self.state.home = home
            self._home_local = local
            self.frame_map = frame_map
        self._events["home"].set()

    def _on_wind_cov(self, msg) -> None:
        try:
            self.state.wind = decode_wind_cov(msg, self.clock.time())
        except ValueError as exc:
            self._reject(msg, str(exc))

    def _on_wind(self, msg) -> None:
        try:
            self.state.wind = decode_wind(msg, self.clock.time())
        except ValueError as exc:
            self._reject(msg, str(exc))

    def _on_ack(self, msg) -> None:
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.endpoint.gcs_sysid):
            return
        queue = self._acks.get(msg.command)
        if queue is not None:
            queue.put_nowait(msg)

    def _on_version(self, msg) -> None:
        uid = int(msg.uid) or int.from_bytes(bytes(msg.uid2), "little")
        self.uid = uid
        self.endpoint.note_uid(self.sysid, uid)
        self._events["version"].set()

    def _on_statustext(self, msg) -> None:
        text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("utf-8", "replace")
        self.statustexts.append((self.clock.time(), msg.severity, text.rstrip("\x00")))

    def link_age_s(self) -> float:
        """Clock seconds since the last message from this vehicle."""
        return self.clock.time() - self._last_rx_s

    def position_fresh(self) -> bool:
        """True when the last position message is younger than 3 clock seconds."""
        t = self.state.last_position_s
        return t is not None and self.clock.time() - t <= _POSITION_FRESH_S

    def position_enu_m(self) -> np.ndarray | None:
        """The vehicle's position in the mission ENU frame, or None if unknown.

        From LOCAL_POSITION_NED when fresh and the home is known, else GLOBAL_POSITION_INT.
        """
        st = self.state
        ned, fmap = st.position_ned_m, self.frame_map
        if ned is not None and fmap is not None and not self._local_stale():
            # a reading check and the display ask for it far more often than it changes
            # (LOCAL_POSITION_NED at 5 Hz): converted once per message (a new array) and frame map
            cached = self._enu_cache
            if cached is None or cached[0] is not ned or cached[1] is not fmap:
                n, e, d = ned
                cached = self._enu_cache = (ned, fmap, fmap.local_ned_to_mission_enu(n, e, d))
            return cached[2].copy()
        if st.lat_deg is None:
            return None
        return geodetic_to_enu(st.lat_deg, st.lon_deg, st.alt_m, self.mission_origin)

    def home_enu_m(self) -> np.ndarray | None:
        """The vehicle's home in the mission ENU frame, or None until HOME_POSITION arrived."""
        if self.state.home is None:
            return None
        return geodetic_to_enu(*self.state.home, self.mission_origin)

    async def wait_for(self, predicate: Callable[[VehicleState], bool], timeout_s: float, what: str) -> VehicleState:
        """Wait until ``predicate(state)`` holds (re-checked on every telemetry update).

        Raises
        ------
        CommandError
            After ``timeout_s`` clock seconds, naming the vehicle and ``what``.
        """
        deadline = self.clock.time() + timeout_s
        event = self._events["update"]
        while not predicate(self.state):
            self._raise_link_error()
            remaining = deadline - self.clock.time()
            if remaining <= 0:
                raise CommandError(f"{self._who()}: timed out after {timeout_s:g} s waiting for {what}"
                                   f" (mode {self.state.mode}, armed {self.state.armed})", sysid=self.sysid)
            event.clear()
            try:
                await wait_on_clock(event.wait(), min(remaining, 0.5), self.clock)
            except TimeoutError:
                pass
        return self.state

    def _who(self) -> str:
        return f"vehicle {self.sysid} ({self.flavour} on {self.endpoint.uri})"

    def _raise_link_error(self) -> None:
        if self.errors:
            raise self.errors[0]
