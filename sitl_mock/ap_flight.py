"""Flight logic shared by both personalities: modes, arming, setpoints, failsafes, missions.

Functions here act on a :class:`sitl_mock.autopilot.MockAutopilot` (``ap``) and its
:class:`FlightState`; the personality decides names and result codes, these functions decide
what the vehicle does:

* GUIDED (ArduPilot): position targets are held forever; velocity targets stop after
  ``GUID_TIMEOUT`` s without a new one; setpoints are ignored on the ground (takeoff first).
* OFFBOARD (PX4): entered only while setpoints stream (last one younger than ``COM_OF_LOSS_T``);
  offboard setpoints can take off.
* failsafes (offboard loss, GCS loss, low battery, geofence) are in :mod:`sitl_mock.ap_failsafe`.
* RTL climbs to the return altitude, flies home and lands; landing disarms on touchdown.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["FlightState", "Setpoint", "apply_params", "arming_problem", "arm", "disarm",
           "disarm_now", "airborne", "is_ardupilot", "battery_level",
           "mode_change_problem", "enter_mode", "start_takeoff", "handle_setpoint",
           "setpoint_echo", "update"]

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
_ARDUPILOT_LAND_DISARM_S = 1.0
#: farthest setpoint (m from the LOCAL_NED origin, per axis; m AMSL for GLOBAL_INT altitudes)
#: followed: beyond, it is absurd and its POSITION_TARGET_* echo could not be encoded
_SETPOINT_LIMIT_M = 1.0e6
_REACHED_ALT_M = 0.5


@dataclass
class Setpoint:
    """A GCS setpoint resolved into the vehicle's LOCAL_NED frame."""

    frame: int
    type_mask: int
    ned: np.ndarray | None
    vel: np.ndarray | None
    yaw: float | None
    yaw_rate: float
    t_s: float


@dataclass
class FlightState:
    """Mutable flight-logic state of one autopilot (reset at boot)."""

    setpoint: Setpoint | None = None
    last_setpoint_s: float = -math.inf
    velocity_stopped: bool = False
    takeoff_alt_m: float | None = None
    rtl_phase: str = ""
    rtl_alt_m: float = 0.0
    mission_idx: int = 0
    mission_gen: int = -1
    mission_started: bool = False
    mission_wait_until_s: float | None = None
    idle_since_s: float | None = None
    has_flown: bool = False
    battery_level_done: int = 0
    gcs_failsafe_done: bool = False
    fence_breached: bool = False
    mission_target_ned: np.ndarray | None = None
    mission_alt_m: float = 0.0


def is_ardupilot(ap) -> bool:
    """True for the ArduPilot personality."""
    return ap.personality.name == "ardupilot"


def airborne(ap) -> bool:
    """True when armed and off the ground."""
    return ap.mc.armed and not ap.mc.landed


def apply_params(ap) -> None:
    """Copy the speed parameters into the dynamics (each vehicle owns its DynamicsParams)."""
    p, dyn = ap.params, ap.mc.params
    if is_ardupilot(ap):
        dyn.max_speed_h_m_s = p["WPNAV_SPEED"] / 100.0
        dyn.max_speed_up_m_s = p["WPNAV_SPEED_UP"] / 100.0
        dyn.max_speed_down_m_s = p["WPNAV_SPEED_DN"] / 100.0
        dyn.land_speed_m_s = p["LAND_SPEED"] / 100.0
    else:
        dyn.max_speed_h_m_s = max(p["MPC_XY_VEL_MAX"], 0.1)
        dyn.max_speed_up_m_s = p["MPC_Z_VEL_MAX_UP"]
        dyn.max_speed_down_m_s = p["MPC_Z_VEL_MAX_DN"]
        dyn.land_speed_m_s = p["MPC_LAND_SPEED"]
        dyn.takeoff_speed_m_s = p["MPC_TKO_SPEED"]


# ------------------------------------------------------------------ arming and modes
def battery_level(ap) -> int:
    """0 fine, 1 low, 2 critical, 3 emergency (per the personality's parameters)."""
    p, rem = ap.params, ap.mc.battery_remaining
    if is_ardupilot(ap):
        mah = rem * p["BATT_CAPACITY"]
        if p["BATT_CRT_MAH"] > 0 and mah <= p["BATT_CRT_MAH"]:
            return 2
        if p["BATT_LOW_MAH"] > 0 and mah <= p["BATT_LOW_MAH"]:
            return 1
        return 0
    if rem <= p["BAT_EMERGEN_THR"]:
        return 3
    if rem <= p["BAT_CRIT_THR"]:
        return 2
    return 1 if rem <= p["BAT_LOW_THR"] else 0


def arming_problem(ap, t_s: float, mode_name: str, check_mode: bool = True) -> str | None:
    """Why arming is refused now (None if it is allowed)."""
    if ap.mc.crashed:
        return "vehicle crashed"
    if is_ardupilot(ap) and ap.params["ARMING_CHECK"] == 0:
        return None
    if not ap.position_ready(t_s):
        return "position estimate not ready"
    if battery_level(ap) > 0:
        return "battery low"
    if check_mode and mode_name not in ap.personality.arming_modes:
        return f"mode {mode_name} does not allow arming"
    if check_mode and mode_name == "OFFBOARD" and \
            t_s - ap.flight.last_setpoint_s > ap.params["COM_OF_LOSS_T"]:
        return "offboard setpoints not streaming"
    return None


def arm(ap, t_s: float, forced: bool = False) -> int:
    """Arm (MAV_CMD_COMPONENT_ARM_DISARM param1 = 1); returns the MAV_RESULT."""
    if ap.mc.armed:
        return mavlink2.MAV_RESULT_ACCEPTED
    problem = None if forced and not ap.mc.crashed else arming_problem(ap, t_s, ap.mode_name)
    if problem is not None:
        prefix = "PreArm: " if is_ardupilot(ap) else "Arming denied: "
        ap.statustext(prefix + problem, mavlink2.MAV_SEVERITY_CRITICAL)
        return ap.personality.reject_result
    ap.mc.arm()
    fs = ap.flight
    fs.idle_since_s = t_s
    fs.has_flown = False
    fs.battery_level_done = 0
    b = ap.behaviour
    if b == "takeoff" and fs.takeoff_alt_m is not None:
        start_takeoff(ap, fs.takeoff_alt_m)
    elif b == "offboard" and fs.setpoint is not None:
        _apply_setpoint(ap, fs.setpoint)
    return mavlink2.MAV_RESULT_ACCEPTED


def disarm(ap, t_s: float, forced: bool = False) -> int:
    """Disarm; refused in the air unless ``forced`` (then the vehicle falls)."""
    if not ap.mc.armed:
        return mavlink2.MAV_RESULT_ACCEPTED
    if not ap.mc.landed and not forced:
        ap.statustext("Disarming denied: not landed", mavlink2.MAV_SEVERITY_CRITICAL)
        return ap.personality.reject_result
    disarm_now(ap, "command")
    return mavlink2.MAV_RESULT_ACCEPTED


def disarm_now(ap, why: str) -> None:
    """Disarm without checks (landing detected, failsafe, command) and announce why."""
    ap.mc.disarm()
    fs = ap.flight
    fs.idle_since_s = None
    fs.takeoff_alt_m = None
    fs.has_flown = False
    ap.statustext(f"Disarmed by {why}")


def mode_change_problem(ap, mode_name: str, t_s: float) -> str | None:
    """Why the autopilot refuses to enter ``mode_name`` now (None if it can)."""
    pers = ap.personality
    needs_position = mode_name in pers.position_modes
    if is_ardupilot(ap):
        # ArduCopter lets any mode be selected while disarmed
        if ap.mc.armed and needs_position and not ap.position_ready(t_s):
            return f"{mode_name} requires position"
        return None
    if needs_position and not ap.position_ready(t_s):
        return f"{mode_name} requires a position estimate"
    if mode_name == "OFFBOARD" and t_s - ap.flight.last_setpoint_s > ap.params["COM_OF_LOSS_T"]:
        return "OFFBOARD requires setpoints streaming"
    if mode_name == "AUTO.MISSION" and not ap.missions.nav_items():
        return "no mission"
    return None


def enter_mode(ap, mode_name: str, t_s: float) -> None:
    """Switch to ``mode_name`` (already validated) and start its behaviour."""
    fs = ap.flight
    previous = ap.mode_name
    ap.mode_name = mode_name
    b = ap.personality.behaviour(mode_name)
    mc = ap.mc
    if b != "rtl":
        fs.rtl_phase = ""
    if b == "hold":
        if airborne(ap):
            mc.command_hold()
    elif b == "guided":
        if previous != mode_name:
            fs.setpoint = None
        if airborne(ap) and fs.takeoff_alt_m is None:
            mc.command_hold()
    elif b == "offboard":
        if fs.setpoint is not None:
            _apply_setpoint(ap, fs.setpoint)
    elif b == "takeoff":
        if fs.takeoff_alt_m is None:
            fs.takeoff_alt_m = float(ap.params["MIS_TAKEOFF_ALT"])
        if mc.armed:
            start_takeoff(ap, fs.takeoff_alt_m)
    elif b == "land":
        if mc.armed:
            mc.command_land()
    elif b == "rtl":
        _start_rtl(ap)
    elif b == "mission":
        fs.mission_gen = -1  # restart from the current item


def start_takeoff(ap, alt_m: float) -> None:
    """Climb to ``alt_m`` metres above home (or go there if already flying)."""
    mc = ap.mc
    ap.flight.takeoff_alt_m = float(alt_m)
    if mc.landed:
        mc.command_takeoff(alt_m)
    else:
        n, e, _d = mc.position_ned_m
        mc.command_position((n, e, -alt_m))


# ------------------------------------------------------------------------ setpoints
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
    _apply_setpoint(ap, sp)


def _apply_setpoint(ap, sp: Setpoint) -> None:
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


# ---------------------------------------------------------------------- the update
def update(ap, t_s: float) -> None:
    """Per-step logic: failsafes, mode behaviours, landing and auto-disarm."""
    mc = ap.mc
    fs = ap.flight
    if mc.armed and not mc.landed:
        fs.has_flown = True
    b = ap.behaviour
    if b == "guided":
        sp = fs.setpoint
        if (sp is not None and sp.ned is None and not fs.velocity_stopped
                and t_s - sp.t_s > ap.params["GUID_TIMEOUT"]):
            mc.command_hold()
            fs.velocity_stopped = True
    elif b == "takeoff":
        if mc.armed and fs.takeoff_alt_m is not None and mc.mode != "takeoff" \
                and _reached_alt(ap, fs.takeoff_alt_m):
            fs.takeoff_alt_m = None
            enter_mode(ap, ap.personality.hold_mode, t_s)
    elif b == "rtl":
        _update_rtl(ap)
    if fs.takeoff_alt_m is not None and b == "guided" and _reached_alt(ap, fs.takeoff_alt_m):
        fs.takeoff_alt_m = None
    _auto_disarm(ap, t_s, b)


def _reached_alt(ap, alt_m: float) -> bool:
    return -ap.mc.position_ned_m[2] >= alt_m - _REACHED_ALT_M


def _auto_disarm(ap, t_s: float, b: str) -> None:
    mc = ap.mc
    fs = ap.flight
    if not (mc.armed and mc.landed and mc.mode == "idle"):
        fs.idle_since_s = None
        return
    if fs.idle_since_s is None:
        fs.idle_since_s = t_s
    if is_ardupilot(ap):
        delay = _ARDUPILOT_LAND_DISARM_S if (b in ("land", "rtl") and fs.has_flown) \
            else float(ap.params["DISARM_DELAY"])
        if delay <= 0:
            return
    else:
        delay = ap.params["COM_DISARM_LAND"] if fs.has_flown else ap.params["COM_DISARM_PRFLT"]
        if delay < 0:
            return
    if b == "takeoff" or (b == "mission" and not fs.has_flown and ap.missions.nav_items()):
        return
    if t_s - fs.idle_since_s >= delay:
        disarm_now(ap, "landing" if fs.has_flown else "auto preflight disarming")


def _start_rtl(ap) -> None:
    fs = ap.flight
    mc = ap.mc
    if not mc.armed:
        fs.rtl_phase = "done"
        return
    if mc.landed:
        fs.rtl_phase = "land"
        mc.command_land()
        return
    rtl_alt = ap.params["RTL_ALT"] / 100.0 if is_ardupilot(ap) else ap.params["RTL_RETURN_ALT"]
    fs.rtl_alt_m = max(-mc.position_ned_m[2], rtl_alt)
    fs.rtl_phase = "climb"
    n, e, _d = mc.position_ned_m
    mc.command_position((n, e, -fs.rtl_alt_m))


def _update_rtl(ap) -> None:
    fs = ap.flight
    mc = ap.mc
    if fs.rtl_phase == "climb" and _reached_alt(ap, fs.rtl_alt_m):
        fs.rtl_phase = "return"
        mc.command_position((ap.home_ned[0], ap.home_ned[1], -fs.rtl_alt_m))
    elif fs.rtl_phase == "return":
        n, e, _d = mc.position_ned_m
        if math.hypot(n - ap.home_ned[0], e - ap.home_ned[1]) < 1.0 and abs(mc.velocity_ned_m_s[0]) < 0.5:
            fs.rtl_phase = "land"
            mc.command_land()
