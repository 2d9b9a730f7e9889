"""MockAutopilot driven in-process (no sockets): modes, ACKs, setpoints, failsafes, params, missions."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.transport import make_parser

ORIGIN = (45.19, 5.72, 230.0)
DT = 0.02
POS_ONLY = 0b110111111000
VEL_ONLY = 0b110111000111


class Harness:
    """One autopilot + dynamics stepped by hand; a GCS encoder and a parser for the replies."""

    def __init__(self, personality: str, **overrides):
        self.mc = Multicopter(DynamicsParams(), np.random.default_rng(1))
        self.ap = MockAutopilot(1, personality, self.mc, ORIGIN, 0.0, param_overrides=overrides)
        self.gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = make_parser()
        self.uplink = make_parser()
        self.t = 0.0
        self.received = []

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / DT))):
            self.ap.step(self.t, DT)
            self.mc.step(DT)
            self.ap.send_telemetry(self.t)
            self.t += DT
            self._collect()

    def _collect(self):
        for frame in self.ap.drain_outbox():
            self.received += self.parser.parse_buffer(frame) or []

    def send(self, msg) -> list:
        start = len(self.received)
        for parsed in self.uplink.parse_buffer(msg.pack(self.gcs)) or []:
            self.ap.handle_message(parsed, self.t)
        self._collect()
        return self.received[start:]

    def command(self, cmd, *params, target=1):
        p = list(params) + [0.0] * (7 - len(params))
        replies = self.send(self.gcs.command_long_encode(target, 1, cmd, 0, *p))
        acks = [m for m in replies if m.get_type() == "COMMAND_ACK"]
        return acks[0].result if acks else None

    def set_mode(self, name: str):
        cm = self.ap.personality.custom_mode(name)
        if self.ap.personality.name == "px4":
            return self.command(mav.MAV_CMD_DO_SET_MODE, 1, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF)
        return self.command(mav.MAV_CMD_DO_SET_MODE, 1, cm)

    def setpoint(self, north, east, down, mask=POS_ONLY, frame=mav.MAV_FRAME_LOCAL_NED):
        return self.send(self.gcs.set_position_target_local_ned_encode(
            0, 1, 1, frame, mask, north, east, down, north, east, down, 0, 0, 0, 0, 0))

    def arm(self):
        return self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def takeoff(self, alt_m=10.0):
        if self.ap.personality.name == "px4":
            return self.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                                ORIGIN[2] + alt_m)
        return self.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m)

    def airborne(self, alt_m=10.0):
        """Ready, armed and hovering at ``alt_m`` in GUIDED (ArduPilot) or Hold (PX4)."""
        self.run(2.5)
        if self.ap.personality.name == "ardupilot":
            assert self.set_mode("GUIDED") == mav.MAV_RESULT_ACCEPTED
        assert self.arm() == mav.MAV_RESULT_ACCEPTED
        assert self.takeoff(alt_m) == mav.MAV_RESULT_ACCEPTED
        self.run(alt_m / 1.5 + 4.0)
        assert -self.mc.position_ned_m[2] == pytest.approx(alt_m, abs=0.3)


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_flies_mode_arm_takeoff_setpoints_land(personality):
    h = Harness(personality)
    h.airborne(10.0)
    if personality == "px4":
        assert h.ap.mode_name == "AUTO.LOITER"  # takeoff ends in Hold
        h.setpoint(30.0, -20.0, -15.0)
        assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
        for _ in range(150):  # stream at 10 Hz
            h.setpoint(30.0, -20.0, -15.0)
            h.run(0.1)
    else:
        h.setpoint(30.0, -20.0, -15.0)
        h.run(15.0)  # ArduPilot holds a position target with no new setpoint
    lpn = [m for m in h.received if m.get_type() == "LOCAL_POSITION_NED"][-1]
    assert (lpn.x, lpn.y, lpn.z) == pytest.approx((30.0, -20.0, -15.0), abs=0.2)
    target = [m for m in h.received if m.get_type() == "POSITION_TARGET_LOCAL_NED"][-1]
    assert (target.x, target.y, target.z) == pytest.approx((30.0, -20.0, -15.0))
    assert h.command(mav.MAV_CMD_NAV_LAND) == mav.MAV_RESULT_ACCEPTED
    h.run(30.0)
    assert h.mc.landed and not h.ap.armed
    assert h.ap.mode_name == h.ap.personality.land_mode


@pytest.mark.parametrize("personality,scenario,expected", [
    ("ardupilot", "arm_not_ready", mav.MAV_RESULT_FAILED),
    ("px4", "arm_not_ready", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("ardupilot", "takeoff_disarmed", mav.MAV_RESULT_FAILED),
    ("ardupilot", "takeoff_not_guided", mav.MAV_RESULT_FAILED),
    ("px4", "takeoff_not_ready", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("px4", "offboard_without_setpoints", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("px4", "mission_mode_without_mission", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("ardupilot", "unknown_mode", mav.MAV_RESULT_FAILED),
    ("px4", "unknown_mode", mav.MAV_RESULT_ACCEPTED),  # PX4 ACKs an unknown main mode, changes nothing
    ("px4", "unknown_auto_sub_mode", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("ardupilot", "unknown_command", mav.MAV_RESULT_UNSUPPORTED),
    ("px4", "unknown_command", mav.MAV_RESULT_UNSUPPORTED),
    ("ardupilot", "bad_arm_value", mav.MAV_RESULT_UNSUPPORTED),
    ("px4", "bad_arm_value", mav.MAV_RESULT_UNSUPPORTED),
    ("px4", "mission_start_without_mission", mav.MAV_RESULT_DENIED),
    ("ardupilot", "request_unknown_message", mav.MAV_RESULT_DENIED),
    ("px4", "request_home_before_fix", mav.MAV_RESULT_TEMPORARILY_REJECTED),
    ("ardupilot", "disarm_in_air", mav.MAV_RESULT_FAILED),
    ("px4", "disarm_in_air", mav.MAV_RESULT_TEMPORARILY_REJECTED),
])
def test_denials_get_the_autopilots_ack(personality, scenario, expected):
    h = Harness(personality)
    if scenario not in ("arm_not_ready", "takeoff_not_ready", "request_home_before_fix"):
        h.run(2.5)
    armed_before = None
    if scenario == "arm_not_ready":
        result = h.arm()
    elif scenario == "takeoff_disarmed":
        h.set_mode("GUIDED")
        result = h.takeoff()
    elif scenario == "takeoff_not_guided":
        assert h.arm() == mav.MAV_RESULT_ACCEPTED  # STABILIZE allows arming
        result = h.takeoff()
    elif scenario == "takeoff_not_ready":
        result = h.takeoff()
    elif scenario == "offboard_without_setpoints":
        result = h.set_mode("OFFBOARD")
    elif scenario == "mission_mode_without_mission":
        result = h.set_mode("AUTO.MISSION")
    elif scenario == "unknown_mode":
        mode_before = h.ap.mode_name
        result = h.command(mav.MAV_CMD_DO_SET_MODE, 1, 99, 0)
        assert h.ap.mode_name == mode_before
    elif scenario == "unknown_auto_sub_mode":
        result = h.command(mav.MAV_CMD_DO_SET_MODE, 1, 4, 42)
    elif scenario == "unknown_command":
        result = h.command(31337)
    elif scenario == "bad_arm_value":
        result = h.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.5)
    elif scenario == "mission_start_without_mission":
        result = h.command(mav.MAV_CMD_MISSION_START)
    elif scenario == "request_home_before_fix":
        result = h.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
        h.run(2.5)
        assert h.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION) == \
            mav.MAV_RESULT_ACCEPTED
        assert h.received[-1].get_type() == "HOME_POSITION"
    elif scenario == "request_unknown_message":
        result = h.command(mav.MAV_CMD_REQUEST_MESSAGE, 9999)
    else:  # disarm_in_air
        h.airborne(5.0)
        armed_before = h.ap.armed
        result = h.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    assert result == expected
    if armed_before is not None:
        assert h.ap.armed and not h.mc.landed


@pytest.mark.parametrize("target_system", [2, 200])
def test_messages_for_another_system_are_ignored_not_acked(target_system):
    h = Harness("px4")
    h.run(2.5)
    assert h.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=target_system) is None
    assert not h.ap.armed
    assert h.ap.counters["rx_not_for_us"] == 1


def test_ardupilot_guided_velocity_target_times_out_and_stops():
    h = Harness("ardupilot")
    h.airborne(10.0)
    h.setpoint(2.0, 0.0, 0.0, mask=VEL_ONLY)
    h.run(1.0)
    assert h.mc.velocity_ned_m_s[0] == pytest.approx(2.0, abs=0.3)
    h.run(6.0)  # GUID_TIMEOUT 3 s: stops
    assert np.linalg.norm(h.mc.velocity_ned_m_s) < 0.05
    assert h.ap.mode_name == "GUIDED"


#: COM_OBL_RC_ACT 0 (PX4's default, position mode): real PX4 v1.16 SIH reports POSCTL and, without
#: RC, descends at MPC_LAND_SPEED, lands, disarms and shows OFFBOARD again (measured by
#: tests/sitl/test_sitl_faults_px4.py and tests/conformance/test_conformance_px4_failsafes.py). The
#: action comes at once, with no COM_FAIL_ACT_T hold: PX4's failsafe framework handles the offboard
#: loss as a mode fallback that allows user takeover at any time, which arms no delay
@pytest.mark.parametrize("obl_action,expected_mode", [(0, "POSCTL"), (3, "AUTO.RTL"), (4, "AUTO.LAND")])
def test_px4_offboard_loss_failsafe(obl_action, expected_mode):
    h = Harness("px4", COM_OBL_RC_ACT=obl_action)
    h.airborne(10.0)
    h.setpoint(0.0, 0.0, -12.0)
    assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
    h.run(0.5)
    assert h.ap.mode_name == "OFFBOARD"
    h.run(1.0)  # COM_OF_LOSS_T = 1 s without setpoints
    assert h.ap.mode_name == expected_mode
    assert h.ap.failsafe == "offboard"
    texts = [m.text for m in h.received if m.get_type() == "STATUSTEXT"]
    assert "Failsafe activated" in texts  # PX4's words for an action without a hold first
    assert not any(t.startswith("Failsafe activated: entering Hold") for t in texts)


def test_px4_position_mode_without_rc_descends_lands_and_shows_offboard_again():
    """Offboard loss, COM_OBL_RC_ACT 0: POSCTL, straight down at MPC_LAND_SPEED (also above 10 m,
    where AUTO.LAND goes faster), landed state IN_AIR (not LANDING) until ON_GROUND, disarmed
    after COM_DISARM_LAND, then OFFBOARD shown again, disarmed, failsafe over."""
    h = Harness("px4", COM_OBL_RC_ACT=0)
    h.airborne(10.0)
    h.setpoint(0.0, 0.0, -14.0)
    assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
    for _ in range(16):  # a setpoint every 0.5 s (< COM_OF_LOSS_T): climbs to 14 m in OFFBOARD
        h.setpoint(0.0, 0.0, -14.0)
        h.run(0.5)
    assert h.ap.mode_name == "OFFBOARD"
    h.run(1.5)
    assert h.ap.mode_name == "POSCTL" and h.mc.armed
    h.run(1.0)  # past the stop of the climb
    alt0, t0 = -h.mc.position_ned_m[2], h.t
    assert alt0 > 11.0
    h.run(4.0)
    rate = (alt0 - (-h.mc.position_ned_m[2])) / (h.t - t0)
    assert rate == pytest.approx(h.ap.params["MPC_LAND_SPEED"], abs=0.1)
    assert h.ap.mode_name == "POSCTL" and h.mc.armed
    assert h.ap.landed_state() == mav.MAV_LANDED_STATE_IN_AIR
    horizontal = np.hypot(*h.mc.position_ned_m[:2])
    assert horizontal < 0.5
    for _ in range(60):
        if not h.mc.armed:
            break
        h.run(1.0)
    assert not h.mc.armed and h.mc.landed
    assert h.ap.mode_name == "OFFBOARD" and h.ap.failsafe is None
    assert h.ap.landed_state() == mav.MAV_LANDED_STATE_ON_GROUND


@pytest.mark.parametrize("personality,param,value,expected_mode", [
    ("ardupilot", "FS_GCS_ENABLE", 1, "RTL"),
    ("ardupilot", "FS_GCS_ENABLE", 5, "LAND"),
    ("px4", "NAV_DLL_ACT", 2, "AUTO.RTL"),
    ("px4", "NAV_DLL_ACT", 3, "AUTO.LAND"),
])
def test_gcs_loss_failsafe_follows_params(personality, param, value, expected_mode):
    h = Harness(personality, **{param: value})
    h.airborne(8.0)
    h.send(h.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    mode_before = h.ap.mode_name
    h.run(12.0)  # no more GCS heartbeats: FS_GCS_TIMEOUT 5 s / COM_DL_LOSS_T 10 s
    assert mode_before != expected_mode
    if personality == "px4":  # PX4 holds for COM_FAIL_ACT_T (5 s) first
        assert h.ap.mode_name == "AUTO.LOITER" and h.ap.failsafe == "gcs"
        h.run(3.5)
    assert h.ap.mode_name == expected_mode


def _px4_losing_its_gcs(**params):
    """A mock PX4 hovering in OFFBOARD that heard a GCS once at t and then nothing (COM_DL_LOSS_T 10 s)."""
    h = Harness("px4", **params)
    h.airborne(8.0)
    h.setpoint(0.0, 0.0, -8.0)
    assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
    h.send(h.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    return h, h.t


def _stream(h, seconds, gcs_heartbeat=False):
    """Setpoints at 10 Hz for ``seconds`` (a data-link loss is the GCS heartbeats missing, not the setpoints)."""
    for _ in range(int(round(seconds * 10))):
        h.setpoint(0.0, 0.0, -8.0)
        if gcs_heartbeat:
            h.send(h.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        h.run(0.1)


@pytest.mark.parametrize("dll_act, delay_s, expected_mode", [
    (2, 5.0, "AUTO.RTL"), (3, 5.0, "AUTO.LAND"), (3, 2.0, "AUTO.LAND"), (2, 0.0, "AUTO.RTL")])
def test_px4_data_link_loss_holds_com_fail_act_t_then_acts(dll_act, delay_s, expected_mode):
    """Real PX4 (v1.14+ commander/failsafe): NAV_DLL_ACT Return/Land is an action that allows user
    takeover ("Auto"): Hold (AUTO.LOITER, in failsafe) for COM_FAIL_ACT_T, then the action; 0 acts at once."""
    h, t0 = _px4_losing_its_gcs(NAV_DLL_ACT=dll_act, COM_FAIL_ACT_T=delay_s)
    _stream(h, 10.3)  # COM_DL_LOSS_T 10 s after the last GCS heartbeat
    # PX4 sends no STATUSTEXT while it hears no GCS (real PX4 v1.16 SIH), what it said comes with
    # the next GCS heartbeat (if under 5 s old)
    assert [m.text for m in h.received if m.get_type() == "STATUSTEXT"] == []
    h.send(h.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    h.run(0.1)
    texts = [m.text for m in h.received if m.get_type() == "STATUSTEXT"]
    assert texts[:2] == ["Connection to ground station lost", "Preflight Fail: No connection to the ground contro"]
    if delay_s == 0.0:
        assert h.ap.mode_name == expected_mode
        return
    assert h.ap.mode_name == "AUTO.LOITER" and h.ap.failsafe == "gcs"
    assert h.ap.heartbeat_fields()[2] == mav.MAV_STATE_CRITICAL
    assert f"Failsafe activated: entering Hold for {delay_s:.0f} seconds" in texts
    _stream(h, delay_s - 0.7)
    assert h.ap.mode_name == "AUTO.LOITER"
    _stream(h, 0.8)
    assert h.ap.mode_name == expected_mode and h.ap.failsafe == "gcs"


def test_px4_data_link_loss_action_survives_the_link_coming_back():
    """PX4 clears a data-link-loss action on a mode change or a disarm only: the GCS heard again
    during the hold does not stop the Return."""
    h, t0 = _px4_losing_its_gcs(NAV_DLL_ACT=2)
    _stream(h, 10.3)
    assert h.ap.mode_name == "AUTO.LOITER"
    _stream(h, 2.0, gcs_heartbeat=True)  # the link is back
    assert h.ap.mode_name == "AUTO.LOITER" and h.ap.failsafe == "gcs"
    _stream(h, 3.5, gcs_heartbeat=True)
    assert h.ap.mode_name == "AUTO.RTL"


def test_px4_data_link_loss_action_dropped_when_a_mode_is_commanded_during_the_hold():
    """A mode commanded during the hold is the user taking over: PX4 drops the pending action."""
    h, t0 = _px4_losing_its_gcs(NAV_DLL_ACT=2)
    _stream(h, 10.3)
    assert h.ap.mode_name == "AUTO.LOITER"
    h.send(h.gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
    _stream(h, 6.0, gcs_heartbeat=True)
    assert h.ap.mode_name == "OFFBOARD"


@pytest.mark.parametrize("personality,expected_mode", [("ardupilot", "LAND"), ("px4", "AUTO.RTL")])
def test_low_battery_fault_triggers_the_personalitys_failsafe(personality, expected_mode):
    h = Harness(personality)
    h.airborne(6.0)
    h.ap.faults.set("battery_low", True)
    h.run(0.5)
    if personality == "px4":  # PX4 holds for COM_FAIL_ACT_T (5 s) first, and says so (real SIH: after "Critical battery")
        assert h.ap.mode_name == "AUTO.LOITER" and h.ap.failsafe == "battery"
        texts = [m.text for m in h.received if m.get_type() == "STATUSTEXT"]
        assert "Failsafe activated: entering Hold for 5 seconds" in texts
        h.run(5.0)
    assert h.ap.mode_name == expected_mode
    assert h.ap.failsafe == "battery"


def test_rtl_flies_home_and_lands_disarmed():
    h = Harness("ardupilot")
    h.airborne(10.0)
    h.setpoint(40.0, 30.0, -10.0)
    h.run(15.0)
    assert h.set_mode("RTL") == mav.MAV_RESULT_ACCEPTED
    h.run(60.0)
    assert np.linalg.norm(h.mc.position_ned_m) < 1.0
    assert h.mc.landed and not h.ap.armed


@pytest.mark.parametrize("personality,name,value", [
    ("ardupilot", "WPNAV_SPEED", 500.0),
    ("ardupilot", "FS_GCS_ENABLE", 1),
    ("px4", "MPC_XY_VEL_MAX", 4.0),
    ("px4", "NAV_DLL_ACT", 2),
])
def test_param_set_read_round_trip_changes_behaviour(personality, name, value):
    h = Harness(personality)
    table = h.ap.params
    wire = value
    if personality == "px4" and isinstance(value, int):  # PX4 encodes integers bytewise
        import struct
        wire = struct.unpack("<f", struct.pack("<i", value))[0]
    replies = h.send(h.gcs.param_set_encode(1, 1, name.encode(), wire, table.ptype(name)))
    echo = [m for m in replies if m.get_type() == "PARAM_VALUE"][0]
    assert echo.param_id == name and echo.param_value == pytest.approx(wire)
    replies = h.send(h.gcs.param_request_read_encode(1, 1, name.encode(), -1))
    assert [m for m in replies if m.get_type() == "PARAM_VALUE"][0].param_value == pytest.approx(wire)
    assert table[name] == value
    if name in ("WPNAV_SPEED", "MPC_XY_VEL_MAX"):
        assert h.mc.params.max_speed_h_m_s == pytest.approx(value / 100.0 if name == "WPNAV_SPEED" else value)


def test_param_list_and_rejections_are_counted():
    h = Harness("ardupilot")
    replies = h.send(h.gcs.param_request_list_encode(1, 1))
    values = [m for m in replies if m.get_type() == "PARAM_VALUE"]
    assert len(values) == len(h.ap.params) and {m.param_count for m in values} == {len(h.ap.params)}
    assert h.send(h.gcs.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, 9)) == []
    assert h.ap.counters["param_unknown"] == 1
    before = h.ap.params["FS_GCS_TIMEOUT"]
    replies = h.send(h.gcs.param_set_encode(1, 1, b"FS_GCS_TIMEOUT", 1e9, 9))
    assert replies[0].param_value == before  # out of range: unchanged value echoed
    assert h.ap.counters["param_rejected"] == 1


@pytest.mark.parametrize("personality,mission_type", [
    ("ardupilot", mav.MAV_MISSION_TYPE_MISSION), ("px4", mav.MAV_MISSION_TYPE_MISSION),
    ("px4", mav.MAV_MISSION_TYPE_FENCE),
])
def test_mission_upload_download_round_trip(personality, mission_type):
    h = Harness(personality)
    h.run(2.5)
    items = [(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 10.0)] + [
        (mav.MAV_CMD_NAV_WAYPOINT, int((45.19 + 1e-4 * k) * 1e7), int(5.72 * 1e7), 10.0 + k)
        for k in range(4)]
    replies = h.send(h.gcs.mission_count_encode(1, 1, len(items), mission_type))
    for seq, (cmd, x, y, z) in enumerate(items):
        req = [m for m in replies if m.get_type() == "MISSION_REQUEST_INT"]
        assert req and req[-1].seq == seq
        replies = h.send(h.gcs.mission_item_int_encode(
            1, 1, seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, 0, 0, 0, 0, x, y, z,
            mission_type))
    ack = [m for m in replies if m.get_type() == "MISSION_ACK"][-1]
    assert ack.type == mav.MAV_MISSION_ACCEPTED
    count = [m for m in h.send(h.gcs.mission_request_list_encode(1, 1, mission_type))
             if m.get_type() == "MISSION_COUNT"][0].count
    assert count == len(items)
    down = [h.send(h.gcs.mission_request_int_encode(1, 1, s, mission_type))[0] for s in range(count)]
    first = 1 if personality == "ardupilot" and mission_type == 0 else 0  # ArduPilot: item 0 = home
    assert [(m.command, m.x, m.y, m.z) for m in down[first:]] == [
        (c, x, y, pytest.approx(z)) for c, x, y, z in items[first:]]
    if first:
        assert down[0].x == int(round(ORIGIN[0] * 1e7))


def test_mission_upload_retries_then_cancels_on_timeout():
    h = Harness("px4")
    replies = h.send(h.gcs.mission_count_encode(1, 1, 3, 0))
    assert [m.seq for m in replies if m.get_type() == "MISSION_REQUEST_INT"] == [0]
    h.run(12.0)
    requests = [m for m in h.received if m.get_type() == "MISSION_REQUEST_INT"]
    acks = [m for m in h.received if m.get_type() == "MISSION_ACK"]
    assert len(requests) == 6  # first request + 5 retries
    assert acks and acks[-1].type == mav.MAV_MISSION_OPERATION_CANCELLED


def test_mission_flies_in_auto():
    h = Harness("px4")
    h.run(2.5)
    wp = h.ap.ned_to_geodetic((20.0, 10.0, 0.0))
    items = [(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 8.0),
             (mav.MAV_CMD_NAV_WAYPOINT, int(round(wp[0] * 1e7)), int(round(wp[1] * 1e7)), 8.0)]
    h.send(h.gcs.mission_count_encode(1, 1, len(items), 0))
    for seq, (cmd, x, y, z) in enumerate(items):
        h.send(h.gcs.mission_item_int_encode(1, 1, seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                             cmd, 0, 1, 0, 0, 0, 0, x, y, z, 0))
    assert h.command(mav.MAV_CMD_MISSION_START) == mav.MAV_RESULT_ACCEPTED
    h.run(25.0)
    assert h.mc.position_ned_m == pytest.approx((20.0, 10.0, -8.0), abs=0.5)
    assert [m.seq for m in h.received if m.get_type() == "MISSION_ITEM_REACHED"] == [0, 1]
    assert h.ap.mode_name == "AUTO.LOITER"


@pytest.mark.parametrize("msg_id,interval_us,expected_count", [
    (mav.MAVLINK_MSG_ID_ATTITUDE, 100_000, 50),   # 10 Hz for 5 s
    (mav.MAVLINK_MSG_ID_ATTITUDE, -1, 0),         # disabled
    (mav.MAVLINK_MSG_ID_VFR_HUD, 500_000, 10),    # not streamed by default: 2 Hz
])
def test_set_message_interval_changes_the_stream(msg_id, interval_us, expected_count):
    h = Harness("ardupilot")
    assert h.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us) == mav.MAV_RESULT_ACCEPTED
    start = len(h.received)
    h.run(5.0)
    n = sum(1 for m in h.received[start:] if m.get_msgId() == msg_id)
    assert abs(n - expected_count) <= 1


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_autopilot_version_has_capabilities_and_uid(personality):
    h = Harness(personality)
    assert h.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == \
        mav.MAV_RESULT_ACCEPTED
    version = [m for m in h.received if m.get_type() == "AUTOPILOT_VERSION"][0]
    for cap in (mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2, mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
                mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT,
                mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED):
        assert version.capabilities & cap
    assert version.uid == h.ap.uid != 0


def test_global_setpoint_relative_alt_is_followed():
    h = Harness("ardupilot")
    h.airborne(10.0)
    lat, lon, _ = h.ap.ned_to_geodetic((-15.0, 25.0, 0.0))
    h.send(h.gcs.set_position_target_global_int_encode(
        0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, POS_ONLY, int(round(lat * 1e7)),
        int(round(lon * 1e7)), 12.0, 0, 0, 0, 0, 0, 0, 0, 0))
    h.run(20.0)
    assert h.mc.position_ned_m == pytest.approx((-15.0, 25.0, -12.0), abs=0.1)


def test_sysid_param_takes_effect_after_reboot():
    h = Harness("ardupilot")
    h.send(h.gcs.param_set_encode(1, 1, b"MAV_SYSID", 7.0, mav.MAV_PARAM_TYPE_INT16))
    h.run(1.0)
    assert {m.get_srcSystem() for m in h.received if m.get_type() == "HEARTBEAT"} == {1}
    assert h.command(mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == mav.MAV_RESULT_ACCEPTED
    start = len(h.received)
    h.run(2.0)
    assert {m.get_srcSystem() for m in h.received[start:] if m.get_type() == "HEARTBEAT"} == {7}
    assert h.ap.sysid == 7
    # answered as system 7, and accepted: STABILIZE allows arming and the 2 s GPS warm-up since
    # the reboot is over
    assert h.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=7) == mav.MAV_RESULT_ACCEPTED
    assert h.ap.armed


@pytest.mark.parametrize("glitch_m", [0.0, 25.0])
def test_gps_glitch_moves_the_reported_not_the_true_position(glitch_m):
    h = Harness("px4")
    h.ap.faults.set("gps_glitch_m", glitch_m)
    h.run(3.0)
    lpn = [m for m in h.received if m.get_type() == "LOCAL_POSITION_NED"][-1]
    assert lpn.x == pytest.approx(glitch_m)
    assert h.mc.position_ned_m[0] == 0.0


@pytest.mark.parametrize("personality,params,expected_mode", [
    ("ardupilot", {"FENCE_ENABLE": 1, "FENCE_RADIUS": 30.0}, "RTL"),
    ("px4", {"GF_MAX_HOR_DIST": 30.0, "GF_ACTION": 5}, "AUTO.LAND"),
])
def test_geofence_breach_triggers_the_fence_action(personality, params, expected_mode):
    h = Harness(personality, **params)
    h.airborne(10.0)
    if personality == "px4":
        h.setpoint(50.0, 0.0, -10.0)
        assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
        for _ in range(100):
            h.setpoint(50.0, 0.0, -10.0)
            h.run(0.1)
            if h.ap.mode_name != "OFFBOARD":
                break
    else:
        h.setpoint(50.0, 0.0, -10.0)
        h.run(10.0)
    if personality == "px4":
        # real PX4 v1.16 first holds, in failsafe, for COM_FAIL_ACT_T (5 s), then takes GF_ACTION
        assert h.ap.mode_name == "AUTO.LOITER"
        assert h.ap.heartbeat_fields()[2] == mav.MAV_STATE_CRITICAL
        h.run(4.5)
        assert h.ap.mode_name == "AUTO.LOITER"
        h.run(1.0)
    assert h.ap.mode_name == expected_mode
    texts = [m.text for m in h.received if m.get_type() == "STATUSTEXT"]
    assert ("Failsafe: geofence breached" if personality == "ardupilot"
            else "Geofence: exceeding maximum distance to Home") in texts
    # ArduPilot returns at once; PX4 brakes to its hold from full speed first
    assert h.mc.position_ned_m[0] < (40.0 if personality == "ardupilot" else 60.0)


@pytest.mark.parametrize("delay_s, first_mode", [(0.0, "AUTO.LAND"), (2.0, "AUTO.LOITER")])
def test_px4_geofence_action_waits_com_fail_act_t(delay_s, first_mode):
    h = Harness("px4", GF_ACTION=5, COM_FAIL_ACT_T=delay_s)
    h.airborne(10.0)
    h.ap.params.set("GF_MAX_VER_DIST", 8.0)            # the ceiling lowered under it: breached
    h.setpoint(0.0, 0.0, -10.0)
    assert h.set_mode("OFFBOARD") == mav.MAV_RESULT_ACCEPTED
    for _ in range(20):
        h.setpoint(0.0, 0.0, -10.0)
        h.run(0.1)
        if h.ap.mode_name != "OFFBOARD":
            break
    assert h.ap.mode_name == first_mode
    texts = [m.text for m in h.received if m.get_type() == "STATUSTEXT"]
    held = [t for t in texts if t.startswith("Failsafe activated: entering Hold")]
    assert held == ([] if delay_s == 0.0 else ["Failsafe activated: entering Hold for 2 seconds"]), texts
    h.run(delay_s + 0.5)
    assert h.ap.mode_name == "AUTO.LAND"


@pytest.mark.parametrize("frame,xyz,expected_ned", [
    (mav.MAV_FRAME_LOCAL_NED, (10.0, 5.0, -12.0), (10.0, 5.0, -12.0)),
    (mav.MAV_FRAME_LOCAL_OFFSET_NED, (10.0, 5.0, -2.0), (10.0, 5.0, -12.0)),  # from (0, 0, -10)
])
def test_local_setpoint_frames_and_yaw_are_honoured(frame, xyz, expected_ned):
    h = Harness("ardupilot")
    h.airborne(10.0)
    mask_with_yaw = POS_ONLY & ~1024  # use the yaw field
    h.send(h.gcs.set_position_target_local_ned_encode(0, 1, 1, frame, mask_with_yaw, *xyz,
                                                      0, 0, 0, 0, 0, 0, math.radians(90), 0))
    h.run(15.0)
    assert h.mc.position_ned_m == pytest.approx(expected_ned, abs=0.1)
    assert h.mc.yaw_rad == pytest.approx(math.radians(90), abs=1e-3)
    echo = [m for m in h.received if m.get_type() == "POSITION_TARGET_GLOBAL_INT"][-1]
    lat, lon, alt = h.ap.ned_to_geodetic(expected_ned)
    assert echo.lat_int == pytest.approx(lat * 1e7, abs=2) and echo.lon_int == pytest.approx(lon * 1e7, abs=2)
    assert echo.alt == pytest.approx(alt, abs=0.02)  # offsets start from the current position


def test_setpoints_outside_guided_are_not_followed_and_bad_frames_counted():
    h = Harness("ardupilot")
    h.airborne(10.0)
    assert h.set_mode("LOITER") == mav.MAV_RESULT_ACCEPTED
    h.setpoint(30.0, 0.0, -10.0)
    h.setpoint(30.0, 0.0, -10.0, frame=mav.MAV_FRAME_GLOBAL_INT)  # not a local frame
    h.setpoint(30.0, 0.0, -10.0, mask=0b110111111111)  # neither position nor velocity
    h.run(5.0)
    assert h.mc.position_ned_m[0] == pytest.approx(0.0, abs=0.1)
    assert h.ap.counters["setpoint_not_in_guided"] == 1
    assert h.ap.counters["setpoint_bad_frame"] == 1
    assert h.ap.counters["setpoint_unsupported_mask"] == 1


def test_px4_takeoff_while_disarmed_selects_takeoff_mode_and_climbs_on_arming():
    h = Harness("px4", MIS_TAKEOFF_ALT=4.0)
    h.run(2.5)
    assert h.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                     math.nan) == mav.MAV_RESULT_ACCEPTED  # NaN altitude: MIS_TAKEOFF_ALT
    assert h.ap.mode_name == "AUTO.TAKEOFF" and not h.ap.armed
    h.run(1.0)
    assert h.mc.landed
    assert h.arm() == mav.MAV_RESULT_ACCEPTED
    h.run(6.0)
    assert -h.mc.position_ned_m[2] == pytest.approx(4.0, abs=0.2)
    assert h.ap.mode_name == "AUTO.LOITER"


@pytest.mark.parametrize("name,value,match", [
    ("NO_SUCH", 1, "unknown parameter 'NO_SUCH'"),
    ("FS_GCS_ENABLE", 1.5, "expected an integer"),
    ("FS_GCS_TIMEOUT", 1e9, r"outside \[2.0, 120.0\]"),
    ("RTL_ALT", math.nan, "must be finite"),
])
def test_param_table_rejects_bad_values(name, value, match):
    from sitl_mock.ap_params import ParamError
    table = Harness("ardupilot").ap.params
    with pytest.raises(ParamError, match=match):
        table.set(name, value)


def test_param_overrides_are_checked_at_construction():
    from sitl_mock.ap_params import ParamError
    with pytest.raises(ParamError, match="MPC_XY_VEL_MAX"):
        Harness("px4", MPC_XY_VEL_MAX=-1.0)


def test_ardupilot_auto_flies_the_mission_after_its_home_item():
    h = Harness("ardupilot")
    h.run(2.5)
    wp = h.ap.ned_to_geodetic((-10.0, 15.0, 0.0))
    items = [(mav.MAV_CMD_NAV_WAYPOINT, 0, 0, 0.0),  # item 0: home, overwritten by ArduPilot
             (mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 6.0),
             (mav.MAV_CMD_NAV_WAYPOINT, int(round(wp[0] * 1e7)), int(round(wp[1] * 1e7)), 6.0),
             (mav.MAV_CMD_NAV_LAND, 0, 0, 0.0)]
    h.send(h.gcs.mission_count_encode(1, 1, len(items), 0))
    for seq, (cmd, x, y, z) in enumerate(items):
        h.send(h.gcs.mission_item_int_encode(1, 1, seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                             cmd, 0, 1, 0, 0, 0, 0, x, y, z, 0))
    assert h.set_mode("LOITER") == mav.MAV_RESULT_ACCEPTED
    assert h.arm() == mav.MAV_RESULT_ACCEPTED
    assert h.set_mode("AUTO") == mav.MAV_RESULT_ACCEPTED
    h.run(40.0)
    assert [m.seq for m in h.received if m.get_type() == "MISSION_ITEM_REACHED"] == [1, 2, 3]
    # the waypoint is reached within WPNAV_RADIUS (2 m); NAV_LAND at lat/lon 0 lands right there
    assert h.mc.position_ned_m == pytest.approx((-10.0, 15.0, 0.0), abs=2.5)
    assert h.mc.landed and not h.ap.armed
