"""The mock autopilot's UDP receive path decodes single-frame datagrams with wire.fast_decode.

``VehicleLinks._receive`` hands ``MockAutopilot.handle_message`` the message of a one-frame
datagram from :func:`wire.fast_decode.decode_single_frame` and everything else (several frames,
a bad CRC, a truncated tail, a message with a string field, MAVLink 1, TCP chunks) from the
peer's pymavlink parser. The autopilot must see exactly what pymavlink alone would give it:
the same messages, fields, frame bytes and header, and the same counters.
"""
from __future__ import annotations

import selectors

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

import sitl_mock.transport as transport
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics import Multicopter
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.transport import VehicleLinks, make_parser
from tests.support.decode_spy import spy_on_fast_decoder
from tests.support.fuzz_helpers import FakeClock, encode

_M = mavlink
HOME = (45.19, 5.72, 230.0)


def _setpoint(north_m: float, east_m: float, down_m: float):
    return _M.MAVLink_set_position_target_local_ned_message(
        1000, 1, 1, _M.MAV_FRAME_LOCAL_NED, 0b110111111000, north_m, east_m, down_m,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _signed(msg) -> bytes:
    enc = _M.MAVLink(None, srcSystem=255, srcComponent=190)
    enc.signing.secret_key = bytes(range(32))
    enc.signing.sign_outgoing = True
    enc.signing.timestamp = 123456
    return bytes(msg.pack(enc))


def _datagrams() -> list[bytes]:
    sp = encode(_setpoint(1.0, 2.0, -3.0), seq=7)
    cmd = encode(_M.MAVLink_command_long_message(1, 1, _M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                 1, 0, 0, 0, 0, 0, 0))
    bad_crc = sp[:-1] + bytes([sp[-1] ^ 0xFF])
    return [
        sp,                                        # one valid frame: the fast path
        cmd,
        encode(_M.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)),
        _signed(_setpoint(4.0, 5.0, -6.0)),         # signed: decoded key-less, checked afterwards
        sp + cmd,                                  # two frames: pymavlink
        bad_crc,                                   # pymavlink's BAD_DATA
        sp[:-5],                                   # truncated: rx_truncated
        encode(_M.MAVLink_param_set_message(1, 1, b"MPC_XY_VEL_MAX", 5.0, 9)),  # a string field
        encode(_setpoint(0.5, 0.5, -1.0), mavlink1=True),  # MAVLink 1
        b"\x00\x01garbage",
    ]


def _received(monkeypatch, fast: bool):
    """What the autopilot was handed for every datagram of :func:`_datagrams`, and its counters."""
    if not fast:
        monkeypatch.setattr(transport, "decode_single_frame", lambda data: None)
    decoded = spy_on_fast_decoder(monkeypatch, transport)
    ap = MockAutopilot(1, "px4", Multicopter(DynamicsParams(), np.random.default_rng(0)), HOME, 0.0)
    seen = []
    monkeypatch.setattr(ap, "handle_message", lambda msg, t_s: seen.append(msg))
    links = VehicleLinks(ap, FakeClock(0.0), selectors.SelectSelector(), np.random.default_rng(0))
    parser = make_parser()
    for data in _datagrams():
        links._receive(parser, data)
    monkeypatch.undo()
    return seen, decoded, dict(ap.counters)


def _key(msg):
    return (type(msg).__name__, msg.get_header().__dict__, bytes(msg.get_msgbuf()),
            str(msg.to_dict()), msg.get_crc() if msg.get_type() != "BAD_DATA" else None)


def test_single_frame_datagrams_reach_the_autopilot_as_pymavlink_would_give_them(monkeypatch):
    plain, plain_decoded, plain_counters = _received(monkeypatch, fast=False)
    fast, fast_decoded, fast_counters = _received(monkeypatch, fast=True)
    assert not any(plain_decoded)
    # the fast path took the four one-frame datagrams of fixed-layout messages, nothing else
    assert fast_decoded == [True, True, True, True] + [False] * 6
    assert [_key(m) for m in fast] == [_key(m) for m in plain]
    assert len(fast) >= 9  # every datagram's messages, the bad ones as BAD_DATA
    assert fast_counters == plain_counters
    assert fast_counters.get("rx_truncated") == 1


def test_a_tcp_chunk_always_goes_through_pymavlinks_stream_parser(monkeypatch):
    calls = []
    monkeypatch.setattr(transport, "decode_single_frame", lambda data: calls.append(data))
    ap = MockAutopilot(1, "ardupilot", Multicopter(DynamicsParams(), np.random.default_rng(0)), HOME, 0.0)
    seen = []
    monkeypatch.setattr(ap, "handle_message", lambda msg, t_s: seen.append(msg))
    links = VehicleLinks(ap, FakeClock(0.0), selectors.SelectSelector(), np.random.default_rng(0))
    frame = encode(_setpoint(1.0, 2.0, -3.0))
    parser = make_parser()
    links._receive(parser, frame[:9], stream=True)  # a frame split across two reads
    links._receive(parser, frame[9:], stream=True)
    assert calls == []
    assert [m.get_type() for m in seen] == ["SET_POSITION_TARGET_LOCAL_NED"]
