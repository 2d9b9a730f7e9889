"""COMMAND_LONG / COMMAND_INT / SET_MODE handling with honest COMMAND_ACK results.

Results follow the real autopilots: ACCEPTED; UNSUPPORTED for commands the mock does not know;
the personality's rejection (ArduPilot ``FAILED``, PX4 ``TEMPORARILY_REJECTED``) when a
precondition fails (arming checks, takeoff while disarmed or not in GUIDED, mode change refused,
disarm in the air); ``DENIED`` for invalid arguments (non-finite or out-of-range home, unknown
message id, a message interval beyond the int32 range, mission start without a mission). A
mode the autopilot does not have: ArduPilot ``FAILED``; PX4 ACKs ``ACCEPTED`` and changes
nothing for an unknown main mode (as its commander does) but rejects an unknown AUTO sub mode.
An arm/disarm param1 other than 0 or 1: ``UNSUPPORTED``. MAV_CMD_REQUEST_PROTOCOL_VERSION:
``UNSUPPORTED`` (pymavlink 2.4.50's ardupilotmega dialect has no PROTOCOL_VERSION message).
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock import ap_flight
from sitl_mock.ap_telemetry import BUILDERS, MAX_INTERVAL_US, build_message

__all__ = ["handle_command", "handle_set_mode", "handle_request_data_stream", "COMMANDS"]

_M = mavlink2
_ACCEPTED = _M.MAV_RESULT_ACCEPTED
_DENIED = _M.MAV_RESULT_DENIED
_UNSUPPORTED = _M.MAV_RESULT_UNSUPPORTED
_FORCE_MAGIC = 21196
#: altitudes (m AMSL) accepted for a new home: HOME_POSITION.altitude is an int32 in mm
_HOME_ALT_RANGE_M = (-1.0e4, 1.0e5)


def _params(msg) -> list[float]:
    if msg.get_type() == "COMMAND_INT":
        return [msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7, msg.y / 1e7, msg.z]
    return [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]


def _ack(ap, msg, command: int, result: int) -> None:
    ap.emit(ap.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(),
                                      msg.get_srcComponent()))


def handle_command(ap, msg, t_s: float) -> None:
    """Execute a COMMAND_LONG / COMMAND_INT and send its COMMAND_ACK."""
    p = _params(msg)
    handler = COMMANDS.get(msg.command)
    if handler is None:
        ap.counters["cmd_unsupported"] += 1
        _ack(ap, msg, msg.command, _UNSUPPORTED)
        return
    result = handler(ap, p, t_s, msg)
    if result is not None:
        _ack(ap, msg, msg.command, result)


def handle_set_mode(ap, msg, t_s: float) -> None:
    """SET_MODE message (acknowledged as MAV_CMD_DO_SET_MODE, as both autopilots do)."""
    cm = msg.custom_mode
    if ap.personality.name == "px4":
        result = _set_mode(ap, msg.base_mode, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF, t_s)
    else:
        result = _set_mode(ap, msg.base_mode, cm, 0, t_s)
    _ack(ap, msg, _M.MAV_CMD_DO_SET_MODE, result)


def _set_mode(ap, base_mode, p2, p3, t_s: float) -> int:
    if not all(math.isfinite(v) for v in (base_mode, p2, p3)):
        return _DENIED
    name = ap.personality.mode_from_command(base_mode, p2, p3)
    if not name:
        if ap.personality.name == "ardupilot":
            ap.statustext(f"No such mode {int(p2)}", _M.MAV_SEVERITY_WARNING)  # as ArduCopter 4.7
        elif name is not None:  # PX4 says nothing about an unknown main mode (it ACKs it ACCEPTED)
            ap.statustext("Unsupported mode", _M.MAV_SEVERITY_WARNING)
        return ap.personality.unknown_mode_result if name is None else ap.personality.reject_result
    problem = ap_flight.mode_change_problem(ap, name, t_s)
    if problem is not None:
        ap.statustext(f"Mode change failed: {problem}", _M.MAV_SEVERITY_WARNING)
        return ap.personality.reject_result
    if name != ap.mode_name or ap.behaviour in ("hold",):
        ap_flight.enter_mode(ap, name, t_s)
    return _ACCEPTED


def _cmd_set_mode(ap, p, t_s, msg):
    return _set_mode(ap, p[0], p[1], p[2], t_s)


def _cmd_arm_disarm(ap, p, t_s, msg):
    action = p[0]
    forced = math.isfinite(p[1]) and int(round(p[1])) == _FORCE_MAGIC
    if action == 1.0:
        return ap_flight.arm(ap, t_s, forced)
    if action == 0.0:
        return ap_flight.disarm(ap, t_s, forced)
    return _UNSUPPORTED  # as both autopilots answer a param1 other than 0 / 1


def _cmd_takeoff(ap, p, t_s, msg):
    mc = ap.mc
    alt_param = p[6]
    if ap.personality.name == "ardupilot":
        # ArduCopter: GUIDED (user takeoff), armed, on the ground; param7 = metres above home
        if not mc.armed or not mc.landed or ap.behaviour != "guided":
            why = "not armed" if not mc.armed else ("already flying" if not mc.landed
                                                    else f"not in GUIDED ({ap.mode_name})")
            ap.statustext(f"Takeoff refused: {why}", _M.MAV_SEVERITY_WARNING)
            return ap.personality.reject_result
        if not (math.isfinite(alt_param) and alt_param > 0):
            return ap.personality.reject_result  # ArduCopter cannot take off downwards
        ap_flight.start_takeoff(ap, alt_param)
        return _ACCEPTED
    # PX4: switch to AUTO.TAKEOFF; param7 is AMSL (NaN: MIS_TAKEOFF_ALT above home)
    problem = ap_flight.mode_change_problem(ap, "AUTO.TAKEOFF", t_s)
    if problem is not None:
        ap.statustext(f"Takeoff refused: {problem}", _M.MAV_SEVERITY_WARNING)
        return ap.personality.reject_result
    home_alt = (ap.home or ap.home_origin)[2]
    if math.isfinite(alt_param) and alt_param - home_alt > 0.5:
        alt = alt_param - home_alt
    else:
        alt = float(ap.params["MIS_TAKEOFF_ALT"])
    ap.flight.takeoff_alt_m = max(alt, 1.0)
    ap_flight.enter_mode(ap, "AUTO.TAKEOFF", t_s)
    return _ACCEPTED


def _cmd_run_prearm_checks(ap, p, t_s, msg):
    """ArduPilot: run the pre-arm checks for the current mode, report a failure as ``PreArm:``."""
    if ap.personality.name != "ardupilot":
        ap.counters["cmd_unsupported"] += 1
        return _UNSUPPORTED
    if ap.mc.armed:
        return ap.personality.reject_result
    problem = ap_flight.arming_problem(ap, t_s, ap.mode_name, check_mode=False)
    if problem is not None:
        ap.statustext(f"PreArm: {problem}", _M.MAV_SEVERITY_CRITICAL)
    return _ACCEPTED


def _cmd_land(ap, p, t_s, msg):
    return _change_to(ap, ap.personality.land_mode, t_s)


def _cmd_rtl(ap, p, t_s, msg):
    return _change_to(ap, ap.personality.rtl_mode, t_s)


def _change_to(ap, name: str, t_s: float) -> int:
    problem = ap_flight.mode_change_problem(ap, name, t_s)
    if problem is not None:
        ap.statustext(f"Mode change failed: {problem}", _M.MAV_SEVERITY_WARNING)
        return ap.personality.reject_result
    ap_flight.enter_mode(ap, name, t_s)
    return _ACCEPTED


def _msg_id(value: float) -> int | None:
    if not math.isfinite(value) or value < 0 or value != int(value):
        return None
    return int(value)


def _cmd_request_message(ap, p, t_s, msg):
    msg_id = _msg_id(p[0])
    if msg_id is None or msg_id not in BUILDERS:
        return _DENIED
    reply = build_message(ap, msg_id, t_s)
    if reply is None:  # known message, nothing to say yet (e.g. HOME_POSITION before a fix)
        ap.counters["request_unavailable"] += 1
        return ap.personality.reject_result
    _ack(ap, msg, msg.command, _ACCEPTED)
    ap.emit(reply)
    return None


def _cmd_request_capabilities(ap, p, t_s, msg):
    _ack(ap, msg, msg.command, _ACCEPTED)
    ap.send_message_now(_M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, t_s)
    return None


def _cmd_set_message_interval(ap, p, t_s, msg):
    msg_id = _msg_id(p[0])
    if msg_id is None or not math.isfinite(p[1]) or p[1] > MAX_INTERVAL_US:
        return _DENIED  # MESSAGE_INTERVAL.interval_us is an int32: larger cannot be reported
    if not ap.scheduler.set_interval(msg_id, p[1], t_s):
        return _M.MAV_RESULT_FAILED if ap.personality.name == "ardupilot" else _DENIED
    return _ACCEPTED


def _cmd_get_message_interval(ap, p, t_s, msg):
    msg_id = _msg_id(p[0])
    if msg_id is None:
        return _DENIED
    _ack(ap, msg, msg.command, _ACCEPTED)
    ap.emit(ap.mav.message_interval_encode(msg_id, ap.scheduler.interval_us(msg_id)))
    return None


def _valid_home(lat_deg: float, lon_deg: float, alt_m: float) -> bool:
    """True for a home HOME_POSITION can carry (finite, on Earth, alt within _HOME_ALT_RANGE_M)."""
    return (all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)) and -90 <= lat_deg <= 90
            and -180 <= lon_deg <= 180 and _HOME_ALT_RANGE_M[0] <= alt_m <= _HOME_ALT_RANGE_M[1])


def _cmd_set_home(ap, p, t_s, msg):
    if ap.home is None:
        return ap.personality.reject_result
    use_current = p[0] > 0.5
    lat, lon, alt = ap.ned_to_geodetic(ap.mc.position_ned_m) if use_current else (p[4], p[5], p[6])
    if not _valid_home(lat, lon, alt):  # checked before anything changes: HOME_POSITION must pack
        return _DENIED
    ned = ap.mc.position_ned_m if use_current else ap.geodetic_to_ned(lat, lon, alt)
    ap.home = (float(lat), float(lon), float(alt))
    ap.home_ned = ned
    ap.send_message_now(_M.MAVLINK_MSG_ID_HOME_POSITION, t_s)
    return _ACCEPTED


def _cmd_mission_start(ap, p, t_s, msg):
    if not ap.missions.nav_items():
        return _DENIED
    if ap.personality.name == "px4":
        result = _change_to(ap, "AUTO.MISSION", t_s)
        if result == _ACCEPTED and not ap.mc.armed:
            result = ap_flight.arm(ap, t_s)
        return result
    if not ap.mc.armed:
        return ap.personality.reject_result
    return _change_to(ap, "AUTO", t_s)


def _cmd_reposition(ap, p, t_s, msg):
    lat, lon, alt = p[4], p[5], p[6]
    if not (math.isfinite(lat) and math.isfinite(lon)):
        return _DENIED
    if not math.isfinite(alt):
        alt = ap.ned_to_geodetic(ap.mc.position_ned_m)[2]
    elif msg.get_type() == "COMMAND_INT" and msg.frame in (
            _M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, _M.MAV_FRAME_GLOBAL_RELATIVE_ALT):
        alt += (ap.home or ap.home_origin)[2]
    hold = ap.personality.hold_mode if ap.personality.name == "px4" else "GUIDED"
    result = _change_to(ap, hold, t_s)
    if result == _ACCEPTED and ap.mc.armed and not ap.mc.landed:
        ap.mc.command_position(ap.geodetic_to_ned(lat, lon, alt))
    return result


def _cmd_change_speed(ap, p, t_s, msg):
    speed = p[1]
    if not (math.isfinite(speed) and speed > 0):
        return _DENIED
    ap.mc.params.max_speed_h_m_s = float(speed)
    return _ACCEPTED


def _cmd_condition_yaw(ap, p, t_s, msg):
    angle = p[0]
    if not math.isfinite(angle):
        return _DENIED
    yaw = math.radians(angle) if p[3] == 0 else ap.mc.yaw_rad + math.radians(angle) * (
        -1 if p[2] < 0 else 1)
    mc = ap.mc
    if mc.armed and not mc.landed:
        target = mc.position_target_ned_m
        mc.command_position(target if target is not None else mc.position_ned_m, yaw)
    return _ACCEPTED


def _cmd_reboot(ap, p, t_s, msg):
    if p[0] == 0:
        return _ACCEPTED
    if p[0] != 1 or ap.mc.armed:
        return _DENIED if p[0] != 1 else ap.personality.reject_result
    _ack(ap, msg, msg.command, _ACCEPTED)
    ap.reboot(t_s)
    return None


#: MAV_CMD -> handler(ap, params[7], t_s, msg) -> MAV_RESULT (None: ACK already sent)
COMMANDS = {
    _M.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm_disarm,
    _M.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
    _M.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
    _M.MAV_CMD_NAV_LAND: _cmd_land,
    _M.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
    _M.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
    _M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_request_capabilities,
    _M.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_message_interval,
    _M.MAV_CMD_GET_MESSAGE_INTERVAL: _cmd_get_message_interval,
    _M.MAV_CMD_DO_SET_HOME: _cmd_set_home,
    _M.MAV_CMD_MISSION_START: _cmd_mission_start,
    _M.MAV_CMD_DO_REPOSITION: _cmd_reposition,
    _M.MAV_CMD_DO_CHANGE_SPEED: _cmd_change_speed,
    _M.MAV_CMD_CONDITION_YAW: _cmd_condition_yaw,
    _M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: _cmd_reboot,
    _M.MAV_CMD_RUN_PREARM_CHECKS: _cmd_run_prearm_checks,
}

_STREAM_GROUPS = {
    _M.MAV_DATA_STREAM_EXTENDED_STATUS: (_M.MAVLINK_MSG_ID_SYS_STATUS, _M.MAVLINK_MSG_ID_GPS_RAW_INT,
                                         _M.MAVLINK_MSG_ID_MISSION_CURRENT),
    _M.MAV_DATA_STREAM_POSITION: (_M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                  _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    _M.MAV_DATA_STREAM_EXTRA1: (_M.MAVLINK_MSG_ID_ATTITUDE,),
    _M.MAV_DATA_STREAM_EXTRA2: (_M.MAVLINK_MSG_ID_VFR_HUD,),
    _M.MAV_DATA_STREAM_EXTRA3: (_M.MAVLINK_MSG_ID_WIND,),
}


def handle_request_data_stream(ap, msg, t_s: float) -> None:
    """Legacy REQUEST_DATA_STREAM (ArduPilot's SRx groups); PX4 ignores it."""
    if ap.personality.name != "ardupilot":
        ap.counters["rx_unhandled"] += 1
        return
    groups = list(_STREAM_GROUPS) if msg.req_stream_id == _M.MAV_DATA_STREAM_ALL \
        else [msg.req_stream_id]
    rate = msg.req_message_rate if msg.start_stop else 0
    for g in groups:
        for msg_id in _STREAM_GROUPS.get(g, ()):
            ap.scheduler.set_interval(msg_id, 1e6 / rate if rate > 0 else -1, t_s)
