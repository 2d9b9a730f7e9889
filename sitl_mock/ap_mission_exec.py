"""Flying an uploaded mission (ArduPilot AUTO, PX4 AUTO.MISSION).

Supported items: NAV_TAKEOFF, NAV_WAYPOINT (with hold time), NAV_LOITER_TIME,
NAV_SPLINE_WAYPOINT (flown as a waypoint), NAV_LAND, NAV_RETURN_TO_LAUNCH; other items (DO_*,
CONDITION_*) are skipped. Each reached item is reported with MISSION_ITEM_REACHED and the next
one with MISSION_CURRENT. At the end ArduPilot holds in AUTO and PX4 switches to Hold.
"""
from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock import ap_flight

__all__ = ["step_mission", "item_target_ned"]

_NAV_WAYPOINTS = (mavlink2.MAV_CMD_NAV_WAYPOINT, mavlink2.MAV_CMD_NAV_LOITER_TIME,
                  mavlink2.MAV_CMD_NAV_SPLINE_WAYPOINT)
_LOCAL = (mavlink2.MAV_FRAME_LOCAL_NED,)
_REL = (mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)


def item_target_ned(ap, item) -> np.ndarray:
    """Target of a mission item in the vehicle's LOCAL_NED frame (lat/lon 0 = where it is)."""
    cur = ap.mc.position_ned_m
    if item.frame in _LOCAL:
        return np.array((item.x / 1e4, item.y / 1e4, item.z))
    home_alt = (ap.home or ap.home_origin)[2]
    alt = item.z + home_alt if item.frame in _REL else item.z
    if item.x == 0 and item.y == 0:
        ned = ap.geodetic_to_ned(*ap.ned_to_geodetic(cur)[:2], alt)
        return np.array((cur[0], cur[1], ned[2]))
    return ap.geodetic_to_ned(item.x / 1e7, item.y / 1e7, alt)


def _acceptance_m(ap, item) -> float:
    default = ap.params["WPNAV_RADIUS"] / 100.0 if ap.personality.name == "ardupilot" \
        else ap.params["NAV_ACC_RAD"]
    if item.command == mavlink2.MAV_CMD_NAV_WAYPOINT and item.param2 > 0:
        return float(item.param2)
    return max(default, 0.3)


def _start_item(ap, item) -> None:
    mc = ap.mc
    cmd = item.command
    if cmd == mavlink2.MAV_CMD_NAV_TAKEOFF:
        target = item_target_ned(ap, item)
        alt = max(-target[2], 1.0)
        if mc.landed:
            mc.command_takeoff(alt)
        else:
            n, e, _d = mc.position_ned_m
            mc.command_position((n, e, -alt))
        ap.flight.mission_alt_m = alt
    elif cmd in _NAV_WAYPOINTS:
        ap.flight.mission_target_ned = item_target_ned(ap, item)
        mc.command_position(ap.flight.mission_target_ned)
    elif cmd == mavlink2.MAV_CMD_NAV_LAND:
        mc.command_land()


def _item_done(ap, item, t_s: float) -> bool:
    mc = ap.mc
    fs = ap.flight
    cmd = item.command
    if cmd == mavlink2.MAV_CMD_NAV_TAKEOFF:
        return -mc.position_ned_m[2] >= fs.mission_alt_m - 0.5
    if cmd in _NAV_WAYPOINTS:
        if fs.mission_wait_until_s is not None:
            return t_s >= fs.mission_wait_until_s
        target = fs.mission_target_ned
        if np.linalg.norm(mc.position_ned_m - target) > _acceptance_m(ap, item):
            return False
        hold_s = item.param1 if cmd in (mavlink2.MAV_CMD_NAV_WAYPOINT,
                                        mavlink2.MAV_CMD_NAV_LOITER_TIME) else 0.0
        if hold_s > 0 and math.isfinite(hold_s):
            fs.mission_wait_until_s = t_s + hold_s
            return False
        return True
    if cmd == mavlink2.MAV_CMD_NAV_LAND:
        return mc.landed
    return True


def step_mission(ap, t_s: float) -> None:
    """Advance the mission by one step (call while the behaviour is ``mission``)."""
    fs = ap.flight
    missions = ap.missions
    items = missions.nav_items()
    if fs.mission_gen != missions.generation or fs.mission_gen == -1:
        fs.mission_gen = missions.generation
        start_seq = missions.current_seq
        fs.mission_idx = next((i for i, it in enumerate(items) if it.seq >= start_seq), 0)
        fs.mission_started = False
        fs.mission_wait_until_s = None
    if not ap.mc.armed:
        return
    if fs.mission_idx >= len(items):
        return
    item = items[fs.mission_idx]
    if item.command == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        ap_flight.enter_mode(ap, ap.personality.rtl_mode, t_s)
        return
    if not fs.mission_started:
        if ap.mc.landed and item.command != mavlink2.MAV_CMD_NAV_TAKEOFF and \
                item.command in _NAV_WAYPOINTS:
            return  # on the ground a mission needs a takeoff item first
        _start_item(ap, item)
        fs.mission_started = True
        return
    if not _item_done(ap, item, t_s):
        return
    ap.emit(ap.mav.mission_item_reached_encode(item.seq))
    fs.mission_idx += 1
    fs.mission_started = False
    fs.mission_wait_until_s = None
    if fs.mission_idx < len(items):
        missions.current_seq = items[fs.mission_idx].seq
        ap.emit(ap.mav.mission_current_encode(missions.current_seq))
    elif item.command != mavlink2.MAV_CMD_NAV_LAND and ap.personality.name == "px4":
        ap_flight.enter_mode(ap, ap.personality.hold_mode, t_s)
