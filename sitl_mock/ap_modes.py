"""The two autopilot personalities: flight-mode tables, MAVLink identity and result codes.

A personality says how an autopilot *names* things (custom_mode numbers, mode names, parameter
table, HEARTBEAT identity) and which COMMAND_ACK result it gives when a precondition fails; the
flight logic shared by both lives in :mod:`sitl_mock.autopilot`. Each mode maps to one of the
mock's internal behaviours:

``hold``      hold position (LOITER, BRAKE, POSHOLD, CIRCLE, PX4 Hold; manual modes without RC)
``guided``    follow GCS setpoints (ArduPilot GUIDED)
``offboard``  follow GCS setpoints with the offboard-loss failsafe (PX4 OFFBOARD)
``takeoff``   PX4 AUTO.TAKEOFF: climb to the takeoff altitude, then Hold
``land``      descend and land where it is, disarm on touchdown
``rtl``       climb to the return altitude, fly home, land, disarm
``mission``   fly the uploaded mission (ArduPilot AUTO, PX4 AUTO.MISSION)
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sitl_mock.ap_params import ParamSpec, ardupilot_param_specs, px4_param_specs

__all__ = ["Personality", "ArduPilotPersonality", "Px4Personality", "make_personality",
           "PERSONALITY_NAMES", "px4_custom_mode"]

PERSONALITY_NAMES = ("ardupilot", "px4")

_CAPS_COMMON = (
    mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4's HEARTBEAT custom_mode: ``main_mode << 16 | sub_mode << 24``."""
    return (int(main_mode) << 16) | (int(sub_mode) << 24)


class Personality:
    """What differs between the autopilots, as data plus a few lookups.

    Attributes
    ----------
    name : str
        ``"ardupilot"`` or ``"px4"``.
    autopilot : int
        HEARTBEAT.autopilot (MAV_AUTOPILOT_*).
    modes : dict
        custom_mode -> mode name.
    behaviours : dict
        mode name -> internal behaviour (see the module docstring).
    reject_result : int
        COMMAND_ACK result when a precondition fails (arming checks, takeoff, mode change).
    unknown_mode_result : int
        COMMAND_ACK result of a mode change to a mode the autopilot does not have.
    capabilities : int
        AUTOPILOT_VERSION.capabilities bits.
    param_bytewise : bool
        Integer parameters encoded bytewise in PARAM_VALUE.
    boot_mode, land_mode, rtl_mode, hold_mode, takeoff_mode, mission_mode : str
        Mode names the flight logic switches to.
    wind_msg_id : int
        The message carrying the wind estimate (PX4 WIND_COV, ArduPilot WIND; -1: none), the
        only one of the two the personality sends or accepts a rate for.
    wind_default_hz : float
        Its rate before any SET_MESSAGE_INTERVAL (0: not streamed until asked).
    """

    name = ""
    autopilot = mavlink2.MAV_AUTOPILOT_GENERIC
    modes: dict[int, str] = {}
    behaviours: dict[str, str] = {}
    position_modes: frozenset = frozenset()
    arming_modes: frozenset = frozenset()
    reject_result = mavlink2.MAV_RESULT_FAILED
    unknown_mode_result = mavlink2.MAV_RESULT_FAILED
    capabilities = _CAPS_COMMON
    param_bytewise = False
    sysid_param = ""
    boot_mode = land_mode = rtl_mode = hold_mode = takeoff_mode = mission_mode = ""
    wind_msg_id = -1
    wind_default_hz = 0.0

    def __init__(self):
        self._by_name = {name: cm for cm, name in self.modes.items()}

    def custom_mode(self, mode_name: str) -> int:
        """HEARTBEAT custom_mode of ``mode_name``."""
        return self._by_name[mode_name]

    def mode_name(self, custom_mode: int) -> str | None:
        """Mode name for a custom_mode, or None when the autopilot has no such mode."""
        return self.modes.get(int(custom_mode))

    def behaviour(self, mode_name: str) -> str:
        """Internal behaviour of ``mode_name``."""
        return self.behaviours[mode_name]

    def mode_from_command(self, base_mode: float, p2: float, p3: float) -> str | None:
        """Mode named by MAV_CMD_DO_SET_MODE's params 1..3; None (no such mode: the
        personality's ``unknown_mode_result``) or ``""`` (a rejected request)."""
        raise NotImplementedError

    def param_specs(self, sysid: int, dyn) -> list[ParamSpec]:
        """The parameter table (see :mod:`sitl_mock.ap_params`)."""
        raise NotImplementedError


class ArduPilotPersonality(Personality):
    """ArduCopter: custom_mode is the Copter mode number; failed preconditions -> FAILED."""

    name = "ardupilot"
    autopilot = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    modes = {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER",
             6: "RTL", 7: "CIRCLE", 9: "LAND", 16: "POSHOLD", 17: "BRAKE", 21: "SMART_RTL"}
    behaviours = {"STABILIZE": "hold", "ACRO": "hold", "ALT_HOLD": "hold", "AUTO": "mission",
                  "GUIDED": "guided", "LOITER": "hold", "RTL": "rtl", "CIRCLE": "hold",
                  "LAND": "land", "POSHOLD": "hold", "BRAKE": "hold", "SMART_RTL": "rtl"}
    position_modes = frozenset({"AUTO", "GUIDED", "LOITER", "RTL", "CIRCLE", "POSHOLD", "BRAKE",
                                "SMART_RTL"})
    arming_modes = frozenset({"STABILIZE", "ACRO", "ALT_HOLD", "GUIDED", "LOITER", "POSHOLD"})
    reject_result = mavlink2.MAV_RESULT_FAILED
    capabilities = _CAPS_COMMON | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST | \
        mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET | \
        mavlink2.MAV_PROTOCOL_CAPABILITY_COMPASS_CALIBRATION
    param_bytewise = False
    sysid_param = "MAV_SYSID"
    boot_mode, land_mode, rtl_mode, hold_mode = "STABILIZE", "LAND", "RTL", "LOITER"
    takeoff_mode, mission_mode = "GUIDED", "AUTO"
    # WIND is in ArduCopter's SRx_EXTRA3 stream group (off on a link until asked)
    wind_msg_id = mavlink2.MAVLINK_MSG_ID_WIND

    def mode_from_command(self, base_mode, p2, p3):
        """Param 2 is the Copter mode number (custom mode flag required)."""
        if not int(base_mode) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        return self.mode_name(int(p2))

    def param_specs(self, sysid, dyn):
        """ArduCopter's table (see :func:`~sitl_mock.ap_params.ardupilot_param_specs`)."""
        return ardupilot_param_specs(sysid, dyn)


class Px4Personality(Personality):
    """PX4: custom_mode = main << 16 | sub << 24; failed preconditions -> TEMPORARILY_REJECTED."""

    name = "px4"
    autopilot = mavlink2.MAV_AUTOPILOT_PX4
    modes = {
        px4_custom_mode(1): "MANUAL",
        px4_custom_mode(2): "ALTCTL",
        px4_custom_mode(3): "POSCTL",
        px4_custom_mode(4, 2): "AUTO.TAKEOFF",
        px4_custom_mode(4, 3): "AUTO.LOITER",
        px4_custom_mode(4, 4): "AUTO.MISSION",
        px4_custom_mode(4, 5): "AUTO.RTL",
        px4_custom_mode(4, 6): "AUTO.LAND",
        px4_custom_mode(5): "ACRO",
        px4_custom_mode(6): "OFFBOARD",
        px4_custom_mode(7): "STABILIZED",
    }
    behaviours = {"MANUAL": "hold", "ALTCTL": "hold", "POSCTL": "hold", "AUTO.TAKEOFF": "takeoff",
                  "AUTO.LOITER": "hold", "AUTO.MISSION": "mission", "AUTO.RTL": "rtl",
                  "AUTO.LAND": "land", "ACRO": "hold", "OFFBOARD": "offboard",
                  "STABILIZED": "hold"}
    position_modes = frozenset({"POSCTL", "AUTO.TAKEOFF", "AUTO.LOITER", "AUTO.MISSION",
                                "AUTO.RTL", "AUTO.LAND", "OFFBOARD"})
    arming_modes = frozenset({"MANUAL", "ALTCTL", "POSCTL", "AUTO.TAKEOFF", "AUTO.LOITER",
                              "AUTO.MISSION", "ACRO", "OFFBOARD", "STABILIZED"})
    reject_result = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
    unknown_mode_result = mavlink2.MAV_RESULT_ACCEPTED  # PX4 ACKs and ignores an unknown main mode
    capabilities = _CAPS_COMMON | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE | \
        mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    param_bytewise = True
    sysid_param = "MAV_SYS_ID"
    boot_mode, land_mode, rtl_mode, hold_mode = "AUTO.LOITER", "AUTO.LAND", "AUTO.RTL", "AUTO.LOITER"
    takeoff_mode, mission_mode = "AUTO.TAKEOFF", "AUTO.MISSION"
    # PX4's mavlink module streams WIND_COV at 0.5 Hz in its "normal" link mode
    # (mavlink_main.cpp), when EKF2 estimates the wind
    wind_msg_id = mavlink2.MAVLINK_MSG_ID_WIND_COV
    wind_default_hz = 0.5

    def mode_from_command(self, base_mode, p2, p3):
        """Params 2 and 3 are PX4's main and sub mode (custom mode flag required).

        As PX4's commander: an unknown AUTO sub mode is an error (``""``), an unknown main
        mode or a request without the custom flag changes nothing (None; PX4 still ACKs it
        ACCEPTED).
        """
        if not int(base_mode) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        main, sub = int(p2), int(p3)
        if main == 4 and sub == 0:
            sub = 4  # AUTO without a sub mode is MISSION
        if main != 4:
            sub = 0
        name = self.mode_name(px4_custom_mode(main, sub))
        if name is None and main == 4:
            return ""
        return name

    def mode_name(self, custom_mode):
        """Mode name of a PX4 custom_mode (the sub mode only counts in AUTO)."""
        cm = int(custom_mode)
        if (cm >> 16) & 0xFF != 4:
            cm &= 0x00FF0000  # sub mode only meaningful in AUTO
        return self.modes.get(cm)

    def param_specs(self, sysid, dyn):
        """PX4's table (see :func:`~sitl_mock.ap_params.px4_param_specs`)."""
        return px4_param_specs(sysid, dyn)


def make_personality(name: str) -> Personality:
    """A personality by name: ``"ardupilot"`` or ``"px4"``."""
    if name == "ardupilot":
        return ArduPilotPersonality()
    if name == "px4":
        return Px4Personality()
    raise ValueError(f"unknown personality {name!r}; known: {', '.join(PERSONALITY_NAMES)}")
