"""Failsafes of the mock autopilots: offboard loss, GCS loss, low battery, geofence.

Each check runs every step while armed and, when it trips, announces it (STATUSTEXT), marks
the autopilot in failsafe (HEARTBEAT system_status CRITICAL) and switches to the action its
parameters ask for:

* offboard loss (PX4): no setpoint for ``COM_OF_LOSS_T`` s in OFFBOARD -> ``COM_OBL_RC_ACT``
  (0 Position mode: as real PX4 v1.16 SIH without RC, measured by ``tests/sitl/test_sitl_faults_px4.py``
  and ``tests/conformance/test_conformance_px4_failsafes.py``, it shows ``POSCTL`` and descends at
  ``MPC_LAND_SPEED`` to the ground, lands, disarms and then shows OFFBOARD again;
  3 Return, 4 Land, otherwise Hold);
* GCS loss: no GCS heartbeat for ``FS_GCS_TIMEOUT`` (ArduPilot, heartbeats from
  ``MAV_GCS_SYSID``) or ``COM_DL_LOSS_T`` (PX4, any MAV_TYPE_GCS) -> ``FS_GCS_ENABLE`` /
  ``NAV_DLL_ACT``; only after a GCS has been heard once; PX4 holds first (below);
* low battery: ArduPilot ``BATT_LOW_MAH`` / ``BATT_CRT_MAH``, or the pack voltage (``SIM_BATT_VOLTAGE``
  when set) below ``BATT_LOW_VOLT`` / ``BATT_CRT_VOLT`` for ``BATT_LOW_TIMER`` s -> ``BATT_FS_LOW_ACT`` /
  ``BATT_FS_CRT_ACT``; PX4 ``BAT_CRIT_THR`` / ``BAT_EMERGEN_THR`` -> ``COM_LOW_BAT_ACT``;
* geofence: ArduPilot ``FENCE_ENABLE`` / ``FENCE_TYPE`` (altitude and circle bits) / ``FENCE_RADIUS`` /
  ``FENCE_ALT_MAX`` ->
  ``FENCE_ACTION`` at once; PX4 ``GF_MAX_HOR_DIST`` / ``GF_MAX_VER_DIST`` -> Hold (AUTO.LOITER, in
  failsafe) for ``COM_FAIL_ACT_T`` s (5 by default), then ``GF_ACTION`` (as real PX4 v1.16 SIH:
  AUTO.LOITER 1.0 s after the ceiling was lowered, LAND 2.6 s later at speed-up 2, docs/faults.md);
  the action is dropped if the breach is over by then.

PX4's hold before the action (:func:`_hold_first`, PX4 v1.14+ ``commander/failsafe``): a failsafe
whose action is Return or Land (data-link loss ``NAV_DLL_ACT`` 2/3, geofence ``GF_ACTION`` 3/5,
low battery ``COM_LOW_BAT_ACT``)
first holds (AUTO.LOITER, in failsafe) for ``COM_FAIL_ACT_T`` s, saying ``Failsafe activated:
entering Hold for N seconds``, then acts. Terminate acts at once (no user takeover allowed, no
delay), and so does the offboard loss: PX4 handles it as a mode fallback that allows user
takeover at any time, which arms no delay. A mode commanded during the hold (the user taking
over) drops the action; the link coming back does not (its action clears on a mode change or a
disarm only), the fence breach being over does.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock import ap_flight, ap_flight_state

__all__ = ["check_failsafes"]

#: failsafe actions by parameter value (looked up every step: built once)
_GCS_ACTIONS_ARDUPILOT = {0: "none", 2: "rtl", 5: "land", 7: "land"}      # FS_GCS_ENABLE, else rtl
_GCS_ACTIONS_PX4 = {1: "hold", 2: "rtl", 3: "land", 5: "terminate", 6: "terminate"}  # NAV_DLL_ACT, else none
_FENCE_ACTIONS_ARDUPILOT = {0: "none", 2: "land", 4: "hold", 6: "hold"}   # FENCE_ACTION, else rtl
_FENCE_ACTIONS_PX4 = {0: "none", 1: "none", 2: "hold", 3: "rtl", 4: "terminate", 5: "land"}  # GF_ACTION
#: PX4's battery check's words by warning level (1 low, 2 critical, 3 emergency)
_PX4_BATTERY_WORDS = {1: "Low battery", 2: "Critical battery", 3: "Emergency battery level"}


def check_failsafes(ap, t_s: float) -> None:
    """Run every failsafe check (call each step, before the flight logic)."""
    if not ap.mc.armed:
        return
    if ap.behaviour == "offboard" and t_s - ap.flight.last_setpoint_s > ap.params["COM_OF_LOSS_T"]:
        action = {0: "position", 3: "rtl", 4: "land"}.get(int(ap.params["COM_OBL_RC_ACT"]), "hold")
        _failsafe(ap, t_s, "offboard", action, None)  # real PX4 names no cause: "Failsafe activated" only
        _announce(ap, action)
    _check_gcs_loss(ap, t_s)
    _check_battery(ap, t_s)
    _check_fence(ap, t_s)
    _delayed_action(ap, t_s)


def _hold_first(ap, t_s: float, reason: str, action: str) -> str:
    """The action to take now for PX4's failsafe ``reason``: ``"hold"`` with ``action`` pending for
    ``COM_FAIL_ACT_T`` s when it is Return or Land (and the delay above 0.1 s, as PX4), else ``action``."""
    delay_s = 0.0 if ap_flight_state.is_ardupilot(ap) else float(ap.params["COM_FAIL_ACT_T"])
    if delay_s <= 0.1 or action not in ("rtl", "land") or not ap_flight_state.airborne(ap):
        return action
    pending = ap.flight.pending_failsafe
    if pending is None or pending[2] != reason:  # the same failsafe again keeps its running delay
        ap.flight.pending_failsafe = (action, t_s + delay_s, reason)
    return "hold"


def _announce(ap, action: str) -> None:
    """PX4's STATUSTEXT when a failsafe acts (``FailsafeBase::notifyUser``, ``mavlink_log_critical``):
    ``Failsafe activated: entering Hold for N seconds`` when it holds before its action, else
    ``Failsafe activated`` (the offboard loss, an action without delay). ArduPilot: nothing more."""
    if ap_flight_state.is_ardupilot(ap) or action == "none":
        return
    text = "Failsafe activated"
    if action == "hold" and ap.flight.pending_failsafe is not None:
        text += f": entering Hold for {round(float(ap.params['COM_FAIL_ACT_T']))} seconds"
    ap.statustext(text, mavlink2.MAV_SEVERITY_CRITICAL)


def _delayed_action(ap, t_s: float) -> None:
    """PX4: the failsafe action held back by ``COM_FAIL_ACT_T`` is taken when due, if the vehicle is
    still in that hold (no mode was commanded meanwhile) and its cause allows: a fence breach still
    there; a data-link loss even if the link came back."""
    fs = ap.flight
    if fs.pending_failsafe is None or t_s < fs.pending_failsafe[1]:
        return
    action, _, reason = fs.pending_failsafe
    fs.pending_failsafe = None
    if ap.mode_name != ap.personality.hold_mode:
        return  # a mode was commanded during the hold: the user took over, PX4 drops the action
    if reason == "fence" and ap.failsafe == "fence" and fs.fence_breached:
        _failsafe(ap, t_s, "fence", action, None)
        _announce(ap, action)
    elif reason in ("gcs", "battery"):  # a data-link loss even if the link came back; a battery never recovers
        _failsafe(ap, t_s, reason, action, None)
        _announce(ap, action)


def _failsafe(ap, t_s: float, reason: str, action: str, text: str | None) -> None:
    """Enter failsafe ``reason`` with ``action``, saying ``text`` first (None: nothing; PX4 names its
    causes with its own checks' words, :func:`_px4_says`)."""
    ap.failsafe = reason
    if text is not None:
        ap.statustext(text, mavlink2.MAV_SEVERITY_CRITICAL)
    pers = ap.personality
    if action == "none":
        return
    if action == "terminate":
        ap_flight.disarm_now(ap, "failsafe")
        return
    if action == "land" and not ap_flight_state.airborne(ap):
        if ap.mc.armed:
            ap_flight.disarm_now(ap, "failsafe")
        return
    target = {"hold": pers.hold_mode, "rtl": pers.rtl_mode, "land": pers.land_mode,
              "position": "POSCTL"}[action]
    previous = ap.mode_name
    ap_flight.enter_mode(ap, target, t_s)
    if action == "position" and ap_flight_state.airborne(ap):
        _descend_without_pilot(ap, previous)


def _descend_without_pilot(ap, previous_mode: str) -> None:
    """PX4's position mode without RC (the mock has none): it shows POSCTL but descends at
    ``MPC_LAND_SPEED`` straight down, landed state IN_AIR until ON_GROUND (not LANDING), lands and
    disarms after ``COM_DISARM_LAND``; then it shows ``previous_mode`` again (real PX4 v1.16 SIH,
    measured: 0.71 m/s, docs/faults.md)."""
    fs = ap.flight
    fs.descent_without_pilot, fs.mode_before_failsafe = True, previous_mode
    ap.mc.command_land(fast_high=False)


def _check_gcs_loss(ap, t_s: float) -> None:
    fs = ap.flight
    last = ap.last_gcs_heartbeat_s
    if last is None:
        return
    if ap_flight_state.is_ardupilot(ap):
        enable, timeout = int(ap.params["FS_GCS_ENABLE"]), ap.params["FS_GCS_TIMEOUT"]
        action = _GCS_ACTIONS_ARDUPILOT.get(enable, "rtl")
        if enable == 2 and ap.behaviour == "mission":
            action = "none"
    else:
        enable, timeout = int(ap.params["NAV_DLL_ACT"]), ap.params["COM_DL_LOSS_T"]
        action = _GCS_ACTIONS_PX4.get(enable, "none")
    lost = t_s - last > timeout
    _px4_data_link_words(ap, lost)
    pending = fs.pending_failsafe is not None and fs.pending_failsafe[2] == "gcs"
    if not lost:
        if fs.gcs_failsafe_done:
            fs.gcs_failsafe_done = False
            if ap.failsafe == "gcs" and not pending:  # a pending action keeps PX4 in failsafe
                ap.failsafe = None
        return
    if enable == 0 or fs.gcs_failsafe_done:
        return
    fs.gcs_failsafe_done = True
    action = _hold_first(ap, t_s, "gcs", action)
    _failsafe(ap, t_s, "gcs", action, "Failsafe: GCS connection lost" if ap_flight_state.is_ardupilot(ap) else None)
    _announce(ap, action)


def _px4_data_link_words(ap, lost: bool) -> None:
    """PX4's commander says when the data link is lost and regained, whatever ``NAV_DLL_ACT`` (real
    PX4 v1.16 SIH: "Connection to ground station lost" (INFO), then its health report's "Preflight
    Fail: No connection to the ground control station" (WARNING); "GCS connection regained" (INFO)).
    ArduPilot: nothing here."""
    fs = ap.flight
    if ap_flight_state.is_ardupilot(ap) or lost == fs.gcs_lost_said:
        return
    fs.gcs_lost_said = lost
    if lost:
        _px4_says(ap, ("Connection to ground station lost", mavlink2.MAV_SEVERITY_INFO),
                  ("Preflight Fail: No connection to the ground control station", mavlink2.MAV_SEVERITY_WARNING))
    else:
        _px4_says(ap, ("GCS connection regained", mavlink2.MAV_SEVERITY_INFO))


def _px4_says(ap, *texts: tuple[str, int]) -> None:
    """Each ``(text, severity)`` as a STATUSTEXT (the mock's :meth:`statustext` holds them back while PX4
    would hear no ground station)."""
    for text, severity in texts:
        ap.statustext(text, severity)


def _voltage_level(ap, t_s: float) -> int:
    """ArduPilot's voltage failsafe: 1 (2) once the pack stayed below ``BATT_LOW_VOLT``
    (``BATT_CRT_VOLT``) for ``BATT_LOW_TIMER`` s (as AP_BattMonitor; a threshold of 0 is off)."""
    p, fs = ap.params, ap.flight
    volts, timer_s = ap_flight.battery_voltage_v(ap), float(p["BATT_LOW_TIMER"])
    level = 0
    for lvl, name, attr in ((1, "BATT_LOW_VOLT", "volt_low_since_s"), (2, "BATT_CRT_VOLT", "volt_crt_since_s")):
        if not 0 < volts < p[name]:
            setattr(fs, attr, None)
            continue
        since = getattr(fs, attr)
        if since is None:
            setattr(fs, attr, t_s)
        elif t_s - since >= timer_s:
            level = lvl
    return level


def _check_battery(ap, t_s: float) -> None:
    fs = ap.flight
    level = ap_flight.battery_level(ap)
    if ap_flight_state.is_ardupilot(ap):
        level = max(level, _voltage_level(ap, t_s))
    if level <= fs.battery_level_done or not ap_flight_state.airborne(ap):
        return
    fs.battery_level_done = level
    p = ap.params
    if ap_flight_state.is_ardupilot(ap):
        act = int(p["BATT_FS_CRT_ACT"] if level >= 2 else p["BATT_FS_LOW_ACT"])
        action = {0: "none", 1: "land", 5: "terminate", 7: "land"}.get(act, "rtl")
    else:
        act = int(p["COM_LOW_BAT_ACT"])
        action = "none"
        if level >= 2 and act in (1, 3):
            action = "rtl"
        if (level >= 2 and act == 2) or (level >= 3 and act == 3):
            action = "land"
    action = _hold_first(ap, t_s, "battery", action)
    if ap_flight_state.is_ardupilot(ap):
        names = {1: "low", 2: "critical", 3: "emergency"}
        _failsafe(ap, t_s, "battery", action, f"Failsafe: battery {names[level]}")
    else:  # PX4's battery check ("Critical battery" heard on SIH before its hold; the others are its strings)
        _px4_says(ap, (_PX4_BATTERY_WORDS[level], mavlink2.MAV_SEVERITY_CRITICAL))
        _failsafe(ap, t_s, "battery", action, None)
    _announce(ap, action)


def _check_fence(ap, t_s: float) -> None:
    p = ap.params
    fs = ap.flight
    if ap_flight_state.is_ardupilot(ap):
        if not p["FENCE_ENABLE"]:
            return
        kinds = int(p["FENCE_TYPE"])
        radius = p["FENCE_RADIUS"] if kinds & 2 else math.inf
        alt_max = p["FENCE_ALT_MAX"] if kinds & 1 else math.inf
        action = _FENCE_ACTIONS_ARDUPILOT.get(int(p["FENCE_ACTION"]), "rtl")
    else:
        radius = p["GF_MAX_HOR_DIST"] or math.inf
        alt_max = p["GF_MAX_VER_DIST"] or math.inf
        if math.isinf(radius) and math.isinf(alt_max):
            return
        action = _FENCE_ACTIONS_PX4[int(p["GF_ACTION"])]
    north_m, east_m, down_m = ap.mc.position_ned_m_tuple()  # after the checks that end early: no array
    home_ned = ap.home_ned
    dist = math.hypot(north_m - home_ned[0], east_m - home_ned[1])
    alt = -down_m
    breached = dist > radius or alt > alt_max
    if not breached:
        if fs.fence_breached and dist < radius - 2.0 and alt < alt_max - 2.0:
            fs.fence_breached = False
            if ap.failsafe == "fence":
                ap.failsafe = None
        return
    if fs.fence_breached or ap.behaviour in ("rtl", "land"):
        return
    fs.fence_breached = True
    action = _hold_first(ap, t_s, "fence", action)
    if ap_flight_state.is_ardupilot(ap):
        _failsafe(ap, t_s, "fence", action, "Failsafe: geofence breached")
    else:  # PX4's geofence check, then its failsafe (real PX4 v1.16 SIH, GF_ACTION 2)
        if dist > radius:
            _px4_says(ap, ("Geofence: exceeding maximum distance to Home", mavlink2.MAV_SEVERITY_CRITICAL))
        if alt > alt_max:
            _px4_says(ap, ("Geofence: exceeding maximum altitude above Home", mavlink2.MAV_SEVERITY_CRITICAL))
        _failsafe(ap, t_s, "fence", action, None)
    _announce(ap, action)

