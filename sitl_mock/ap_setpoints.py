"""GCS setpoints of a mock autopilot: frames, validation, following and echo.

SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT are resolved into the
vehicle's LOCAL_NED frame (local, offset, body and global frames; the ``type_mask`` ignore
bits), checked (frame, mask, finite values, range) and, in GUIDED / OFFBOARD, handed to the
dynamics. :func:`setpoint_echo` gives what POSITION_TARGET_* reports. Functions act on a
:class:`sitl_mock.autopilot.MockAutopilot` (``ap``) and its
:class:`~sitl_mock.ap_flight_state.FlightState`.
"""
from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock.ap_flight_state import Setpoint, is_ardupilot

__all__ = ["handle_setpoint", "apply_setpoint", "setpoint_echo"]

_POS_IGNORE = 0b111
_VEL_IGNORE = 0b111000
_YAW_IGNORE = 1024
_YAW_RATE_IGNORE = 2048
_LOCAL_FRAMES = {mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_LOCAL_OFFSET_NED,
                 mavlink2.MAV_FRAME_BODY_NED, mavlink2.MAV_FRAME_BODY_OFFSET_NED,
                 mavlink2.MAV_FRAME_BODY_FRD}
_AMSL_FRAMES = {mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_INT}
_REL_FRAMES = {mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
               mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
#: farthest setpoint (m from the LOCAL_NED origin, per axis; m AMSL for GLOBAL_INT altitudes)
#: followed: beyond, it is absurd and its POSITION_TARGET_* echo could not be encoded
_SETPOINT_LIMIT_M = 1.0e6


def _resolve_local(ap, msg, ignore: int):
    frame = msg.coordinate_frame
    mc = ap.mc
    yaw = mc.yaw_rad
    c, s = math.cos(yaw), math.sin(yaw)
    pos = vel = None
    if not ignore & _POS_IGNORE == _POS_IGNORE:
        cur = mc.position_ned_m
        raw = np.array((msg.x, msg.y, msg.z), dtype=float)
        if frame in (mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_NED):
            pos = raw
        elif frame == mavlink2.MAV_FRAME_LOCAL_OFFSET_NED:
            pos = cur + raw
        else:  # BODY_OFFSET_NED, BODY_FRD: offset in the heading frame
            pos = cur + np.array((c * raw[0] - s * raw[1], s * raw[0] + c * raw[1], raw[2]))
        for i, bit in enumerate((1, 2, 4)):
            if ignore & bit:
                pos[i] = cur[i]
    if not ignore & _VEL_IGNORE == _VEL_IGNORE:
        raw = np.array((msg.vx, msg.vy, msg.vz), dtype=float)
        for i, bit in enumerate((8, 16, 32)):
            if ignore & bit:
                raw[i] = 0.0
        if frame in (mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_LOCAL_OFFSET_NED):
            vel = raw
        else:
            vel = np.array((c * raw[0] - s * raw[1], s * raw[0] + c * raw[1], raw[2]))
    return pos, vel


def _global_out_of_range(msg, ignore: int) -> bool:
    """True when a GLOBAL_INT position is off the Earth or its (finite) altitude is absurd."""
    if ignore & _POS_IGNORE == _POS_IGNORE:
        return False
    return (abs(msg.lat_int) > 900_000_000 or abs(msg.lon_int) > 1_800_000_000
            or (math.isfinite(msg.alt) and abs(msg.alt) > _SETPOINT_LIMIT_M))


def _resolve_global(ap, msg, ignore: int):
    frame = msg.coordinate_frame
    pos = vel = None
    if not ignore & _POS_IGNORE == _POS_IGNORE:
        lat, lon = msg.lat_int / 1e7, msg.lon_int / 1e7
        alt = float(msg.alt)
        if frame in _REL_FRAMES:
            alt += (ap.home or ap.home_origin)[2]
        pos = ap.geodetic_to_ned(lat, lon, alt)
        cur = ap.mc.position_ned_m
        for i, bit in enumerate((1, 2, 4)):
            if ignore & bit:
                pos[i] = cur[i]
    if not ignore & _VEL_IGNORE == _VEL_IGNORE:
        vel = np.array((msg.vx, msg.vy, msg.vz), dtype=float)
        for i, bit in enumerate((8, 16, 32)):
            if ignore & bit:
                vel[i] = 0.0
    return pos, vel


def handle_setpoint(ap, msg, t_s: float) -> None:
    """SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT: store, and follow in GUIDED / OFFBOARD.

    Rejected and counted: an unsupported frame or mask, non-finite values
    (``setpoint_not_finite``), a position off the Earth or farther than 1e6 m on an axis
    (``setpoint_out_of_range``).
    """
    ignore = msg.type_mask
    is_local = msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    frames = _LOCAL_FRAMES if is_local else (_AMSL_FRAMES | _REL_FRAMES)
    if msg.coordinate_frame not in frames:
        ap.counters["setpoint_bad_frame"] += 1
        return
    if not is_local and _global_out_of_range(msg, ignore):
        ap.counters["setpoint_out_of_range"] += 1
        return
    pos, vel = (_resolve_local if is_local else _resolve_global)(ap, msg, ignore)
    if pos is None and vel is None:
        ap.counters["setpoint_unsupported_mask"] += 1
        return
    if (pos is not None and not np.all(np.isfinite(pos))) or \
            (vel is not None and not np.all(np.isfinite(vel))):
        ap.counters["setpoint_not_finite"] += 1
        return
    if pos is not None and np.any(np.abs(pos) > _SETPOINT_LIMIT_M):
        ap.counters["setpoint_out_of_range"] += 1
        return
    yaw = None if ignore & _YAW_IGNORE or not math.isfinite(msg.yaw) else float(msg.yaw)
    yaw_rate = 0.0 if ignore & _YAW_RATE_IGNORE or not math.isfinite(msg.yaw_rate) else msg.yaw_rate
    sp = Setpoint(msg.coordinate_frame, ignore, pos, vel, yaw, float(yaw_rate), t_s)
    fs = ap.flight
    fs.last_setpoint_s = t_s
    b = ap.behaviour
    if b not in ("guided", "offboard"):
        fs.setpoint = sp  # PX4 keeps the latest for switching into OFFBOARD
        ap.counters["setpoint_not_in_guided"] += 1
        return
    fs.setpoint = sp
    apply_setpoint(ap, sp)


def apply_setpoint(ap, sp: Setpoint) -> None:
    """Follow ``sp`` if armed (ArduCopter: not on the ground before a takeoff)."""
    mc = ap.mc
    fs = ap.flight
    if not mc.armed:
        return
    if is_ardupilot(ap) and mc.landed and fs.takeoff_alt_m is None:
        ap.counters["setpoint_on_ground"] += 1  # ArduCopter needs a takeoff first
        return
    if sp.ned is not None:
        mc.command_position(sp.ned, sp.yaw, sp.vel)
    else:
        mc.command_velocity(sp.vel, sp.yaw)
    fs.takeoff_alt_m = None
    fs.velocity_stopped = False


def setpoint_echo(ap):
    """``(frame, type_mask, ned, vel, yaw, yaw_rate)`` of the followed setpoint, or None."""
    sp = ap.flight.setpoint
    if sp is None or ap.behaviour not in ("guided", "offboard"):
        return None
    ned = sp.ned if sp.ned is not None else ap.mc.position_ned_m
    vel = sp.vel if sp.vel is not None else np.zeros(3)
    return (sp.frame, sp.type_mask, ned, vel, sp.yaw if sp.yaw is not None else 0.0, sp.yaw_rate)
