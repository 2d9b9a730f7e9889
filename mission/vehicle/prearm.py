"""The autopilot's own pre-arm state, read from its telemetry (no command is sent here).

A vehicle can be connected, have a GPS fix, a home and report MAV_STATE_STANDBY and still refuse
to arm: ArduCopter SITL refuses ``Need Position Estimate`` for about 40 s after boot, until its
EKF uses the GPS. :class:`PrearmStatus` keeps what the autopilot says about itself:

* SYS_STATUS ``onboard_control_sensors_present / enabled / health``: an enabled sensor that is
  not healthy, and in particular the pre-arm check bit ``MAV_SYS_STATUS_PREARM_CHECK`` (both
  autopilots set it; ArduPilot runs its checks for the *current* mode, so in STABILIZE right
  after boot the bit can read healthy while arming in GUIDED is still refused);
* EKF_STATUS_REPORT flags (ArduPilot): the estimate needs an absolute horizontal position (now
  and predicted), no constant-position mode, no GPS glitch: the condition behind ``Need
  Position Estimate`` whatever the current mode;
* ESTIMATOR_STATUS flags (PX4), when the vehicle sends them;
* the last ``PreArm:`` / ``Arm:`` STATUSTEXT, to show the operator the autopilot's own words.

:meth:`PrearmStatus.problems` turns that into a list of reasons (empty: the autopilot is ready
as far as its telemetry tells). ``mission.flight.readiness_autopilot`` waits on it.
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["PrearmStatus", "EKF_NEEDED", "ESTIMATOR_NEEDED", "extra_rates_hz", "sensor_names",
           "PREARM_TEXT_PREFIXES"]

_M = mavlink
PREARM_BIT = _M.MAV_SYS_STATUS_PREARM_CHECK
#: EKF_STATUS_REPORT flags ArduCopter needs to arm in GUIDED (its "Need Position Estimate")
EKF_NEEDED = (_M.EKF_ATTITUDE | _M.EKF_VELOCITY_HORIZ | _M.EKF_VELOCITY_VERT | _M.EKF_POS_HORIZ_ABS
              | _M.EKF_POS_VERT_ABS | _M.EKF_PRED_POS_HORIZ_ABS)
_EKF_BAD = _M.EKF_CONST_POS_MODE | _M.EKF_UNINITIALIZED | _M.EKF_GPS_GLITCHING
#: ESTIMATOR_STATUS flags PX4 needs for position control
ESTIMATOR_NEEDED = (_M.ESTIMATOR_ATTITUDE | _M.ESTIMATOR_VELOCITY_HORIZ | _M.ESTIMATOR_POS_HORIZ_ABS
                    | _M.ESTIMATOR_POS_VERT_ABS)
#: (not CONST_POS_MODE: PX4 v1.16 SIH reports it together with POS_HORIZ_ABS, flags 0x3ff, and
#: arms and flies offboard; POS_HORIZ_ABS, required above, is what position control needs)
_ESTIMATOR_BAD = _M.ESTIMATOR_GPS_GLITCH | _M.ESTIMATOR_ACCEL_ERROR
#: sensors whose bad health the autopilot itself may fly with: no RC receiver (an offboard / guided
#: mission without a pilot; PX4 SITL reports it present, enabled and unhealthy). Reported, not
#: blocking: the autopilot's own PREARM_CHECK bit and its refusals decide.
_NOT_BLOCKING = _M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER
#: STATUSTEXT prefixes of pre-arm / arming refusals (ArduPilot "PreArm:", "Arm:"; PX4 "Preflight Fail:",
#: "Arming denied")
PREARM_TEXT_PREFIXES = ("PreArm:", "Arm:", "Preflight Fail", "Preflight fail", "Arming denied")
#: a refusal text older than this (clock seconds) is no longer shown as the current reason
_TEXT_FRESH_S = 45.0


def extra_rates_hz(flavour: str) -> dict[str, float]:
    """Telemetry the pre-arm state needs beyond the mission's rates, per autopilot flavour."""
    if flavour == "ardupilot":
        return {"EKF_STATUS_REPORT": 1.0}
    return {}


def sensor_names(bits: int) -> list[str]:
    """Short names of the MAV_SYS_STATUS_SENSOR bits set in ``bits`` (``"GPS"``, ``"PREARM_CHECK"``...)."""
    out = []
    for value, entry in sorted(_M.enums["MAV_SYS_STATUS_SENSOR"].items()):
        if value and value & bits and value & (value - 1) == 0:
            out.append(entry.name.replace("MAV_SYS_STATUS_SENSOR_", "").replace("MAV_SYS_STATUS_", ""))
    return out


def _flag_names(enum: str, flags: int, prefix: str) -> str:
    names = [e.name.replace(prefix, "") for v, e in sorted(_M.enums[enum].items())
             if v and v & flags and v & (v - 1) == 0]
    return "|".join(names) or "none"


class PrearmStatus:
    """What one vehicle's autopilot reports about its own readiness to arm.

    Parameters
    ----------
    flavour : str
        ``"ardupilot"``, ``"px4"`` or ``"generic"``.

    Attributes
    ----------
    present, enabled, health : int or None
        The SYS_STATUS sensor bit fields (None until the first SYS_STATUS).
    ekf_flags : int or None
        EKF_STATUS_REPORT.flags (ArduPilot), None until received.
    estimator_flags : int or None
        ESTIMATOR_STATUS.flags (PX4), None until received.
    last_refusal : tuple of (float, str) or None
        Clock time and text of the last pre-arm / arming refusal STATUSTEXT.
    """

    def __init__(self, flavour: str) -> None:
        self.flavour = flavour
        self.present: int | None = None
        self.enabled: int | None = None
        self.health: int | None = None
        self.ekf_flags: int | None = None
        self.estimator_flags: int | None = None
        self.last_refusal: tuple[float, str] | None = None

    def handlers(self, clock) -> dict:
        """Message id -> handler(msg) for the messages this status reads (``clock``: for the texts)."""
        return {
            _M.MAVLINK_MSG_ID_SYS_STATUS: self.on_sys_status,
            _M.MAVLINK_MSG_ID_EKF_STATUS_REPORT: self.on_ekf_status,
            _M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self.on_estimator_status,
            _M.MAVLINK_MSG_ID_STATUSTEXT: lambda msg: self.on_statustext(msg, clock.time()),
        }

    def on_sys_status(self, msg) -> None:
        """Keep the SYS_STATUS sensor bits."""
        self.present = int(msg.onboard_control_sensors_present)
        self.enabled = int(msg.onboard_control_sensors_enabled)
        self.health = int(msg.onboard_control_sensors_health)

    def on_ekf_status(self, msg) -> None:
        """Keep EKF_STATUS_REPORT.flags."""
        self.ekf_flags = int(msg.flags)

    def on_estimator_status(self, msg) -> None:
        """Keep ESTIMATOR_STATUS.flags."""
        self.estimator_flags = int(msg.flags)

    def on_statustext(self, msg, t_s: float) -> None:
        """Keep the last pre-arm / arming refusal text."""
        text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("utf-8", "replace")
        text = text.rstrip("\x00").strip()
        if text.startswith(PREARM_TEXT_PREFIXES):
            self.last_refusal = (t_s, text)

    def autopilot_says(self, now_s: float) -> str | None:
        """The last refusal text if it is recent (``_TEXT_FRESH_S``), else None."""
        if self.last_refusal is None or now_s - self.last_refusal[0] > _TEXT_FRESH_S:
            return None
        return self.last_refusal[1]

    def prearm_check_fails(self) -> bool:
        """True when SYS_STATUS says the pre-arm checks are enabled and unhealthy."""
        return self.health is not None and bool((self.enabled or 0) & ~self.health & PREARM_BIT)

    def notes(self) -> list[str]:
        """What the autopilot reports unhealthy but flies with (:data:`_NOT_BLOCKING`): warnings."""
        if self.health is None:
            return []
        bad = (self.enabled or 0) & ~self.health & _NOT_BLOCKING
        return [f"{', '.join(sensor_names(bad))} unhealthy (no RC link? the autopilot's own failsafes "
                "decide; see docs/field-checklist.md)"] if bad else []

    def problems(self, now_s: float | None = None) -> list[str]:
        """Why the autopilot is not ready to arm, as far as its telemetry says (empty: ready).

        The last refusal STATUSTEXT, when recent, is appended to the first problem.
        """
        out: list[str] = []
        if self.health is None:
            out.append("no SYS_STATUS received yet")
        else:
            bad = (self.enabled or 0) & ~self.health
            if bad & PREARM_BIT:
                out.append("the autopilot's pre-arm checks fail (SYS_STATUS PREARM_CHECK unhealthy)")
            other = bad & ~PREARM_BIT & ~_NOT_BLOCKING
            if other:
                out.append("unhealthy sensors: " + ", ".join(sensor_names(other)))
        if self.flavour == "ardupilot" and self.ekf_flags is None:
            out.append("no EKF_STATUS_REPORT received yet")
        elif self.ekf_flags is not None and (
                self.ekf_flags & EKF_NEEDED != EKF_NEEDED or self.ekf_flags & _EKF_BAD):
            out.append(f"EKF has no usable absolute position yet (EKF_STATUS_REPORT flags "
                       f"{self.ekf_flags:#x}: {_flag_names('EKF_STATUS_FLAGS', self.ekf_flags, 'EKF_')}); "
                       "ArduCopter refuses to arm in GUIDED: Need Position Estimate")
        if self.estimator_flags is not None and (
                self.estimator_flags & ESTIMATOR_NEEDED != ESTIMATOR_NEEDED
                or self.estimator_flags & _ESTIMATOR_BAD):
            out.append(f"estimator has no usable position yet (ESTIMATOR_STATUS flags "
                       f"{self.estimator_flags:#x}: "
                       f"{_flag_names('ESTIMATOR_STATUS_FLAGS', self.estimator_flags, 'ESTIMATOR_')})")
        if out and now_s is not None:
            says = self.autopilot_says(now_s)
            if says:
                out[0] += f"; autopilot says: {says!r}"
        return out
