"""Fuzzing the mock autopilot's MAVLink input path: nothing escapes, every frame is counted,
invalid input changes nothing.

Entry point: ``sitl_mock.transport.VehicleLinks._receive(parser, data)``, what the UDP and TCP
handlers call with each datagram / chunk and that peer's parser; it hands every parsed message to
``MockAutopilot.handle_message``, which accepts it (``rx_frames``) or counts why not
(``rx_bad_crc``, ``rx_malformed``, ``rx_unknown_msg``). The socket-level test goes through a
running :class:`~sitl_mock.fleet.MockFleet`.
"""
from __future__ import annotations

import math
import random
import select
import selectors
import socket
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.embedded import free_port_block
from sitl_mock.ap_commands import COMMANDS
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics import DynamicsParams, Multicopter
from sitl_mock.fleet import MockFleet
from sitl_mock.transport import VehicleLinks, make_parser
from fuzz_helpers import (ALL_MESSAGE_CLASSES, FakeClock, encode, frames, is_bad, is_valid_for, message_class,
                          mutated, reference_parse, state_repr)

_M = mavlink
SYSID = 1
HOME = (45.19, 5.72, 230.0)
_DT_S = 0.02
_SETTINGS = settings(max_examples=60, deadline=2000,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
#: every counter of a frame the receive path took in: accepted, rejected or dropped by a link fault
_COUNTED = ("rx_frames", "rx_bad_crc", "rx_malformed", "rx_unknown_msg", "rx_dropped_link",
            "rx_dropped_loss")
#: messages the mock acts upon (commands, setpoints, parameters, missions)
_ACTED_UPON = tuple(message_class(n) for n in (
    "COMMAND_LONG", "COMMAND_INT", "SET_MODE", "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT", "PARAM_SET", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST",
    "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
    "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_ACK", "REQUEST_DATA_STREAM", "TIMESYNC",
    "HEARTBEAT"))
_COMMAND_IDS = st.one_of(st.sampled_from(sorted(COMMANDS)), st.integers(0, 0xFFFF))
#: largest |altitude| (m) whose HOME_POSITION.altitude (int32 mm) can be encoded
_INT32_ALT_M = (2 ** 31 - 1) / 1000.0
#: setpoints farther than this (m) are absurd; the mock accepts them and its telemetry then fails
_ABSURD_SETPOINT_M = 1e6


def _no_known_crash(frame: bytes) -> bool:
    """False for the commands that let an exception escape (one xfail test each, below): kept
    out of the random input so that the properties test everything else. Remove once fixed."""
    for msg in reference_parse(frame)[0]:
        kind = msg.get_type()
        if kind.startswith("SET_POSITION_TARGET_"):
            coords = (msg.x, msg.y, msg.z) if kind.endswith("LOCAL_NED") else (msg.alt,)
            if any(math.isfinite(v) and abs(v) > _ABSURD_SETPOINT_M for v in coords):
                return False
        command = getattr(msg, "command", None)
        if kind not in ("COMMAND_LONG", "COMMAND_INT"):
            continue
        if command in (_M.MAV_CMD_REQUEST_PROTOCOL_VERSION, _M.MAV_CMD_GET_MESSAGE_INTERVAL):
            return False
        alt_m = msg.param7 if msg.get_type() == "COMMAND_LONG" else msg.z
        if command == _M.MAV_CMD_DO_SET_HOME and abs(alt_m) >= _INT32_ALT_M:
            return False
    return True


def _run(ap, t_s: float, duration_s: float) -> float:
    for _ in range(int(round(duration_s / _DT_S))):
        ap.step(t_s, _DT_S)
        ap.mc.step(_DT_S)
        ap.send_telemetry(t_s)
        t_s += _DT_S
    return t_s


def _command(command: int, *params: float, target=(SYSID, 1)) -> bytes:
    p = [float(v) for v in params] + [0.0] * (7 - len(params))
    return encode(_M.MAVLink_command_long_message(*target, command, 0, *p))


def _vehicle(personality: str = "ardupilot", flying: bool = False):
    """A mock autopilot with its (unopened) links, past boot; flying: GUIDED at 10 m."""
    mc = Multicopter(DynamicsParams(), np.random.default_rng(0))
    ap = MockAutopilot(SYSID, personality, mc, HOME, 0.0)
    clock = FakeClock(0.0)
    links = VehicleLinks(ap, clock, selectors.SelectSelector(), np.random.default_rng(0))
    clock.t_s = _run(ap, 0.0, 3.0)
    if flying:
        parser = make_parser()
        for frame in (_command(_M.MAV_CMD_DO_SET_MODE, 1, 4), _command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1),
                      _command(_M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10)):
            links._receive(parser, frame)
        clock.t_s = _run(ap, clock.t_s, 4.0)
    ap.drain_outbox()
    return ap, links, clock


def _state(ap) -> str:
    fs = ap.flight
    return state_repr(ap.sysid, ap.mode_name, ap.armed, ap.failsafe, ap.home, ap.mc.mode,
                      ap.mc.position_target_ned_m, ap.params.as_dict(),
                      [ap.missions.items(kind) for kind in (0, 1, 2)], fs.setpoint,
                      fs.last_setpoint_s, fs.takeoff_alt_m, ap.last_gcs_heartbeat_s)


def _counted(ap) -> int:
    return sum(ap.counters[name] for name in _COUNTED)


def _feed(links, datagrams) -> None:
    parser = make_parser()  # one peer: one parser for all its datagrams, as the transport does
    for data in datagrams:
        links._receive(parser, data)


@pytest.mark.parametrize("personality, frame", [
    ("ardupilot", _command(_M.MAV_CMD_DO_SET_MODE, 1, 9)),                      # LAND
    ("ardupilot", encode(_M.MAVLink_param_set_message(SYSID, 1, b"FS_GCS_ENABLE", 2.0,
                                                      _M.MAV_PARAM_TYPE_INT8))),
    ("px4", _command(_M.MAV_CMD_NAV_LAND)),
    ("px4", _command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196, target=(0, 0))),   # broadcast
])
def test_the_state_image_sees_what_a_valid_command_changes(personality, frame):
    """The 'state unchanged' assertions below can fail: a valid command changes the image."""
    ap, links, _ = _vehicle(personality, flying=True)
    assert ap.armed and not ap.mc.landed
    before = _state(ap)
    _feed(links, [frame])
    assert _state(ap) != before


_junk = st.lists(st.one_of(st.binary(max_size=40),
                           st.sampled_from([b"\xfd", b"\xfe", b"\xfd\x09\x00\x00", b"\xfe\x21"])),
                 min_size=1, max_size=12).map(b"".join)
_acted_frames = frames(_ACTED_UPON, target_system=SYSID, target_component=st.sampled_from([0, 1]),
                       command=_COMMAND_IDS).filter(_no_known_crash)


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(), st.lists(_junk, min_size=1, max_size=6))
def test_random_bytes_are_counted_and_change_nothing(personality, flying, datagrams):
    ap, links, _ = _vehicle(personality, flying)
    msgs, _ = reference_parse(datagrams)
    assume(not any(is_valid_for(m, SYSID) for m in msgs))
    before, counted = _state(ap), _counted(ap)
    _feed(links, datagrams)
    assert _state(ap) == before
    assert _counted(ap) - counted == len(msgs)
    assert ap.drain_outbox() == []          # no answer to garbage
    assert ap.counters["rx_parser_error"] == 0


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(),
       st.lists(mutated(_acted_frames), min_size=1, max_size=4))
def test_broken_frames_of_real_commands_are_counted_and_change_nothing(personality, flying, datagrams):
    ap, links, _ = _vehicle(personality, flying)
    msgs, _ = reference_parse(datagrams)
    assume(not any(is_valid_for(m, SYSID) for m in msgs))
    before, counted, accepted = _state(ap), _counted(ap), ap.counters["rx_frames"]
    _feed(links, datagrams)
    assert _state(ap) == before
    assert _counted(ap) - counted == len(msgs)
    assert ap.counters["rx_frames"] - accepted == sum(not is_bad(m) for m in msgs)
    assert ap.drain_outbox() == []


#: state-changing messages that carry both target_system and target_component
_TARGETED = tuple(message_class(n) for n in (
    "COMMAND_LONG", "COMMAND_INT", "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT",
    "PARAM_SET", "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL",
    "MISSION_SET_CURRENT"))
_other_system = st.one_of(
    frames(_TARGETED, target_system=st.integers(2, 255), command=_COMMAND_IDS),
    frames([message_class("SET_MODE")], target_system=st.integers(2, 255)))
_other_component = frames(_TARGETED, target_system=st.sampled_from([0, SYSID]),
                          target_component=st.integers(2, 255), command=_COMMAND_IDS)


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(),
       st.lists(st.one_of(_other_system, _other_component), min_size=1, max_size=8))
def test_valid_commands_for_another_system_or_component_change_nothing(personality, flying, frame_list):
    ap, links, _ = _vehicle(personality, flying)
    before, not_for_us = _state(ap), ap.counters["rx_not_for_us"]
    _feed(links, frame_list)
    assert _state(ap) == before
    assert ap.counters["rx_not_for_us"] - not_for_us == len(frame_list)
    assert ap.drain_outbox() == []


_any_frames = st.one_of(
    _acted_frames,
    frames(ALL_MESSAGE_CLASSES, target_system=st.sampled_from([0, SYSID, 2]),
           target_component=st.sampled_from([0, 1, 190]), command=_COMMAND_IDS),
    frames(_ACTED_UPON, sysid=st.integers(1, 255), compid=st.integers(0, 255),
           target_system=st.sampled_from([0, SYSID]), command=_COMMAND_IDS)).filter(_no_known_crash)


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(), st.lists(_any_frames, min_size=1, max_size=8))
def test_random_valid_messages_never_escape_the_receive_path(personality, flying, frame_list):
    """Random field values (NaN, infinities, extremes) in real messages: handled or counted."""
    ap, links, clock = _vehicle(personality, flying)
    counted = _counted(ap)
    _feed(links, frame_list)
    assert _counted(ap) - counted == len(frame_list)
    _run(ap, clock.t_s, 0.5)                      # and the vehicle still flies afterwards
    assert np.all(np.isfinite(ap.mc.position_ned_m))
    assert ap.counters["rx_parser_error"] == 0


@pytest.mark.parametrize("personality, flying", [("ardupilot", False), ("px4", True)])
def test_a_valid_command_after_garbage_from_another_peer_still_works(personality, flying):
    ap, links, _ = _vehicle(personality, flying)
    _feed(links, [b"\xfd\xff\x00\x00garbage", bytes(range(256)), b"\xfe\x21"])
    _feed(links, [_command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)])
    acks = [m for m in reference_parse(b"".join(ap.drain_outbox()))[0] if m.get_type() == "COMMAND_ACK"]
    assert [(a.command, a.result) for a in acks] == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)]


@pytest.mark.xfail(strict=True, raises=AttributeError, reason=(
    "sitl_mock/ap_commands.py _cmd_protocol_version calls mav.protocol_version_encode, which the "
    "pymavlink ardupilotmega dialect does not have: AttributeError escapes handle_message"))
@pytest.mark.parametrize("kind", ["COMMAND_LONG", "COMMAND_INT"])
def test_request_protocol_version_is_answered_without_escaping(kind):
    ap, links, _ = _vehicle("ardupilot")
    if kind == "COMMAND_LONG":
        frame = _command(_M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)
    else:
        frame = encode(_M.MAVLink_command_int_message(SYSID, 1, 0, _M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 0, 0,
                                                      1, 0, 0, 0, 0, 0, 0))
    _feed(links, [frame + _command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)])
    acks = [m.command for m in reference_parse(b"".join(ap.drain_outbox()))[0] if m.get_type() == "COMMAND_ACK"]
    assert acks == [_M.MAV_CMD_REQUEST_PROTOCOL_VERSION, _M.MAV_CMD_REQUEST_MESSAGE]  # 2nd not lost


@pytest.mark.xfail(strict=True, raises=struct.error, reason=(
    "sitl_mock/ap_telemetry.py MessageScheduler.set_interval accepts intervals above the int32 "
    "range of MESSAGE_INTERVAL.interval_us; GET_MESSAGE_INTERVAL then raises struct.error"))
def test_get_message_interval_after_a_huge_interval_does_not_escape():
    ap, links, _ = _vehicle("ardupilot")
    msg_id = _M.MAVLINK_MSG_ID_ATTITUDE
    _feed(links, [_command(_M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 3.0e9),
                  _command(_M.MAV_CMD_GET_MESSAGE_INTERVAL, msg_id)])
    msgs = reference_parse(b"".join(ap.drain_outbox()))[0]
    assert [m.get_type() for m in msgs if m.get_type() != "COMMAND_ACK"] == ["MESSAGE_INTERVAL"]


@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "sitl_mock/transport.py VehicleLinks keeps one stream parser per UDP peer: a partial frame at "
    "the end of a datagram stays buffered and swallows the next datagram's frames"))
def test_a_partial_frame_ending_a_datagram_does_not_swallow_the_next_datagram():
    ap, links, _ = _vehicle("ardupilot")
    parser = make_parser()
    links._receive(parser, b"\xfd\xff")      # 2 bytes announcing a 255-byte payload, then nothing
    links._receive(parser, _command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
    acks = [m for m in reference_parse(b"".join(ap.drain_outbox()))[0] if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1


@pytest.mark.xfail(strict=True, raises=struct.error, reason=(
    "sitl_mock/ap_commands.py _cmd_set_home checks lat/lon but not the altitude: above 2147 km "
    "HOME_POSITION.altitude (int32 mm) cannot be packed and struct.error escapes, after the home "
    "was already changed and without a COMMAND_ACK"))
def test_set_home_to_an_absurd_altitude_is_denied_not_raised():
    ap, links, _ = _vehicle("ardupilot")
    home = ap.home
    _feed(links, [_command(_M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, HOME[0], HOME[1], 2_147_484.0)])
    acks = [m for m in reference_parse(b"".join(ap.drain_outbox()))[0] if m.get_type() == "COMMAND_ACK"]
    assert [a.result for a in acks] == [_M.MAV_RESULT_DENIED] and ap.home == home


@pytest.mark.xfail(strict=True, raises=OverflowError, reason=(
    "sitl_mock/ap_flight.py handle_setpoint only checks that a setpoint is finite: one 3.4e38 m "
    "away is followed, and packing its POSITION_TARGET_* echo then raises OverflowError in "
    "send_telemetry on every step (the fleet records the error; the vehicle's telemetry stops)"))
def test_an_absurd_setpoint_is_rejected_and_telemetry_goes_on():
    ap, links, clock = _vehicle("ardupilot", flying=True)
    setpoint = _M.MAVLink_set_position_target_local_ned_message(
        0, SYSID, 1, _M.MAV_FRAME_LOCAL_NED, 0x0DF8, 0, 3.4e38, 1.4e37, 0, 0, 0, 0, 0, 0, 0, 0)
    _feed(links, [encode(setpoint)])
    ap.drain_outbox()
    _run(ap, clock.t_s, 1.0)
    assert reference_parse(b"".join(ap.drain_outbox()))[0]     # telemetry still flows
    assert ap.flight.setpoint is None or np.all(np.abs(ap.flight.setpoint.ned) < _ABSURD_SETPOINT_M)


# ------------------------------------------------------------------------- over a real socket
def _garbage_datagrams(count: int, seed: int) -> list[bytes]:
    """Random bytes, and real commands for this vehicle broken (bad CRC, bit flip, junk)."""
    rnd = random.Random(seed)
    arm = _command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
    out = []
    for _ in range(count):
        kind = rnd.randrange(4)
        if kind == 0:
            out.append(rnd.randbytes(rnd.randrange(1, 300)))
        elif kind == 1:
            out.append(arm[:-2] + bytes((arm[-2] ^ 0x5A, arm[-1])))
        elif kind == 2:
            frame = bytearray(arm)
            frame[rnd.randrange(10, len(frame) - 2)] ^= 1 << rnd.randrange(8)
            out.append(bytes(frame))
        else:
            out.append(b"\xfd" + rnd.randbytes(rnd.randrange(1, 60)))
    return out


def _await_ack(sock, peer, frame: bytes, command: int, timeout_s: float = 30.0):
    parser = make_parser()
    deadline = time.monotonic() + timeout_s
    next_send = 0.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_send:
            sock.sendto(frame, peer)
            next_send = time.monotonic() + 1.0
        if select.select([sock], [], [], 0.2)[0]:
            for msg in parser.parse_buffer(sock.recv(65536)) or []:
                if msg.get_type() == "COMMAND_ACK" and msg.command == command:
                    return msg
    raise AssertionError(f"no COMMAND_ACK for command {command} within {timeout_s} s")


def _wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def test_garbage_datagrams_to_a_running_vehicle_are_counted_and_it_still_answers():
    garbage = _garbage_datagrams(400, seed=5)
    parser = make_parser()
    expected = []                               # frames the vehicle must account for, cumulative
    for data in garbage:
        msgs = parser.parse_buffer(data) or []
        assert not any(is_valid_for(m, SYSID) for m in msgs)   # the garbage holds no valid command
        expected.append((expected[-1] if expected else 0) + len(msgs))
    base = free_port_block(2)
    fleet = MockFleet(1, personality="ardupilot", speedup=5.0, udp_base_port=base,
                      udp_bind_base_port=base + 1, tcp_base_port=0, zenoh=False)
    vehicle = fleet.vehicles[0]
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        fleet.start()
        attacker.bind(("127.0.0.1", 0))
        gcs.bind(("127.0.0.1", 0))
        peer = ("127.0.0.1", vehicle.udp_bind_port)
        before = (vehicle.mode_name, vehicle.armed)
        counted0 = sum(vehicle.counters.get(name, 0) for name in _COUNTED)
        for start in range(0, len(garbage), 25):       # in batches: never overflow the socket buffer
            for data in garbage[start:start + 25]:
                attacker.sendto(data, peer)
            want = expected[min(start + 25, len(garbage)) - 1]
            _wait_for(lambda: sum(vehicle.counters.get(n, 0) for n in _COUNTED) - counted0 >= want,
                      30.0, f"{want} garbage frames counted")
        counters = vehicle.counters
        assert sum(counters.get(n, 0) for n in _COUNTED) - counted0 == expected[-1]
        assert counters["rx_bad_crc"] + counters["rx_malformed"] > 300
        assert (vehicle.mode_name, vehicle.armed) == before
        ack = _await_ack(gcs, peer, _command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION),
                         _M.MAV_CMD_REQUEST_MESSAGE)
        assert ack.result == _M.MAV_RESULT_ACCEPTED
        assert fleet.errors == []
    finally:
        attacker.close()
        gcs.close()
        fleet.stop()
