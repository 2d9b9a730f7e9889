"""The receive fast path (wire.fast_decode) against pymavlink: same message or "not mine".

:func:`decode_single_frame` must return, for any datagram, either None (pymavlink then parses it)
or exactly the message a fresh robust pymavlink parser returns as the datagram's only message:
same class, fields, header, buffers and CRC. Checked on valid frames of every message (MAVLink 1
and 2, signed and unsigned, zero-trimmed payloads), on frames with any payload length and bytes
(truncated, over-long), on corrupted, truncated, spliced and signed-then-broken frames and on
junk. Then, end to end, two endpoints fed the same datagrams (one with the fast path, one
without) count, log (``.tlog``, quarantine), forward and deliver exactly the same, signing on or
off.
"""
from __future__ import annotations

import functools
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator import mavcrc

import mission.link.endpoint_receive as endpoint_receive
from tests.support.fuzz_helpers import (ALL_MESSAGE_CLASSES, SIGNED_REGIONS, FakeClock, _field, encode, message_class,
                                        mutate_signed, mutated, sign, state_repr)
from mission.link.endpoint import MavEndpoint
from mission.core.uri import parse_connection
from wire.fast_decode import FAST_MSG_IDS, decode_single_frame
from tests.support.decode_spy import spy_on_fast_decoder
from mission.core.signing_config import SigningConfig
from wire.signing import signing_timestamp
from mission.link.tlog import read_tlog_records
from mission.vehicle.vehicle_link import VehicleLink

_M = mavlink
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
_SETTINGS = settings(max_examples=300, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
KEY = bytes(range(1, 33))
SYSID = 3
PEER = ("127.0.0.1", 14583)
ORIGIN = (45.19, 5.72, 230.0)
#: signing timestamps near the endpoints' clock (a new stream a minute behind it is "replayed")
STAMP0 = signing_timestamp(FakeClock().time()) + 1000
_FAST_CLASSES = tuple(c for c in ALL_MESSAGE_CLASSES if c.id in FAST_MSG_IDS)
_TELEMETRY_NAMES = ("HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "LOCAL_POSITION_NED",
                    "GLOBAL_POSITION_INT", "ATTITUDE", "COMMAND_ACK", "HOME_POSITION", "BATTERY_STATUS",
                    "STATUSTEXT", "AUTOPILOT_VERSION")


@functools.cache
def _message_of(cls):
    """A message of ``cls`` with random field values: the strategy ``fuzz_helpers.messages`` draws
    from for ``cls`` (the same field strategies), built once per class here (it builds it anew at
    every draw, about a third of this file's CPU)."""
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    fields = {name: _field(ftype, lengths[name]) for name, ftype in zip(cls.fieldnames, cls.fieldtypes)}
    return st.fixed_dictionaries(fields).map(lambda kw: cls(**kw))


def messages(classes=ALL_MESSAGE_CLASSES):
    """Strategy: ``fuzz_helpers.messages(classes)`` (one of ``classes``, random field values),
    each class's strategy built once (:func:`_message_of`)."""
    return st.sampled_from(list(classes)).flatmap(_message_of)


def frames(classes=ALL_MESSAGE_CLASSES, sysid=st.just(255), compid=st.just(190)):
    """Strategy: ``fuzz_helpers.frames`` over :func:`messages` (valid frames; MAVLink 1 for about
    one in five)."""
    return st.builds(encode, messages(classes), sysid, compid, st.integers(0, 255),
                     st.integers(0, 4).map(lambda k: k == 0))


def _pymavlink(data: bytes) -> list:
    parser = _M.MAVLink(None)
    parser.robust_parsing = True
    return parser.parse_buffer(data) or []


def _image(msg) -> str:
    """Everything of a decoded message, NaN-safe (``repr`` of its attributes and header)."""
    attrs = {k: v for k, v in vars(msg).items() if k != "_header"}
    return state_repr(type(msg).__name__, sorted(attrs.items()), sorted(vars(msg._header).items()),
                      type(msg._msgbuf).__name__, type(msg._payload).__name__)


def _agrees(data: bytes) -> bool:
    """The fast path's answer for ``data`` is None or pymavlink's only message; True if it decided."""
    fast = decode_single_frame(data)
    if fast is None:
        return False
    reference = _pymavlink(data)
    assert len(reference) == 1 and reference[0].get_type() not in ("BAD_DATA", "UNKNOWN")
    assert _image(fast) == _image(reference[0])   # (pymavlink's == is False for NaN fields)
    return True


def test_the_high_rate_telemetry_is_on_the_fast_path():
    for name in ("HEARTBEAT", "SYS_STATUS", "EXTENDED_SYS_STATE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                 "ATTITUDE", "COMMAND_ACK", "SET_POSITION_TARGET_LOCAL_NED"):
        assert message_class(name).id in FAST_MSG_IDS, name
    # arrays and strings stay with pymavlink
    for name in ("STATUSTEXT", "BATTERY_STATUS", "AUTOPILOT_VERSION", "PARAM_VALUE", "HOME_POSITION"):
        assert message_class(name).id not in FAST_MSG_IDS, name


@_SETTINGS
@given(frames(ALL_MESSAGE_CLASSES, sysid=st.integers(0, 255), compid=st.integers(0, 255)))
def test_valid_frames_of_every_message_decode_as_pymavlink_does(frame):
    decided = _agrees(frame)
    assert decided == (frame[0] == 0xFD and _pymavlink(frame)[0].get_msgId() in FAST_MSG_IDS)


@_SETTINGS
@given(messages(_FAST_CLASSES), st.integers(0, (1 << 48) - 1), st.integers(0, 255), st.integers(0, 255))
def test_signed_frames_decode_as_a_keyless_pymavlink_parser_does(msg, stamp, link_id, seq):
    frame = sign(msg, KEY, stamp, sysid=SYSID, compid=1, link_id=link_id, seq=seq)
    assert _agrees(frame)


@st.composite
def _any_payload_frame(draw):
    """A frame of a fast-path message with a correct CRC around any payload of 0..255 bytes
    (shorter: MAVLink 2 zero-trimming and truncation; longer: unknown extensions)."""
    cls = draw(st.sampled_from(_FAST_CLASSES))
    payload = draw(st.one_of(st.binary(max_size=255),
                             st.binary(min_size=cls.unpacker.size, max_size=cls.unpacker.size)))
    signed = draw(st.booleans())
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 1 if signed else 0, draw(st.integers(0, 255)),
                         draw(st.integers(0, 255)), draw(st.integers(0, 255)), draw(st.integers(0, 255)),
                         cls.id & 0xFFFF, cls.id >> 16)
    body = header + payload
    crc = mavcrc.x25crc(body[1:])
    crc.accumulate(bytes((cls.crc_extra,)))
    frame = body + crc.crc.to_bytes(2, "little")
    return frame + (draw(st.binary(min_size=13, max_size=13)) if signed else b"")


@_SETTINGS
@given(_any_payload_frame())
def test_any_payload_length_is_padded_or_cut_as_pymavlink_does(frame):
    assert _agrees(frame)


_signed_broken = st.builds(lambda m, s, l: sign(m, KEY, s, sysid=SYSID, compid=1, link_id=l),
                           messages(_FAST_CLASSES), st.integers(0, (1 << 48) - 1), st.integers(0, 255))


@st.composite
def _broken_signed(draw):
    return mutate_signed(draw(_signed_broken), draw(st.sampled_from(SIGNED_REGIONS)), draw)


@_SETTINGS
@given(st.one_of(mutated(frames(_FAST_CLASSES), max_frames=2), mutated(frames(), max_frames=3),
                 _broken_signed(), st.binary(max_size=80),
                 st.lists(frames(_FAST_CLASSES), min_size=2, max_size=3).map(b"".join)))
def test_broken_frames_are_never_accepted_unless_pymavlink_accepts_them(data):
    _agrees(data)   # None (pymavlink decides) or exactly pymavlink's single message


# ------------------------------------------------------------------------------ end to end
def _heartbeat():
    return _M.MAVLink_heartbeat_message(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_PX4, 0, 4, _M.MAV_STATE_STANDBY, 3)


def _endpoint(tmp_path, name, signing):
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=FakeClock(), heartbeat_hz=0,
                     tlog_dir=tmp_path / name, signing=signing, planned_sysids=(SYSID, 4))
    forwarded = []
    ep.forward = lambda frame: forwarded.append(bytes(frame))
    return ep, forwarded


def _feed(ep, datagrams, vl_holder):
    delivered = []
    for peer, data in datagrams:
        ep.receive_datagram(data, peer)
        if vl_holder[0] is None and ep.last_heartbeat(SYSID) is not None:
            vl = VehicleLink(ep, SYSID, ep.last_heartbeat(SYSID), clock=ep.clock, mission_origin=ORIGIN)
            ep.attach(SYSID, lambda m, vl=vl: (delivered.append(bytes(m.get_msgbuf())), vl._on_message(m)),
                      vl._on_link_error)
            vl_holder[0] = vl
    return delivered


def _signed_or_not(msg, sysid, signing, draw_stamp):
    if signing:
        return sign(msg, KEY, draw_stamp, sysid=sysid, compid=1)
    return encode(msg, sysid, 1)


_TELEMETRY_MESSAGES = messages(tuple(message_class(n) for n in _TELEMETRY_NAMES))


@st.composite
def _session(draw, signing):
    """(peer, datagram) pairs: the vehicle's heartbeat first, then its telemetry, forgeries from
    another address, unplanned ids, broken frames and junk, in any order."""
    stamp = STAMP0
    out = [(PEER, _signed_or_not(_heartbeat(), SYSID, signing, stamp))]
    for _ in range(draw(st.integers(1, 25))):
        stamp += draw(st.integers(-3, 1000))
        kind = draw(st.sampled_from(("telemetry", "telemetry", "foreign", "unplanned", "broken", "junk", "v1")))
        # a message only for the kinds that send one (drawing it is most of this test's CPU)
        msg = draw(_TELEMETRY_MESSAGES) if kind != "junk" else None
        if kind in ("telemetry", "foreign", "unplanned"):
            sysid = 77 if kind == "unplanned" else SYSID
            peer = ("127.0.0.1", 9999) if kind == "foreign" else PEER
            out.append((peer, _signed_or_not(msg, sysid, signing and draw(st.integers(0, 5)) > 0, stamp)))
        elif kind == "broken":
            out.append((PEER, draw(mutated(st.just(_signed_or_not(msg, SYSID, signing, stamp)), max_frames=2))))
        elif kind == "v1":
            out.append((PEER, encode(msg, SYSID, 1, mavlink1=True)))
        else:
            out.append((PEER, draw(st.binary(max_size=60))))
    return out


@pytest.mark.parametrize("signing", [False, True])
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_endpoint_with_and_without_fast_path_counts_logs_forwards_and_delivers_the_same(tmp_path_factory, signing,
                                                                                          data):
    datagrams = data.draw(_session(signing))
    results = []
    for fast in (True, False):
        tmp = tmp_path_factory.mktemp("fast" if fast else "slow")
        ep, forwarded = _endpoint(tmp, "tlogs", SigningConfig(KEY, send_setup=False) if signing else None)
        holder = [None]
        original = endpoint_receive.decode_single_frame
        if not fast:
            endpoint_receive.decode_single_frame = lambda d: None
        try:
            delivered = _feed(ep, datagrams, holder)
        finally:
            endpoint_receive.decode_single_frame = original
        ep.tlogs.close()
        if ep.quarantine is not None:
            ep.quarantine.close()
        logs = sorted((p.relative_to(tmp).as_posix(), [f for _, f in read_tlog_records(p)])
                      for p in tmp.rglob("*.tlog"))
        vl = holder[0]
        results.append((dict(ep.counters), forwarded, delivered, logs,
                        vl is not None and state_repr(vl.state, vl.rejected),
                        ep.verifier is not None and dict(ep.verifier.counters)))
    assert results[0] == results[1]


@pytest.mark.parametrize("signing", [False, True])
def test_telemetry_takes_the_fast_path_and_reaches_the_vehicle_tlog_and_forward_byte_for_byte(tmp_path, signing,
                                                                                            monkeypatch):
    ep, forwarded = _endpoint(tmp_path, "tlogs", SigningConfig(KEY, send_setup=False) if signing else None)
    msgs = [_heartbeat(), _M.MAVLink_local_position_ned_message(10, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3),
            _M.MAVLink_global_position_int_message(10, 451900100, 57200200, 233000, 3000, 1, 2, 3, 0),
            _M.MAVLink_sys_status_message(32, 32, 32, 100, 12600, -1, 87, 0, 0, 0, 0, 0, 0)]
    datagrams = [(PEER, _signed_or_not(m, SYSID, signing, STAMP0 + k)) for k, m in enumerate(msgs)]
    fast_hits = spy_on_fast_decoder(monkeypatch, endpoint_receive)
    holder = [None]
    delivered = _feed(ep, datagrams, holder)
    ep.tlogs.close()
    frames_sent = [d for _, d in datagrams]
    assert fast_hits == [True] * len(msgs)
    assert ep.counters["frames_in"] == len(msgs) and forwarded == frames_sent
    assert delivered == frames_sent[1:]   # attached after its first heartbeat
    assert [f for _, f in read_tlog_records(tmp_path / "tlogs" / f"vehicle-{SYSID}.tlog")] == frames_sent
    state = holder[0].state
    assert state.position_ned_m.tolist() == [1.0, 2.0, -3.0] and state.lat_deg == pytest.approx(45.19001)
    if signing:
        assert ep.verifier.counters["accepted"] == len(msgs)
