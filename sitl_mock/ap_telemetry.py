"""Telemetry of the mock autopilots: message builders and the per-message rate scheduler.

Every streamed message has a default rate (modest, see :data:`DEFAULT_RATES_HZ`) that
SET_MESSAGE_INTERVAL / MAV_CMD_SET_MESSAGE_INTERVAL change and MAV_CMD_REQUEST_MESSAGE
bypasses (one message now). Builders read the autopilot's state through the small interface
documented in :class:`TelemetrySource`.
"""
from __future__ import annotations

import math
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock import ap_flight
from sitl_mock.ap_prearm import build_ekf_status_report
from sitl_mock.ap_wind import wind_cov_fields, wind_fields

__all__ = ["DEFAULT_RATES_HZ", "MAX_RATE_HZ", "MAX_INTERVAL_US", "MessageScheduler", "TelemetrySource",
           "BUILDERS", "build_message", "SENSORS_PRESENT", "WIND_MSG_IDS"]

#: Streamed by default (Hz); anything in BUILDERS can be enabled by SET_MESSAGE_INTERVAL.
DEFAULT_RATES_HZ = {
    mavlink2.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: 4.0,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 2.0,
    mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT: 2.0,
}
#: Fastest stream: one message per physics step.
MAX_RATE_HZ = 50.0
#: Longest interval (us) SET_MESSAGE_INTERVAL accepts: MESSAGE_INTERVAL.interval_us is an int32.
MAX_INTERVAL_US = 2 ** 31 - 1

_S = mavlink2
SENSORS_PRESENT = (
    _S.MAV_SYS_STATUS_SENSOR_3D_GYRO | _S.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | _S.MAV_SYS_STATUS_SENSOR_3D_MAG | _S.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | _S.MAV_SYS_STATUS_SENSOR_GPS | _S.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | _S.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | _S.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | _S.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | _S.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | _S.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | _S.MAV_SYS_STATUS_AHRS
    | _S.MAV_SYS_STATUS_SENSOR_BATTERY | _S.MAV_SYS_STATUS_PREARM_CHECK
)
_NOT_READY = _S.MAV_SYS_STATUS_SENSOR_GPS | _S.MAV_SYS_STATUS_PREARM_CHECK


class TelemetrySource(Protocol):
    """What the builders read from an autopilot (see :class:`sitl_mock.autopilot.MockAutopilot`)."""

    mav: object
    personality: object
    mc: object
    uid: int
    missions: object
    wind: object  # sitl_mock.ap_wind.WindEstimateModel

    def position_ready(self, t_s: float) -> bool:
        """True once the position estimate is usable."""

    def ned_to_geodetic(self, ned) -> tuple:
        """``(lat_deg, lon_deg, alt_m)`` of a LOCAL_NED point."""

    def time_boot_ms(self, t_s: float) -> int:
        """Milliseconds since boot."""

    def estimate(self, t_s: float) -> tuple:
        """``(ned_m, vel_ned_m_s, lat_deg, lon_deg, alt_m)`` as the autopilot estimates it."""

    def estimate_local(self, t_s: float) -> tuple:
        """``(ned_m, vel_ned_m_s)`` of :meth:`estimate`, without the geodetic conversion."""

    def home_geodetic(self) -> tuple | None:
        """Home ``(lat_deg, lon_deg, alt_m)`` or None before the position fix."""

    def heartbeat_fields(self) -> tuple:
        """``(base_mode, custom_mode, system_status)``."""

    def health_ok(self, t_s: float) -> bool:
        """GPS and pre-arm checks healthy."""

    def landed_state(self) -> int:
        """MAV_LANDED_STATE value."""

    def setpoint_echo(self) -> tuple | None:
        """``(frame, type_mask, ned, vel, yaw, yaw_rate)`` of the followed setpoint, or None."""


class MessageScheduler:
    """Per-message intervals and due times, on the simulated clock.

    Parameters
    ----------
    t0_s : float
        Boot time: every default stream is first due then.
    extra_defaults_hz : dict of int to float, optional
        The personality's own default streams beyond :data:`DEFAULT_RATES_HZ` (a rate of 0: known
        to SET_MESSAGE_INTERVAL, not streamed until asked).
    unsupported : iterable of int, optional
        Message ids in :data:`BUILDERS` this personality does not send (refused like unknown ones).
    """

    def __init__(self, t0_s: float, extra_defaults_hz: dict | None = None, unsupported=()):
        self._defaults_hz = {**DEFAULT_RATES_HZ, **{k: v for k, v in (extra_defaults_hz or {}).items() if v > 0}}
        self._unsupported = frozenset(unsupported)
        self._interval: dict[int, float] = {}
        self._due: dict[int, float] = {}
        for msg_id, hz in self._defaults_hz.items():
            self._interval[msg_id] = 1.0 / hz
            self._due[msg_id] = t0_s
        self._next_s = t0_s  # earliest due time (fast path: nothing due)

    def supports(self, msg_id: int) -> bool:
        """True for a message this personality can stream."""
        return msg_id in BUILDERS and msg_id not in self._unsupported

    def set_interval(self, msg_id: int, interval_us: float, t_s: float) -> bool:
        """Apply SET_MESSAGE_INTERVAL semantics (-1 off, 0 default); False if unsupported.

        An interval above :data:`MAX_INTERVAL_US` is refused (False): GET_MESSAGE_INTERVAL
        could not report it.
        """
        if not self.supports(msg_id) or not math.isfinite(interval_us) or interval_us > MAX_INTERVAL_US:
            return False
        self._next_s = min(self._next_s, t_s)
        if interval_us < 0:
            self._interval.pop(msg_id, None)
            self._due.pop(msg_id, None)
            return True
        if interval_us == 0:
            hz = self._defaults_hz.get(msg_id)
            if hz is None:
                self._interval.pop(msg_id, None)
                self._due.pop(msg_id, None)
                return True
            interval_s = 1.0 / hz
        else:
            interval_s = max(interval_us * 1e-6, 1.0 / MAX_RATE_HZ)
        self._interval[msg_id] = interval_s
        self._due[msg_id] = t_s
        return True

    def interval_us(self, msg_id: int) -> int:
        """Current interval in microseconds (-1 when not streamed, 0 when unsupported)."""
        if not self.supports(msg_id):
            return 0
        iv = self._interval.get(msg_id)
        return -1 if iv is None else int(round(iv * 1e6))

    def due(self, t_s: float) -> list[int]:
        """Message ids due at ``t_s`` (and schedule their next time)."""
        if t_s < self._next_s:
            return []
        out = []
        for msg_id, due in self._due.items():
            if t_s >= due:
                out.append(msg_id)
                iv = self._interval[msg_id]
                nxt = due + iv
                self._due[msg_id] = nxt if nxt > t_s else t_s + iv
        self._next_s = min(self._due.values(), default=float("inf"))
        return out


def _heartbeat(ap, t_s):
    base_mode, custom_mode, status = ap.heartbeat_fields()
    return ap.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, ap.personality.autopilot,
                                   base_mode, custom_mode, status, 3)


def _sys_status(ap, t_s):
    health = SENSORS_PRESENT if ap.health_ok(t_s) else SENSORS_PRESENT & ~_NOT_READY
    mc = ap.mc
    return ap.mav.sys_status_encode(
        SENSORS_PRESENT, SENSORS_PRESENT, health, 250, int(ap_flight.battery_voltage_v(ap) * 1000),
        -1, int(round(mc.battery_remaining * 100)), 0, 0, 0, 0, 0, 0)


def _gps_raw_int(ap, t_s):
    ned, vel, lat, lon, alt = ap.estimate(t_s)
    ready = ap.position_ready(t_s)
    speed = math.hypot(vel[0], vel[1])
    cog = int(math.degrees(math.atan2(vel[1], vel[0])) % 360 * 100) if speed > 0.1 else 65535
    return ap.mav.gps_raw_int_encode(
        int(t_s * 1e6), 3 if ready else 1, int(round(lat * 1e7)), int(round(lon * 1e7)),
        int(round(alt * 1000)), 80 if ready else 9999, 120 if ready else 9999,
        int(round(speed * 100)), cog, 12 if ready else 3)


def _global_position_int(ap, t_s):
    ned, vel, lat, lon, alt = ap.estimate(t_s)
    home = ap.home_geodetic()
    rel = -ned[2] if home is not None else 0.0
    hdg = int(math.degrees(ap.mc.yaw_rad) % 360 * 100)
    return ap.mav.global_position_int_encode(
        ap.time_boot_ms(t_s), int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
        int(round(rel * 1000)), int(round(vel[0] * 100)), int(round(vel[1] * 100)),
        int(round(vel[2] * 100)), hdg)


def _local_position_ned(ap, t_s):
    ned, vel = ap.estimate_local(t_s)
    return ap.mav.local_position_ned_encode(ap.time_boot_ms(t_s), ned[0], ned[1], ned[2],
                                            vel[0], vel[1], vel[2])


def _attitude(ap, t_s):
    _ned, vel = ap.estimate_local(t_s)
    # small tilt in the direction of motion (a point mass has no attitude; this looks plausible)
    yaw = ap.mc.yaw_rad
    fwd = vel[0] * math.cos(yaw) + vel[1] * math.sin(yaw)
    right = -vel[0] * math.sin(yaw) + vel[1] * math.cos(yaw)
    return ap.mav.attitude_encode(ap.time_boot_ms(t_s), math.radians(1.5) * right,
                                  -math.radians(1.5) * fwd, yaw, 0.0, 0.0, 0.0)


def _extended_sys_state(ap, t_s):
    return ap.mav.extended_sys_state_encode(mavlink2.MAV_VTOL_STATE_UNDEFINED, ap.landed_state())


def _battery_status(ap, t_s):
    mc = ap.mc
    cells = int(mc.params.battery_cells)
    cell_mv = int(ap_flight.battery_voltage_v(ap) * 1000 / cells)
    volts = [cell_mv] * min(cells, 10) + [65535] * (10 - min(cells, 10))
    remaining = int(round(mc.battery_remaining * 100))
    return ap.mav.battery_status_encode(
        0, mavlink2.MAV_BATTERY_FUNCTION_ALL, mavlink2.MAV_BATTERY_TYPE_LIPO, 32767, volts, -1,
        -1, -1, remaining)


def _home_position(ap, t_s):
    home = ap.home_geodetic()
    if home is None:
        return None
    lat, lon, alt = home
    return ap.mav.home_position_encode(int(round(lat * 1e7)), int(round(lon * 1e7)),
                                       int(round(alt * 1000)), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                       0.0, 0.0, 0.0, int(t_s * 1e6))


def _position_target_local_ned(ap, t_s):
    echo = ap.setpoint_echo()
    if echo is None:
        return None
    _frame, mask, ned, vel, yaw, yaw_rate = echo
    return ap.mav.position_target_local_ned_encode(
        ap.time_boot_ms(t_s), mavlink2.MAV_FRAME_LOCAL_NED, mask, ned[0], ned[1], ned[2],
        vel[0], vel[1], vel[2], 0.0, 0.0, 0.0, yaw, yaw_rate)


def _position_target_global_int(ap, t_s):
    echo = ap.setpoint_echo()
    if echo is None:
        return None
    _frame, mask, ned, vel, yaw, yaw_rate = echo
    lat, lon, alt = ap.ned_to_geodetic(ned)
    return ap.mav.position_target_global_int_encode(
        ap.time_boot_ms(t_s), mavlink2.MAV_FRAME_GLOBAL_INT, mask, int(round(lat * 1e7)),
        int(round(lon * 1e7)), alt, vel[0], vel[1], vel[2], 0.0, 0.0, 0.0, yaw, yaw_rate)


def _autopilot_version(ap, t_s):
    p = ap.personality
    sw = (4 << 24) | (5 << 16) | (0 << 8) | 255 if p.name == "ardupilot" else \
        (1 << 24) | (15 << 16) | (0 << 8) | 255
    return ap.mav.autopilot_version_encode(
        p.capabilities, sw, 0, 0, 0, b"mock\0\0\0\0", b"\0" * 8, b"\0" * 8, 0x1209, 0x5741,
        ap.uid, list(ap.uid.to_bytes(8, "little")) + [0] * 10)


def _gps_global_origin(ap, t_s):
    home = ap.home_geodetic()
    if home is None:
        return None
    lat, lon, alt = home
    return ap.mav.gps_global_origin_encode(int(round(lat * 1e7)), int(round(lon * 1e7)),
                                           int(round(alt * 1000)), int(t_s * 1e6))


def _mission_current(ap, t_s):
    return ap.mav.mission_current_encode(ap.missions.current_seq)


def _vfr_hud(ap, t_s):
    ned, vel, _lat, _lon, alt = ap.estimate(t_s)
    speed = math.hypot(vel[0], vel[1])
    hdg = int(math.degrees(ap.mc.yaw_rad) % 360)
    throttle = 0 if not ap.mc.armed else 50
    return ap.mav.vfr_hud_encode(speed, speed, hdg, throttle, alt, -vel[2])


def _wind_cov(ap, t_s):
    if ap.personality.wind_msg_id != mavlink2.MAVLINK_MSG_ID_WIND_COV:
        return None
    _ned, _vel, _lat, _lon, alt = ap.estimate(t_s)
    f = wind_cov_fields(ap.wind.estimate_ned_m_s(t_s), alt)
    return ap.mav.wind_cov_encode(ap.time_boot_ms(t_s) * 1000, f["wind_x"], f["wind_y"], f["wind_z"], f["var_horiz"],
                                  f["var_vert"], f["wind_alt"], f["horiz_accuracy"], f["vert_accuracy"])


def _wind(ap, t_s):
    if ap.personality.wind_msg_id != mavlink2.MAVLINK_MSG_ID_WIND:
        return None
    f = wind_fields(ap.wind.estimate_ned_m_s(t_s))
    return ap.mav.wind_encode(f["direction"], f["speed"], f["speed_z"])


#: message id -> builder(autopilot, t_s) -> message or None (nothing to say yet)
BUILDERS = {
    mavlink2.MAVLINK_MSG_ID_HEARTBEAT: _heartbeat,
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: _sys_status,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: _gps_raw_int,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _global_position_int,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _local_position_ned,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: _attitude,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _extended_sys_state,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: _battery_status,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: _home_position,
    mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: _position_target_local_ned,
    mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT: _position_target_global_int,
    mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION: _autopilot_version,
    mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: _gps_global_origin,
    mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT: _mission_current,
    mavlink2.MAVLINK_MSG_ID_VFR_HUD: _vfr_hud,
    mavlink2.MAVLINK_MSG_ID_EKF_STATUS_REPORT: build_ekf_status_report,
    mavlink2.MAVLINK_MSG_ID_WIND_COV: _wind_cov,
    mavlink2.MAVLINK_MSG_ID_WIND: _wind,
}
#: the wind messages: each personality sends one (``Personality.wind_msg_id``)
WIND_MSG_IDS = (mavlink2.MAVLINK_MSG_ID_WIND_COV, mavlink2.MAVLINK_MSG_ID_WIND)


def build_message(ap, msg_id: int, t_s: float):
    """Build one telemetry message (None if unsupported or nothing to report yet)."""
    builder = BUILDERS.get(msg_id)
    return None if builder is None else builder(ap, t_s)
