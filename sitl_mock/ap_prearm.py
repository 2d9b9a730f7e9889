"""The mock ArduPilot's EKF start-up: a GPS fix first, an EKF that uses it later.

ArduCopter SITL (4.7, measured with ``run_arducopter.sh`` at speed-up 1) has a GPS fix about
9 s after boot and a home at 19 s, but its EKF starts using the GPS only at about 40 s: until
then EKF_STATUS_REPORT.flags is ``0xa7`` (attitude, velocities, vertical position, constant
position mode: no absolute horizontal position) and arming in GUIDED is refused with
``Arm: Need Position Estimate`` (MAV_RESULT_FAILED); a ``PreArm: Need Position Estimate`` text
repeats every 30 s while disarmed; afterwards the flags are ``0x33f``. The SYS_STATUS pre-arm
bit reflects the checks of the *current* mode: in STABILIZE it can read healthy while GUIDED
would still be refused.

The mock does the same after its own GPS warm-up (``DynamicsParams.gps_warmup_s``), for the
mock-only parameter ``SIM_EKF_GPS_S`` seconds (default 0: no delay, so ordinary tests stay fast).
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["EKF_FLAGS_NO_GPS", "EKF_FLAGS_OK", "ekf_ready", "ekf_flags", "ekf_problem",
           "build_ekf_status_report", "announce_prearm", "PREARM_REPORT_INTERVAL_S"]

_M = mavlink2
#: EKF_STATUS_REPORT.flags before the EKF uses the GPS (as ArduCopter SITL reports)
EKF_FLAGS_NO_GPS = 0xA7
#: ... and once it does
EKF_FLAGS_OK = 0x33F
#: a failing pre-arm check is announced this often while disarmed (ArduPilot: 30 s)
PREARM_REPORT_INTERVAL_S = 30.0
_NEED_POSITION = "Need Position Estimate"


def ekf_ready(ap, t_s: float) -> bool:
    """True once the EKF uses the GPS: GPS warm-up plus ``SIM_EKF_GPS_S`` after boot (ArduPilot);
    for PX4 the position estimate itself."""
    if not ap.position_ready(t_s):
        return False
    if ap.personality.name != "ardupilot" or "SIM_EKF_GPS_S" not in ap.params:
        return True
    delay_s = float(ap.params["SIM_EKF_GPS_S"])
    return t_s - ap.t_boot_s >= ap.mc.params.gps_warmup_s + delay_s


def ekf_flags(ap, t_s: float) -> int:
    """EKF_STATUS_REPORT.flags now."""
    flags = EKF_FLAGS_OK if ekf_ready(ap, t_s) else EKF_FLAGS_NO_GPS
    if ap.faults.gps_glitch_m:
        flags |= _M.EKF_GPS_GLITCHING
    return flags


def ekf_problem(ap, t_s: float, mode_name: str) -> str | None:
    """``"Need Position Estimate"`` when ``mode_name`` needs a position and the EKF has none yet."""
    if mode_name in ap.personality.position_modes and not ekf_ready(ap, t_s):
        return _NEED_POSITION
    return None


def build_ekf_status_report(ap, t_s: float):
    """EKF_STATUS_REPORT (ArduPilot only; PX4 has no such message: None)."""
    if ap.personality.name != "ardupilot":
        return None
    ok = ekf_ready(ap, t_s)
    pos_var = 0.02 if ok else 0.0
    return ap.mav.ekf_status_report_encode(ekf_flags(ap, t_s), 0.02, pos_var, 0.02, 0.03, 0.0)


def announce_prearm(ap, t_s: float, problem: str | None) -> None:
    """While disarmed with a failing check, send ``PreArm: <problem>`` every
    :data:`PREARM_REPORT_INTERVAL_S` (ArduPilot); ``problem`` None resets the timer."""
    fs = ap.flight
    if problem is None or ap.mc.armed or ap.personality.name != "ardupilot":
        fs.prearm_report_s = None
        return
    if fs.prearm_report_s is None:
        fs.prearm_report_s = t_s  # the first report comes one interval after the failure starts
        return
    if t_s - fs.prearm_report_s >= PREARM_REPORT_INTERVAL_S:
        fs.prearm_report_s = t_s
        ap.statustext(f"PreArm: {problem}", _M.MAV_SEVERITY_CRITICAL)
