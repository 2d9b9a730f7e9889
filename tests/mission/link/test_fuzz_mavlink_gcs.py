"""Fuzzing the ground station's MAVLink input path: nothing escapes, every frame is counted,
invalid input changes no vehicle state.

Entry points: ``mission.link.endpoint.MavEndpoint.receive_datagram(data, peer)`` (UDP: one datagram, a
partial frame at its end counted ``truncated``) and ``MavEndpoint.receive_stream_data(data, peer)``
(TCP / serial), the transport callbacks; each parsed frame is counted (``frames_in``,
``bad_crc``, ``malformed``, ``unknown_msgid``) and handed to the attached
:class:`mission.vehicle.vehicle_link.VehicleLink`. The socket-level test goes through a real UDP endpoint.
"""
from __future__ import annotations

import asyncio
import math
import random
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.fuzz_helpers import (ALL_MESSAGE_CLASSES, FakeClock, encode, frames, is_bad, message_class, mutated,
                          reference_parse, state_repr)
from mission.core.clock import WallClock
from mission.link.endpoint import MavEndpoint
from mission.core.uri import parse_connection
from mission.link.poller import UdpPoller
from mission.link.tlog import read_tlog_records
from mission.vehicle.vehicle_link import VehicleLink
from tests.support.wait_helpers import wait_until_async

_M = mavlink
#: NaN and infinite telemetry make numpy warn while the state is updated; that is expected here
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
SYSID = 3
PEER = ("127.0.0.1", 14583)
ORIGIN = (45.19, 5.72, 230.0)
_SETTINGS = settings(max_examples=60, deadline=2000,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_TELEMETRY = tuple(message_class(n) for n in (
    "HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "SYS_STATUS", "BATTERY_STATUS",
    "EXTENDED_SYS_STATE", "HOME_POSITION", "COMMAND_ACK", "AUTOPILOT_VERSION", "STATUSTEXT"))
_COUNTED = ("frames_in", "bad_crc", "malformed")


def _heartbeat():
    """An ArduCopter autopilot HEARTBEAT (GUIDED, disarmed); the sender's id is set by encode()."""
    return _M.MAVLink_heartbeat_message(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 4,
                                        _M.MAV_STATE_STANDBY, 3)


def _endpoint(clock=None):
    """An endpoint (transport not opened) with vehicle ``SYSID`` heard at ``PEER`` and attached."""
    clock = clock if clock is not None else FakeClock()
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=clock, heartbeat_hz=0)
    ep.receive_datagram(encode(_heartbeat(), SYSID, 1), PEER)
    vl = VehicleLink(ep, SYSID, ep.last_heartbeat(SYSID), clock=clock, mission_origin=ORIGIN)
    ep.attach(SYSID, vl._on_message, vl._on_link_error)
    return ep, vl


def _vehicle_state(vl) -> str:
    return state_repr(vl.state, vl.frame_map and vl.frame_map._a, vl.uid, vl.errors, list(vl.statustexts),
                      vl.rejected, vl._last_rx_s)


def _telemetry(**fixed):
    return frames(_TELEMETRY, sysid=st.just(SYSID), compid=st.just(1), **fixed)


_junk = st.lists(st.one_of(st.binary(max_size=40),
                           st.sampled_from([b"\xfd", b"\xfe", b"\xfd\x09\x00\x00", b"\xfe\x09"])),
                 min_size=1, max_size=12).map(b"".join)
_datagram = st.one_of(_junk, mutated(_telemetry(), max_frames=3), mutated(frames(), max_frames=2))


def _counts(ep) -> tuple[int, int, int]:
    c = ep.counters
    return sum(c[n] for n in _COUNTED), c["unknown_msgid"], c["truncated"]


@_SETTINGS
@given(st.lists(_datagram, min_size=1, max_size=8))
def test_garbage_datagrams_are_counted_frame_by_frame_and_change_nothing(datagrams):
    ep, vl = _endpoint()
    parsed = [reference_parse(d) for d in datagrams]   # the endpoint parses each datagram afresh
    msgs = [m for ms, _ in parsed for m in ms]
    assume(not any(not is_bad(m) and m.get_srcSystem() == SYSID for m in msgs))
    before, (counted, unknown, truncated) = _vehicle_state(vl), _counts(ep)
    for data in datagrams:
        ep.receive_datagram(data, PEER)
    after = _counts(ep)
    assert after[0] - counted == len(msgs)
    assert after[1] - unknown == sum(m.get_type().startswith("UNKNOWN") for m in msgs)
    assert after[2] - truncated == sum(left > 0 for _, left in parsed)
    assert _vehicle_state(vl) == before


_stream_piece = st.one_of(_junk, _telemetry(), mutated(_telemetry(), max_frames=2))


@_SETTINGS
@given(st.lists(_stream_piece, min_size=1, max_size=10), st.lists(st.integers(1, 120), max_size=12))
def test_stream_bytes_are_counted_and_valid_frames_survive_any_chunking(pieces, cuts):
    """TCP / serial: however the stream is cut into reads, every valid frame gets through."""
    ep, _ = _endpoint()
    stream = b"".join(pieces)
    chunks, pos = [], 0
    for n in cuts:
        chunks.append(stream[pos:pos + n])
        pos += n
    chunks = [c for c in chunks + [stream[pos:]] if c]
    delivered = []
    ep.detach(SYSID)
    ep.attach(SYSID, delivered.append)
    counted = _counts(ep)[0]
    for chunk in chunks:
        ep.receive_stream_data(chunk, PEER)
    assert _counts(ep)[0] - counted == len(reference_parse(chunks)[0])
    whole = [bytes(m.get_msgbuf()) for m in reference_parse(stream)[0]
             if not is_bad(m) and m.get_srcSystem() == SYSID]
    assert [bytes(m.get_msgbuf()) for m in delivered] == whole


_any_from_vehicle = st.one_of(
    _telemetry(),
    _telemetry(target_system=st.sampled_from([0, 255, 7])),
    frames(ALL_MESSAGE_CLASSES, sysid=st.sampled_from([SYSID, 4, 255]), compid=st.integers(0, 255)))


@_SETTINGS
@given(st.lists(_any_from_vehicle, min_size=1, max_size=10), st.booleans())
def test_random_telemetry_values_never_escape_the_endpoint(frame_list, one_datagram):
    """Real messages with random fields (NaN, infinities, extremes): handled, never raised."""
    ep, vl = _endpoint()
    counted = _counts(ep)[0]
    for data in [b"".join(frame_list)] if one_datagram else frame_list:
        ep.receive_datagram(data, PEER)
    assert _counts(ep)[0] - counted == len(frame_list)
    assert ep.counters["handler_errors"] == 0, ep.last_handler_error
    position = vl.position_enu_m()    # what the coordinator reads next: sane or unknown
    assert position is None or np.all(np.isfinite(position))
    home = vl.home_enu_m()
    assert home is None or np.all(np.isfinite(home))
    vl.state.snapshot()


_WRONG_ACKS = [
    pytest.param(dict(target_system=7), id="other-target-system"),
    pytest.param(dict(command=_M.MAV_CMD_NAV_LAND), id="other-command"),
    pytest.param(dict(src=4), id="other-vehicle"),
    pytest.param(dict(bad_crc=True), id="bad-crc"),
    pytest.param(dict(mavlink1=True, target_system=9), id="mavlink1-other-target"),
]


@pytest.mark.parametrize("wrong", _WRONG_ACKS)
def test_a_command_takes_only_its_own_correctly_addressed_ack(wrong):
    """Forged or misaddressed FAILED acks come first; the command still gets its ACCEPTED."""
    async def scenario():
        ep, vl = _endpoint(WallClock())
        loop = asyncio.get_running_loop()

        def ack(result, command=_M.MAV_CMD_COMPONENT_ARM_DISARM, target_system=255, src=SYSID,
                bad_crc=False, mavlink1=False):
            frame = encode(_M.MAVLink_command_ack_message(command, result, 0, 0, target_system, 190),
                           src, 1, mavlink1=mavlink1)
            return frame[:-1] + bytes((frame[-1] ^ 0xFF,)) if bad_crc else frame

        class _Autopilot:      # answers the first COMMAND_LONG with the wrong ack, then the right one
            def send(self, peer, frame):
                loop.call_soon(ep.receive_datagram, ack(_M.MAV_RESULT_FAILED, **wrong), PEER)
                loop.call_soon(ep.receive_datagram, ack(_M.MAV_RESULT_ACCEPTED), PEER)
                return True

        ep._transport = _Autopilot()
        result = await vl.command_long(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=5.0, retries=0)
        assert result == _M.MAV_RESULT_ACCEPTED
        return ep.counters

    counters = asyncio.run(asyncio.wait_for(scenario(), 30.0))
    assert counters["frames_in"] + counters["bad_crc"] == 3   # heartbeat + both acks, all counted


@pytest.mark.parametrize("fields", [
    pytest.param((451900000, 57200000, 230000, 1e30, 0, 0), id="local-x-1e30"),        # singular frame map
    pytest.param((451900000, 57200000, 230000, math.nan, 0, 0), id="local-x-nan"),
    pytest.param((2147483647, 57200000, 230000, 0, 0, 0), id="latitude-214-deg"),
    pytest.param((451900000, 57200000, 2147483647, 0, 0, 0), id="altitude-2147-km"),
])
def test_absurd_home_position_is_counted_and_changes_nothing(fields):
    ep, vl = _endpoint()
    home = _M.MAVLink_home_position_message(*fields, [1, 0, 0, 0], 0, 0, 0)
    ep.receive_datagram(encode(home, SYSID, 1) + encode(_heartbeat(), SYSID, 1), PEER)
    assert ep.counters["frames_in"] == 3 and ep.counters["handler_errors"] == 0
    assert vl.rejected == {"HOME_POSITION": 1} and vl.frame_map is None and vl.state.home is None


@pytest.mark.parametrize("kind", ["LOCAL_POSITION_NED", "HOME_POSITION"])
def test_non_finite_position_telemetry_is_rejected(kind):
    ep, vl = _endpoint()
    home = _M.MAVLink_home_position_message(451900000, 57200000, 230000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    ep.receive_datagram(encode(home, SYSID, 1), PEER)
    if kind == "LOCAL_POSITION_NED":
        bad = _M.MAVLink_local_position_ned_message(1000, math.nan, 0, -10, 0, 0, 0)
    else:
        bad = _M.MAVLink_home_position_message(451900000, 57200000, 230000, math.nan, 0, 0, [1, 0, 0, 0],
                                               0, 0, 0)
    ep.receive_datagram(encode(_M.MAVLink_local_position_ned_message(900, 1, 2, -10, 0, 0, 0), SYSID, 1)
                        + encode(bad, SYSID, 1), PEER)
    position = vl.position_enu_m()
    assert position is not None and np.all(np.isfinite(position))
    assert vl.rejected == {kind: 1}


def test_a_frame_of_unknown_message_id_goes_to_the_quarantine_log_not_a_vehicle_tlog(tmp_path):
    """Its CRC cannot be checked (no CRC_EXTRA): it is no vehicle's evidence."""
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=FakeClock(), heartbeat_hz=0,
                     tlog_dir=tmp_path)
    try:
        payload = b"\x01\x02\x03"
        frame = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 42, 1, 0xBEEF, 0) + payload + b"\0\0"
        ep.receive_datagram(frame, PEER)
        assert ep.counters["unknown_msgid"] == 1 and ep.counters["quarantined"] == 1
        assert ep.tlogs.paths() == {}
        ep.quarantine.flush()
        assert [f for _, f in read_tlog_records(tmp_path / "quarantine.tlog")] == [frame]
    finally:
        ep.tlogs.close()
        ep.registry.release(ep)


def test_a_handler_that_raises_is_counted_and_the_link_goes_on():
    ep, _ = _endpoint()
    seen = []

    def broken(msg):
        seen.append(msg.get_type())
        raise KeyError("a vehicle-side bug")

    ep.detach(SYSID)
    ep.attach(SYSID, broken)
    ep.receive_datagram(b"".join(encode(_heartbeat(), SYSID, 1) for _ in range(3)), PEER)
    assert seen == ["HEARTBEAT"] * 3
    assert ep.counters["handler_errors"] == 3 and "KeyError" in ep.last_handler_error


# ------------------------------------------------------------------------- over a real socket
def _garbage_datagrams(count: int, seed: int) -> list[bytes]:
    """Random bytes, broken autopilot heartbeats of vehicle 7 and stray frame starts."""
    rnd = random.Random(seed)
    hb = encode(_heartbeat(), 7, 1)
    out = []
    for _ in range(count):
        kind = rnd.randrange(4)
        if kind == 0:
            out.append(rnd.randbytes(rnd.randrange(1, 300)))
        elif kind == 1:
            out.append(hb[:-2] + bytes((hb[-2] ^ 0xA5, hb[-1])))
        elif kind == 2:
            frame = bytearray(hb)
            frame[rnd.randrange(1, len(frame))] ^= 1 << rnd.randrange(8)
            out.append(bytes(frame))
        else:
            out.append(b"\xfd" + rnd.randbytes(rnd.randrange(1, 60)))
    return out


@pytest.mark.parametrize("use_poller", [False, True], ids=["asyncio-transport", "udp-poller"])
def test_garbage_datagrams_to_an_endpoint_are_counted_and_it_still_hears_heartbeats(use_poller):
    garbage = _garbage_datagrams(400, seed=11)
    expected, cumulative = [], (0, 0)
    for data in garbage:
        msgs, left = reference_parse(data)
        assert all(is_bad(m) for m in msgs)        # the garbage holds no valid frame
        cumulative = (cumulative[0] + len(msgs), cumulative[1] + (left > 0))
        expected.append(cumulative)

    async def scenario():
        poller = UdpPoller() if use_poller else None
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=WallClock(), heartbeat_hz=0, poller=poller)
        loop = asyncio.get_running_loop()
        sender, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol,
                                                        remote_addr=tuple(ep.local_address))
        try:
            for start in range(0, len(garbage), 25):    # in batches: never overflow the socket buffer
                for data in garbage[start:start + 25]:
                    sender.sendto(data)
                want = expected[min(start + 25, len(garbage)) - 1]
                await wait_until_async(lambda: (_counts(ep)[0], _counts(ep)[2]) == want, 30.0,
                                       f"{want} garbage frames / truncated datagrams counted")
            assert ep.counters["frames_in"] == ep.counters["unknown_msgid"]   # nothing decoded
            assert ep.counters["bad_crc"] > 50 and ep.counters["malformed"] > 50
            sender.sendto(encode(_heartbeat(), 7, 1))
            sysid, heartbeat = await ep.wait_heartbeat(7, 10.0)
            assert (sysid, heartbeat.autopilot) == (7, _M.MAV_AUTOPILOT_ARDUPILOTMEGA)
            assert ep.counters["frames_in"] == ep.counters["unknown_msgid"] + 1
        finally:
            sender.close()
            await ep.close()
            if poller is not None:
                await poller.close()

    asyncio.run(asyncio.wait_for(scenario(), 120.0))


def test_one_poisonous_datagram_does_not_stop_a_polled_endpoint():
    """A datagram that once made a handler raise (singular HOME_POSITION) and killed the poller."""
    async def scenario():
        poller = UdpPoller()
        clock = WallClock()
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, heartbeat_hz=0, poller=poller)
        loop = asyncio.get_running_loop()
        sender, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol,
                                                        remote_addr=tuple(ep.local_address))
        try:
            sender.sendto(encode(_heartbeat(), SYSID, 1))
            vl = await VehicleLink.create(ep, SYSID, clock=clock, mission_origin=ORIGIN)
            home = _M.MAVLink_home_position_message(451900000, 57200000, 230000, 1e30, 0, 0, [1, 0, 0, 0],
                                                    0, 0, 0)
            sender.sendto(encode(home, SYSID, 1))
            await wait_until_async(lambda: ep.counters["frames_in"] >= 2, 10.0, "the HOME_POSITION")
            sender.sendto(encode(_heartbeat(), SYSID, 1))
            await wait_until_async(lambda: ep.counters["frames_in"] >= 3, 20.0, "a heartbeat after it")
            assert vl.rejected == {"HOME_POSITION": 1} and ep.counters["handler_errors"] == 0
        finally:
            sender.close()
            await ep.close()
            await poller.close()

    asyncio.run(asyncio.wait_for(scenario(), 60.0))
