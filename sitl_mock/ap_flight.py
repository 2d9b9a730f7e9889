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

The state (:class:`FlightState`, :class:`Setpoint`) is in :mod:`sitl_mock.ap_flight_state` and
the setpoints (frames, validation, following, echo) in :mod:`sitl_mock.ap_setpoints`; their
public names are imported from there.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock.ap_flight_state import airborne, is_ardupilot
from sitl_mock.ap_prearm import announce_prearm, ekf_problem
from sitl_mock.ap_setpoints import apply_setpoint

__all__ = [
    "apply_params", "arming_problem", "arm", "disarm", "disarm_now", "battery_level",
    "mode_change_problem", "enter_mode", "start_takeoff", "update",
]

_ARDUPILOT_LAND_DISARM_S = 1.0
_REACHED_ALT_M = 0.5


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
def battery_voltage_v(ap) -> float:
    """The pack voltage the autopilot reports: ArduPilot's ``SIM_BATT_VOLTAGE`` when it is set (> 0),
    else the pack model's."""
    forced = ap.params.get("SIM_BATT_VOLTAGE") if "SIM_BATT_VOLTAGE" in ap.params else 0.0
    return float(forced) if forced > 0 else ap.mc.battery_voltage_v


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
    if check_mode and ap.faults.arm_refused:
        return "arming check failed"
    if is_ardupilot(ap) and ap.params["ARMING_CHECK"] == 0:
        return None
    if not ap.position_ready(t_s):
        return "position estimate not ready"
    if is_ardupilot(ap):  # the EKF may not use the GPS yet (for the modes that need a position)
        problem = ekf_problem(ap, t_s, mode_name)
        if problem is not None:
            return problem
    if battery_level(ap) > 0:
        return "battery low"
    if is_ardupilot(ap) and ap.failsafe == "battery":  # latched until a reboot, as AP_BattMonitor
        return "Battery failsafe"
    if check_mode and mode_name not in ap.personality.arming_modes:
        return f"{mode_name} mode not armable"  # ArduCopter 4.7: "Arm: RTL mode not armable"
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
        prefix = "Arm: " if is_ardupilot(ap) else "Arming denied: "  # as ArduCopter 4.7 says it
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
        apply_setpoint(ap, fs.setpoint)
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
    """Disarm without checks (landing detected, failsafe, command) and announce why.

    After PX4's descent without a pilot (offboard loss, position mode without RC) the failsafe
    ends with the flight: the heartbeat shows the mode it had left again (OFFBOARD), as real
    PX4 v1.16 SIH does (tests/sitl/test_sitl_faults_px4.py, tests/conformance/test_conformance_px4_failsafes.py).
    """
    ap.mc.disarm()
    fs = ap.flight
    if fs.descent_without_pilot:
        ap.mode_name = fs.mode_before_failsafe or ap.mode_name
        fs.descent_without_pilot, fs.mode_before_failsafe = False, None
        if ap.failsafe == "offboard":
            ap.failsafe = None
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
    fs.descent_without_pilot, fs.mode_before_failsafe = False, None
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
        if ap.failsafe == "offboard":  # the setpoints are back and OFFBOARD taken again: PX4 clears it
            ap.failsafe = None
        if fs.setpoint is not None:
            apply_setpoint(ap, fs.setpoint)
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
    if is_ardupilot(ap) and not mc.armed:
        announce_prearm(ap, t_s, arming_problem(ap, t_s, ap.mode_name, check_mode=False))


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
