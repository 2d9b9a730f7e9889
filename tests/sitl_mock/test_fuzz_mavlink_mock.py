"""Fuzzing the mock autopilot's MAVLink input path: nothing escapes, every frame is counted,
invalid input changes nothing.

Entry point: ``sitl_mock.transport.VehicleLinks._receive(parser, data)``, what the UDP and TCP
handlers call with each datagram / chunk and that peer's parser; it hands every parsed message to
``MockAutopilot.handle_message``, which accepts it (``rx_frames``) or counts why not
(``rx_bad_crc``, ``rx_malformed``, ``rx_unknown_msg``). A datagram is a whole unit: a partial
frame ending it is counted (``rx_truncated``) and dropped, so the expected frames are those of
each datagram parsed afresh. The socket-level test goes through a running
:class:`~sitl_mock.fleet.MockFleet`.
"""
from __future__ import annotations

import math
import random
import select
import selectors
import socket
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.sim.embedded import free_port_block
from sitl_mock.ap_commands import COMMANDS
from sitl_mock.ap_telemetry import BUILDERS
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.fleet import MockFleet
from sitl_mock.transport import VehicleLinks, make_parser
from tests.support.fuzz_helpers import (run_autopilot, ALL_MESSAGE_CLASSES, FakeClock, encode, frames, is_bad, is_valid_for, message_class,
                          mutated, reference_parse, state_repr)
from tests.support.wait_helpers import wait_until

_M = mavlink
SYSID = 1
HOME = (45.19, 5.72, 230.0)
_DT_S = 0.02
_SETTINGS = settings(max_examples=60, deadline=2000,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
#: every counter of a frame the receive path took in: accepted, rejected (a random SETUP_SIGNING
#: can turn signing on: then unsigned frames are rejected) or dropped by a link fault
_COUNTED = ("rx_frames", "rx_bad_crc", "rx_malformed", "rx_unknown_msg", "rx_unsigned",
            "rx_bad_signature", "rx_replayed", "rx_dropped_link", "rx_dropped_loss")
#: messages the mock acts upon (commands, setpoints, parameters, missions)
_ACTED_UPON = tuple(message_class(n) for n in (
    "COMMAND_LONG", "COMMAND_INT", "SET_MODE", "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT", "PARAM_SET", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST",
    "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
    "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_ACK", "REQUEST_DATA_STREAM", "TIMESYNC",
    "HEARTBEAT"))
_COMMAND_IDS = st.one_of(st.sampled_from(sorted(COMMANDS)), st.integers(0, 0xFFFF))
#: setpoints farther than this (m) are absurd: the mock rejects them (setpoint_out_of_range)
_ABSURD_SETPOINT_M = 1e6


def _run(ap, t_s: float, duration_s: float) -> float:
    return run_autopilot(ap, t_s, duration_s, _DT_S)


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


def _parse_datagrams(datagrams) -> tuple[list, int]:
    """What the mock must account for: ``(messages, datagrams ending in a partial frame)``, each
    datagram parsed afresh (a datagram is a whole unit, its partial tail is dropped)."""
    parsed = [reference_parse(d) for d in datagrams]
    return [m for msgs, _ in parsed for m in msgs], sum(left > 0 for _, left in parsed)


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
                       command=_COMMAND_IDS)


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(), st.lists(_junk, min_size=1, max_size=6))
def test_random_bytes_are_counted_and_change_nothing(personality, flying, datagrams):
    ap, links, _ = _vehicle(personality, flying)
    msgs, truncated = _parse_datagrams(datagrams)
    assume(not any(is_valid_for(m, SYSID) for m in msgs))
    before, counted, truncated0 = _state(ap), _counted(ap), ap.counters["rx_truncated"]
    _feed(links, datagrams)
    assert _state(ap) == before
    assert _counted(ap) - counted == len(msgs)
    assert ap.counters["rx_truncated"] - truncated0 == truncated
    assert ap.drain_outbox() == []          # no answer to garbage
    assert ap.counters["rx_parser_error"] == 0


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.booleans(),
       st.lists(mutated(_acted_frames), min_size=1, max_size=4))
def test_broken_frames_of_real_commands_are_counted_and_change_nothing(personality, flying, datagrams):
    ap, links, _ = _vehicle(personality, flying)
    msgs, truncated = _parse_datagrams(datagrams)
    assume(not any(is_valid_for(m, SYSID) for m in msgs))
    before, counted, accepted = _state(ap), _counted(ap), ap.counters["rx_frames"]
    truncated0 = ap.counters["rx_truncated"]
    _feed(links, datagrams)
    assert _state(ap) == before
    assert _counted(ap) - counted == len(msgs)
    assert ap.counters["rx_truncated"] - truncated0 == truncated
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
           target_system=st.sampled_from([0, SYSID]), command=_COMMAND_IDS))


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


def _acks(ap) -> list[tuple[int, int]]:
    """``(command, result)`` of the COMMAND_ACKs the vehicle sent since the last drain."""
    return [(m.command, m.result) for m in reference_parse(b"".join(ap.drain_outbox()))[0]
            if m.get_type() == "COMMAND_ACK"]


_AUTOPILOT_VERSION_REQUEST = _command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)


@pytest.mark.parametrize("kind", ["COMMAND_LONG", "COMMAND_INT"])
def test_request_protocol_version_is_answered_without_escaping(kind):
    """pymavlink's ardupilotmega dialect has no PROTOCOL_VERSION (300): UNSUPPORTED, and the
    rest of the datagram is still acted upon."""
    ap, links, _ = _vehicle("ardupilot")
    if kind == "COMMAND_LONG":
        frame = _command(_M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1)
    else:
        frame = encode(_M.MAVLink_command_int_message(SYSID, 1, 0, _M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 0, 0,
                                                      1, 0, 0, 0, 0, 0, 0))
    _feed(links, [frame + _AUTOPILOT_VERSION_REQUEST])
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_PROTOCOL_VERSION, _M.MAV_RESULT_UNSUPPORTED),
                         (_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)]   # 2nd not lost
    assert ap.counters["rx_handler_error"] == 0


@pytest.mark.parametrize("interval_us", [2.0 ** 31, 3.0e9, 3.4e38])
def test_an_interval_beyond_int32_is_denied_and_get_message_interval_still_answers(interval_us):
    ap, links, _ = _vehicle("ardupilot")
    msg_id = _M.MAVLINK_MSG_ID_ATTITUDE
    before = ap.scheduler.interval_us(msg_id)
    _feed(links, [_command(_M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us),
                  _command(_M.MAV_CMD_GET_MESSAGE_INTERVAL, msg_id)])
    msgs = reference_parse(b"".join(ap.drain_outbox()))[0]
    acks = [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"]
    assert acks == [(_M.MAV_CMD_SET_MESSAGE_INTERVAL, _M.MAV_RESULT_DENIED),
                    (_M.MAV_CMD_GET_MESSAGE_INTERVAL, _M.MAV_RESULT_ACCEPTED)]
    assert [(m.message_id, m.interval_us) for m in msgs if m.get_type() == "MESSAGE_INTERVAL"] == [(msg_id, before)]


def test_the_longest_int32_interval_is_accepted_and_reported():
    ap, links, _ = _vehicle("px4")
    msg_id = _M.MAVLINK_MSG_ID_ATTITUDE
    _feed(links, [_command(_M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 2 ** 31 - 128),   # a float32 value
                  _command(_M.MAV_CMD_GET_MESSAGE_INTERVAL, msg_id)])
    msgs = reference_parse(b"".join(ap.drain_outbox()))[0]
    assert [m.interval_us for m in msgs if m.get_type() == "MESSAGE_INTERVAL"] == [2 ** 31 - 128]


@pytest.mark.parametrize("tail", [b"\xfd\xff", b"\xfe", _AUTOPILOT_VERSION_REQUEST[:-1]])
def test_a_partial_frame_ending_a_datagram_does_not_swallow_the_next_datagram(tail):
    ap, links, _ = _vehicle("ardupilot")
    parser = make_parser()                   # one parser per UDP peer, as the transport keeps
    links._receive(parser, _AUTOPILOT_VERSION_REQUEST + tail)
    links._receive(parser, _AUTOPILOT_VERSION_REQUEST)
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)] * 2
    assert ap.counters["rx_truncated"] == 1


def test_a_frame_split_across_tcp_reads_is_reassembled():
    """A stream is not a datagram: a partial frame waits for the next read."""
    ap, links, _ = _vehicle("ardupilot")
    parser = make_parser()
    for cut in (3, 17, len(_AUTOPILOT_VERSION_REQUEST) - 1):
        links._receive(parser, _AUTOPILOT_VERSION_REQUEST[:cut], stream=True)
        links._receive(parser, _AUTOPILOT_VERSION_REQUEST[cut:], stream=True)
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)] * 3
    assert ap.counters["rx_truncated"] == 0


@pytest.mark.parametrize("lat_deg, lon_deg, alt_m", [
    (HOME[0], HOME[1], 2_147_484.0),          # HOME_POSITION.altitude (int32 mm) overflows
    (HOME[0], HOME[1], 1.0e5 + 1.0),
    (HOME[0], HOME[1], -1.0e4 - 1.0),
    (HOME[0], HOME[1], -3.4e38),
    (90.5, HOME[1], 230.0),
    (HOME[0], -180.5, 230.0),
    (HOME[0], HOME[1], math.nan),
])
def test_set_home_out_of_range_is_denied_and_changes_nothing(lat_deg, lon_deg, alt_m):
    ap, links, _ = _vehicle("ardupilot")
    home, home_ned = ap.home, ap.home_ned.copy()
    _feed(links, [_command(_M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, lat_deg, lon_deg, alt_m)])
    assert _acks(ap) == [(_M.MAV_CMD_DO_SET_HOME, _M.MAV_RESULT_DENIED)]
    assert ap.home == home and np.array_equal(ap.home_ned, home_ned)


def test_set_home_within_range_is_accepted():
    """The DENIED above can fail: a reasonable new home is taken."""
    ap, links, _ = _vehicle("ardupilot")
    _feed(links, [_command(_M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, HOME[0] + 0.001, HOME[1], 9.0e4)])
    assert _acks(ap) == [(_M.MAV_CMD_DO_SET_HOME, _M.MAV_RESULT_ACCEPTED)]
    assert ap.home == pytest.approx((HOME[0] + 0.001, HOME[1], 9.0e4))


_LOCAL = _M.MAVLink_set_position_target_local_ned_message
_GLOBAL = _M.MAVLink_set_position_target_global_int_message


@pytest.mark.parametrize("setpoint", [
    _LOCAL(0, SYSID, 1, _M.MAV_FRAME_LOCAL_NED, 0x0DF8, 0, 3.4e38, 1.4e37, 0, 0, 0, 0, 0, 0, 0, 0),
    _LOCAL(0, SYSID, 1, _M.MAV_FRAME_LOCAL_NED, 0x0DF8, 1.0e6 + 1.0, 0, -10, 0, 0, 0, 0, 0, 0, 0, 0),
    _LOCAL(0, SYSID, 1, _M.MAV_FRAME_LOCAL_OFFSET_NED, 0x0DF8, 0, 0, -3.4e38, 0, 0, 0, 0, 0, 0, 0, 0),
    _GLOBAL(0, SYSID, 1, _M.MAV_FRAME_GLOBAL_INT, 0x0DF8, 451900000, 57200000, 3.4e38, 0, 0, 0, 0, 0, 0, 0, 0),
    _GLOBAL(0, SYSID, 1, _M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0x0DF8, 451900000, 57200000, -2.0e6,
            0, 0, 0, 0, 0, 0, 0, 0),
    _GLOBAL(0, SYSID, 1, _M.MAV_FRAME_GLOBAL_INT, 0x0DF8, 2_000_000_000, 57200000, 250, 0, 0, 0, 0, 0, 0, 0, 0),
])
def test_an_absurd_setpoint_is_rejected_and_telemetry_goes_on(setpoint):
    ap, links, clock = _vehicle("ardupilot", flying=True)
    target = ap.mc.position_target_ned_m.copy()
    _feed(links, [encode(setpoint)])
    assert ap.counters["setpoint_out_of_range"] == 1
    ap.drain_outbox()
    _run(ap, clock.t_s, 1.0)
    kinds = {m.get_type() for m in reference_parse(b"".join(ap.drain_outbox()))[0]}
    assert {"HEARTBEAT", "GLOBAL_POSITION_INT"} <= kinds          # telemetry still flows
    assert np.array_equal(ap.mc.position_target_ned_m, target)
    assert ap.counters["tx_error"] == 0


def test_a_far_but_sane_setpoint_is_followed():
    """The rejections above can fail: a setpoint 100 km away is taken."""
    ap, links, _ = _vehicle("ardupilot", flying=True)
    _feed(links, [encode(_LOCAL(0, SYSID, 1, _M.MAV_FRAME_LOCAL_NED, 0x0DF8, 1.0e5, 0, -10,
                                0, 0, 0, 0, 0, 0, 0, 0))])
    assert ap.counters["setpoint_out_of_range"] == 0
    assert ap.mc.position_target_ned_m.tolist() == [1.0e5, 0.0, -10.0]


def test_a_handler_that_raises_anything_is_counted_and_the_datagram_goes_on(monkeypatch):
    ap, links, _ = _vehicle("ardupilot")

    def broken(ap_, params, t_s, msg):
        raise KeyError("boom")

    monkeypatch.setitem(COMMANDS, _M.MAV_CMD_NAV_LAND, broken)
    _feed(links, [_command(_M.MAV_CMD_NAV_LAND) + _AUTOPILOT_VERSION_REQUEST])
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)]
    assert ap.counters["rx_handler_error"] == ap.counters["rx_handler_error:KeyError"] == 1
    assert ap.last_error is not None and "COMMAND_LONG" in ap.last_error and "boom" in ap.last_error


def test_a_telemetry_message_that_cannot_be_built_does_not_silence_the_vehicle(monkeypatch):
    ap, _, clock = _vehicle("ardupilot")

    def broken(ap_, t_s):
        raise RuntimeError("cannot encode")

    monkeypatch.setitem(BUILDERS, _M.MAVLINK_MSG_ID_ATTITUDE, broken)
    _run(ap, clock.t_s, 1.0)
    kinds = {m.get_type() for m in reference_parse(b"".join(ap.drain_outbox()))[0]}
    assert "ATTITUDE" not in kinds and {"HEARTBEAT", "GLOBAL_POSITION_INT"} <= kinds
    assert ap.counters["tx_error"] == ap.counters["tx_error:RuntimeError"] > 0
    assert "RuntimeError" in ap.last_error


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


def test_garbage_datagrams_to_a_running_vehicle_are_counted_and_it_still_answers():
    garbage = _garbage_datagrams(400, seed=5)
    expected = []             # (frames, truncated datagrams) the vehicle must account for, cumulative
    for data in garbage:
        msgs, truncated = _parse_datagrams([data])
        assert not any(is_valid_for(m, SYSID) for m in msgs)   # the garbage holds no valid command
        total = expected[-1] if expected else (0, 0)
        expected.append((total[0] + len(msgs), total[1] + truncated))
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
        truncated0 = vehicle.counters.get("rx_truncated", 0)
        for start in range(0, len(garbage), 25):       # in batches: never overflow the socket buffer
            for data in garbage[start:start + 25]:
                attacker.sendto(data, peer)
            want, want_truncated = expected[min(start + 25, len(garbage)) - 1]
            wait_until(lambda: (sum(vehicle.counters.get(n, 0) for n in _COUNTED) - counted0 >= want
                                and vehicle.counters.get("rx_truncated", 0) - truncated0 >= want_truncated),
                       30.0, f"{want} garbage frames and {want_truncated} truncated datagrams counted")
        counters = vehicle.counters
        assert sum(counters.get(n, 0) for n in _COUNTED) - counted0 == expected[-1][0]
        assert counters.get("rx_truncated", 0) - truncated0 == expected[-1][1] > 0
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
