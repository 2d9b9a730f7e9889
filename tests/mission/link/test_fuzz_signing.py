"""Fuzzing both MAVLink input paths WITH MAVLink 2 signing on: nothing escapes, every rejection
is counted under its reason, genuine frames among the junk still get through, and no frame that
is not validly signed (unsigned, another key, replayed, older or stale timestamp, far-future
forgery, tampered header / payload / CRC / flag / link id / timestamp / signature, truncated)
changes any state.

Ground station: ``mission.link.endpoint.MavEndpoint.receive_datagram`` / ``receive_stream_data`` with a
:class:`mission.link.signing.SigningConfig` (counters ``frames_in``, ``bad_crc``, ``malformed``,
``unsigned``, ``bad_signature``, ``replayed``, ``setup_signing_sent``), vehicle state through an
attached :class:`mission.vehicle.vehicle_link.VehicleLink`. Mock: ``sitl_mock.transport.VehicleLinks._receive``
into a :class:`sitl_mock.autopilot.MockAutopilot` with a key (``rx_frames``, ``rx_bad_crc``,
``rx_malformed``, ``rx_unknown_msg``, ``rx_unsigned``, ``rx_bad_signature``, ``rx_replayed``).
The expected outcome of every frame comes from :class:`fuzz_helpers.SigningOracle`, a model of
the specification applied to an independent parse of the same bytes.
"""
from __future__ import annotations

import asyncio
import collections
import hashlib
import selectors

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.fuzz_helpers import (run_autopilot, SIGNED_REGIONS, FakeClock, SigningOracle, encode, message_class, messages,
                          mutate_signed, reference_parse, sign, state_repr)
from mission.link.endpoint_registry import LinkError
from mission.link.endpoint import MavEndpoint
from mission.core.uri import parse_connection
from mission.core.signing_config import SigningConfig
from wire.signing import signing_timestamp
from mission.vehicle.vehicle_link import VehicleLink
from sitl_mock.ap_signing import UNSIGNED_OK_MSG_IDS
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.transport import VehicleLinks, make_parser

_M = mavlink
#: NaN and infinite fields in random messages make numpy warn; expected here
pytestmark = [pytest.mark.filterwarnings("ignore::RuntimeWarning"), pytest.mark.timeout(240)]
KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
T0_S = 1_763_717_000.0
STAMP0 = signing_timestamp(T0_S)
STAMP_MAX = (1 << 48) - 1
ORIGIN = (45.19, 5.72, 230.0)
GCS_ID = (255, 190)
VEHICLE_ID = (3, 1)          # the ground station's vehicle (system, component)
MOCK_SYSID = 1
_SETTINGS = settings(max_examples=150, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_junk = st.lists(st.one_of(st.binary(max_size=40),
                           st.sampled_from([b"\xfd", b"\xfe", b"\xfd\x09\x01\x00", b"\xfd\x20\x01"])),
                 min_size=1, max_size=8).map(b"".join)
#: how far from the genuine stream's timestamp a wrong-key forgery is stamped (10 us units)
_FORGED_OFFSETS = st.sampled_from([0, 1, -10**8, 10**11, "max"])


# ------------------------------------------------------------------ scenario: the frames sent
@st.composite
def _scenario(draw, src, captured, next_stamp, attacks, harmless):
    """Items ``(kind, frame)`` in sending order.

    ``src``: the genuine sender (sysid, compid); ``captured``: genuine frames of the setup
    (replayed as they are); ``next_stamp``: the genuine stream's next timestamp (link id 0);
    ``attacks``: strategy of messages that would change state; ``harmless``: the genuine
    messages interleaved (their acceptance changes no state).
    """
    sysid, compid = src
    last_setup = next_stamp - 1
    sent_good: list[bytes] = []
    items = []
    for kind in draw(st.lists(st.sampled_from(
            ["junk", "good", "good", "unsigned", "wrong_key", "replay", "older", "stale_stream",
             "future_stream", "tampered", "tampered"]), min_size=1, max_size=14)):
        if kind == "junk":
            frame = draw(_junk)
        elif kind in ("good", "future_stream"):
            msg = draw(st.sampled_from(harmless))
            if kind == "good":
                frame = sign(msg, KEY, next_stamp, sysid, compid)
                next_stamp += 1
                sent_good.append(frame)
            else:      # the key holder on a new link: legitimate, even far in the future
                far = draw(st.sampled_from([10**11, STAMP_MAX - next_stamp]))
                frame = sign(msg, KEY, next_stamp + far, sysid, compid, link_id=draw(st.integers(1, 255)))
        elif kind == "replay":
            frame = draw(st.sampled_from(list(captured) + sent_good))
        else:
            msg = draw(attacks)
            if kind == "unsigned":
                frame = encode(msg, sysid, compid, mavlink1=draw(st.booleans()) and msg.get_msgId() < 256)
            elif kind == "wrong_key":
                offset = draw(_FORGED_OFFSETS)
                stamp = STAMP_MAX if offset == "max" else next_stamp + offset
                frame = sign(msg, OTHER_KEY, stamp, sysid, compid)
            elif kind == "older":                                  # right key, not above the last
                frame = sign(msg, KEY, last_setup - draw(st.integers(0, 10**8)), sysid, compid)
            elif kind == "stale_stream":                           # right key, new link, 2+ min old
                frame = sign(msg, KEY, next_stamp - draw(st.integers(12_000_000, 10**10)), sysid,
                             compid, link_id=draw(st.integers(1, 255)))
            else:                                                  # right key, then tampered with
                frame = mutate_signed(sign(msg, KEY, next_stamp, sysid, compid),
                                      draw(st.sampled_from(SIGNED_REGIONS)), draw)
                next_stamp += 1
        items.append((kind, frame))
    return items


def _chunks(items, mode: str, cuts) -> list[bytes]:
    """The datagrams (or stream reads) carrying ``items``."""
    frames = [f for _, f in items]
    if mode == "datagram_each":
        return frames
    stream = b"".join(frames)
    if mode == "one_datagram":
        return [stream]
    out, pos = [], 0
    for n in cuts:
        out.append(stream[pos:pos + n])
        pos += n
    return [c for c in out + [stream[pos:]] if c]


def _expected(oracle, chunks, stream: bool) -> list[tuple[str, bytes]]:
    """``(outcome, frame bytes)`` of every frame in ``chunks`` (datagrams parsed afresh)."""
    parsed = reference_parse(chunks)[0] if stream else [m for c in chunks for m in reference_parse(c)[0]]
    return [(oracle.outcome(m), bytes(m.get_msgbuf())) for m in parsed]


# ------------------------------------------------------------------ ground station
def _vmsg(name, *fields):
    return getattr(_M, f"MAVLink_{name}_message")(*fields)


def _heartbeat(armed: bool, custom_mode: int):
    return _vmsg("heartbeat", _M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_ARDUPILOTMEGA,
                 _M.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, custom_mode, _M.MAV_STATE_ACTIVE, 3)


def _local(north_m, east_m):
    return _vmsg("local_position_ned", 1000, north_m, east_m, -10.0, 0.0, 0.0, 0.0)


def _global(lat_e7):
    return _vmsg("global_position_int", 1000, lat_e7, 57200000, 240000, 10000, 0, 0, 0, 0)


#: the vehicle's genuine setup telemetry: old values first (replays of them would roll back)
_GCS_SETUP = (_heartbeat(True, 3), _global(451910000), _local(50.0, 20.0),
              _vmsg("home_position", 451900000, 57200000, 230000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0),
              _heartbeat(False, 4), _global(451900000), _local(1.0, 2.0))
_GCS_CAPTURED = tuple(sign(m, KEY, STAMP0 + i, *VEHICLE_ID) for i, m in enumerate(_GCS_SETUP))
#: re-sending the current state: accepted, changes nothing
_GCS_HARMLESS = (_GCS_SETUP[4], _GCS_SETUP[6])
_GCS_ATTACKS = (_heartbeat(True, 9), _local(300.0, -40.0), _global(452000000),
                _vmsg("home_position", 452000000, 57300000, 250000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0),
                _vmsg("statustext", _M.MAV_SEVERITY_CRITICAL, b"forged", 0, 0))
_TELEMETRY = tuple(message_class(n) for n in (
    "HEARTBEAT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "SYS_STATUS", "HOME_POSITION",
    "EXTENDED_SYS_STATE", "COMMAND_ACK", "AUTOPILOT_VERSION", "STATUSTEXT"))
_GCS_REASONS = {"bad_crc": "bad_crc", "malformed": "malformed", "unsigned": "unsigned",
                "bad_signature": "bad_signature", "replayed": "replayed", "accepted": "frames_in",
                "unsigned_allowed": "frames_in"}


class _Recorder:
    """A transport that keeps what the endpoint sends."""

    def __init__(self):
        self.sent: list[tuple[object, bytes]] = []

    def send(self, peer, frame) -> bool:
        self.sent.append((peer, bytes(frame)))
        return True

    def default_peer(self):
        return None

    def peers(self):
        return []


def _gcs():
    """A signing endpoint that heard the vehicle's signed setup telemetry, a VehicleLink on it,
    and the list of raw frames delivered to the vehicle."""
    clock = FakeClock(T0_S)
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=clock, heartbeat_hz=0,
                     signing=SigningConfig(KEY))
    ep._transport = _Recorder()
    peer = ("127.0.0.1", 14583)
    ep.receive_datagram(_GCS_CAPTURED[0], peer)
    vl = VehicleLink(ep, VEHICLE_ID[0], ep.last_heartbeat(VEHICLE_ID[0]), clock=clock, mission_origin=ORIGIN)
    delivered: list[bytes] = []

    def on_message(msg):
        delivered.append(bytes(msg.get_msgbuf()))
        vl._on_message(msg)

    ep.attach(VEHICLE_ID[0], on_message, vl._on_link_error)
    for frame in _GCS_CAPTURED[1:]:
        ep.receive_datagram(frame, peer)
    assert ep.counters["frames_in"] == len(_GCS_CAPTURED) and ep.counters["handler_errors"] == 0
    return ep, vl, delivered, peer


def _gcs_state(vl) -> str:
    return state_repr(vl.state, vl.frame_map and vl.frame_map._a, vl.uid, vl.errors,
                      list(vl.statustexts), vl.rejected)


def _sender(frame: bytes) -> int:
    return frame[5] if frame[0] == _M.PROTOCOL_MARKER_V2 else frame[3]


def _signature_ok(frame: bytes, key: bytes) -> bool:
    return bool(frame[2] & 1) and hashlib.sha256(key + frame[:-6]).digest()[:6] == frame[-6:]


_gcs_attacks = st.one_of(st.sampled_from(_GCS_ATTACKS),
                         messages(_TELEMETRY), messages([message_class("RADIO_STATUS")]))
_gcs_scenario = _scenario(VEHICLE_ID, _GCS_CAPTURED, STAMP0 + len(_GCS_CAPTURED), _gcs_attacks,
                          _GCS_HARMLESS)
_MODES = st.sampled_from(["datagram_each", "one_datagram", "stream"])


@_SETTINGS
@given(_gcs_scenario, _MODES, st.lists(st.integers(1, 90), max_size=12),
       st.sampled_from([VEHICLE_ID, (7, 1)]))
def test_ground_station_counts_every_rejection_and_only_genuine_frames_get_through(
        items, mode, cuts, unsigned_hb_src):
    ep, vl, delivered, peer = _gcs()
    # an unsigned autopilot heartbeat: from the vehicle (which signs: never provisioned again)
    # or from a system the mission does not expect (never given the key, counted refused)
    items = items + [("unsigned", encode(_heartbeat(True, 9), *unsigned_hb_src))]
    chunks = _chunks(items, mode, cuts)
    oracle = SigningOracle(KEY, ep.signing_state.timestamp)
    oracle.streams = dict(ep.verifier._streams)
    expected = _expected(oracle, chunks, stream=mode == "stream")
    before_state, before = _gcs_state(vl), dict(ep.counters)
    n_delivered = len(delivered)
    for chunk in chunks:
        (ep.receive_stream_data if mode == "stream" else ep.receive_datagram)(chunk, peer)

    want = collections.Counter(_GCS_REASONS[outcome] for outcome, _ in expected)
    assert {k: ep.counters[k] - before[k] for k in set(_GCS_REASONS.values())} == \
        {k: want[k] for k in set(_GCS_REASONS.values())}
    assert ep.counters["handler_errors"] == 0, ep.last_handler_error
    assert delivered[n_delivered:] == [f for outcome, f in expected if outcome in
                                       ("accepted", "unsigned_allowed") and _sender(f) == VEHICLE_ID[0]]
    accepted = [f for outcome, f in expected if outcome == "accepted"]
    harmless = {f for kind, f in items if kind in ("good", "future_stream", "replay")
                and not any(f == c for c in _GCS_CAPTURED)}
    assert set(accepted) <= harmless                  # nothing forged, replayed or stale accepted
    if mode == "datagram_each":                       # every genuine frame got through
        assert [f for kind, f in items if kind == "good"] == \
            [f for f in accepted if f in {g for k, g in items if k == "good"}]
    assert _gcs_state(vl) == before_state
    # SETUP_SIGNING (the key in clear) never to the vehicle that signs nor to a system the
    # mission does not expect: here nobody gets it, and the unexpected one is counted
    setups = [m for _, f in ep._transport.sent for m in reference_parse(f)[0]
              if m.get_type() == "SETUP_SIGNING"]
    assert setups == [] and ep.counters["setup_signing_sent"] == 0
    if unsigned_hb_src != VEHICLE_ID and mode == "datagram_each":  # its own datagram: it was heard
        assert ep.counters["setup_signing_refused"] >= 1
    # and the ground station still sends validly signed frames, whatever timestamps it heard
    ep._peer_of[VEHICLE_ID[0]] = peer
    sp = _M.MAVLink_set_position_target_local_ned_message(0, 3, 1, 1, 0xDF8, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0)
    assert ep.send(VEHICLE_ID[0], sp)
    assert ep.send_payload(VEHICLE_ID[0], sp.id, sp.crc_extra, sp.pack(_M.MAVLink(None))[10:-2])
    assert all(_signature_ok(f, KEY) for _, f in ep._transport.sent[-2:])


@pytest.mark.parametrize("index", range(len(_GCS_ATTACKS)))
def test_each_ground_station_attack_would_change_the_state_if_validly_signed(index):
    """The 'state unchanged' assertion above can fail: each forged message, signed with the key
    on the vehicle's stream, changes what the ground station knows."""
    ep, vl, delivered, peer = _gcs()
    before = _gcs_state(vl)
    n_delivered = len(delivered)
    ep.receive_datagram(sign(_GCS_ATTACKS[index], KEY, STAMP0 + 100, *VEHICLE_ID), peer)
    assert _gcs_state(vl) != before and len(delivered) == n_delivered + 1


@pytest.mark.parametrize("stamp", [STAMP_MAX, STAMP_MAX - 1, STAMP0 + 10**11])
def test_a_genuine_far_future_timestamp_does_not_break_sending(stamp):
    """A key holder's frame stamped at (or near) the 48-bit maximum was accepted, the shared
    timestamp followed it past 2**48 and every later ``send_payload`` raised OverflowError."""
    ep, vl, delivered, peer = _gcs()
    ep.receive_datagram(sign(_GCS_HARMLESS[0], KEY, stamp, *VEHICLE_ID, link_id=9), peer)
    assert ep.verifier.counters["accepted"] == len(_GCS_CAPTURED) + 1
    sp = _M.MAVLink_set_position_target_local_ned_message(0, 3, 1, 1, 0xDF8, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0)
    payload = sp.pack(_M.MAVLink(None))[10:-2]
    for _ in range(3):
        assert ep.send_payload(VEHICLE_ID[0], sp.id, sp.crc_extra, payload)
        assert ep.send(VEHICLE_ID[0], sp)
    sent = [f for _, f in ep._transport.sent]
    assert len(sent) == 6 and all(_signature_ok(f, KEY) for f in sent)
    # one timestamp per frame, the fast path keeping the low 48 bits as pymavlink's pack does
    assert [f[-12:-6] for f in sent] == [((stamp + k) & STAMP_MAX).to_bytes(6, "little") for k in range(6)]


def test_a_forged_far_future_frame_does_not_lock_out_the_vehicle():
    ep, vl, delivered, peer = _gcs()
    n_delivered = len(delivered)
    for stamp in (STAMP_MAX, STAMP0 + 10**11):
        ep.receive_datagram(sign(_heartbeat(True, 9), OTHER_KEY, stamp, *VEHICLE_ID), peer)
    ep.receive_datagram(sign(_GCS_HARMLESS[0], KEY, STAMP0 + 100, *VEHICLE_ID), peer)
    assert ep.counters["bad_signature"] == 2 and ep.counters["replayed"] == 0
    assert len(delivered) == n_delivered + 1 and not vl.state.armed


# ------------------------------------------------------------------ mock autopilot
_DT_S = 0.02
_MOCK_REASONS = {"bad_crc": "rx_bad_crc", "malformed": "rx_malformed", "unknown": "rx_unknown_msg",
                 "unsigned": "rx_unsigned", "bad_signature": "rx_bad_signature",
                 "replayed": "rx_replayed", "accepted": "rx_frames", "unsigned_allowed": "rx_frames"}


def _cmd(command, *params, target=(MOCK_SYSID, 1)):
    p = [float(v) for v in params] + [0.0] * (7 - len(params))
    return _M.MAVLink_command_long_message(*target, command, 0, *p)


def _setpoint(north_m, east_m, down_m):
    return _M.MAVLink_set_position_target_local_ned_message(
        0, MOCK_SYSID, 1, _M.MAV_FRAME_LOCAL_NED, 0x0DF8, north_m, east_m, down_m, 0, 0, 0, 0, 0, 0, 0, 0)


_ARM = _M.MAV_CMD_COMPONENT_ARM_DISARM
#: genuine setup of each case: (frames before flying 4 s, frames after); replays must not act
_MOCK_SETUP = {
    "ground": ((_cmd(_M.MAV_CMD_DO_SET_MODE, 1, 4), _cmd(_ARM, 1), _cmd(_ARM, 0), _setpoint(20, 10, -12),
                _setpoint(0, 0, -10)), ()),
    "flying": ((_cmd(_M.MAV_CMD_DO_SET_MODE, 1, 4), _cmd(_ARM, 1), _cmd(_M.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 10)),
               (_setpoint(20, 10, -12), _setpoint(0, 0, -10))),
}
_MOCK_CAPTURED = {case: tuple(sign(m, KEY, STAMP0 + i, *GCS_ID) for i, m in enumerate(a + b))
                  for case, (a, b) in _MOCK_SETUP.items()}
_MOCK_HARMLESS = (_cmd(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION),)
_MOCK_ATTACKS = {
    "ground": (_cmd(_ARM, 1), _setpoint(100, 50, -20), _cmd(_ARM, 1, 21196),
               _M.MAVLink_setup_signing_message(MOCK_SYSID, 1, list(OTHER_KEY), STAMP0)),
    "flying": (_cmd(_ARM, 0, 21196), _setpoint(100, 50, -20), _cmd(_M.MAV_CMD_NAV_LAND),
               _cmd(_M.MAV_CMD_NAV_RETURN_TO_LAUNCH)),
}
_ACTED_UPON = tuple(message_class(n) for n in (
    "COMMAND_LONG", "COMMAND_INT", "SET_MODE", "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT", "PARAM_SET", "MISSION_COUNT", "MISSION_CLEAR_ALL",
    "SETUP_SIGNING", "HEARTBEAT", "RADIO_STATUS"))


def _run(ap, t_s: float, duration_s: float) -> float:
    return run_autopilot(ap, t_s, duration_s, _DT_S)


def _mock(personality: str, case: str):
    """A signing mock autopilot past boot that accepted the genuine setup of ``case``."""
    mc = Multicopter(DynamicsParams(), np.random.default_rng(0))
    ap = MockAutopilot(MOCK_SYSID, personality, mc, ORIGIN, T0_S, signing_key=KEY)
    clock = FakeClock(T0_S)
    links = VehicleLinks(ap, clock, selectors.SelectSelector(), np.random.default_rng(0))
    clock.t_s = _run(ap, T0_S, 3.0)
    captured = _MOCK_CAPTURED[case]
    first = len(_MOCK_SETUP[case][0])
    parser = make_parser()
    for frame in captured[:first]:
        links._receive(parser, frame)
    if case == "flying":
        clock.t_s = _run(ap, clock.t_s, 4.0)
        for frame in captured[first:]:
            links._receive(parser, frame)
    assert ap.counters["rx_frames"] == len(captured) and ap.armed == (case == "flying")
    assert not any(ap.counters[k] for k in ("rx_unsigned", "rx_bad_signature", "rx_replayed"))
    ap.drain_outbox()
    return ap, links


def _mock_state(ap) -> str:
    fs = ap.flight
    return state_repr(ap.mode_name, ap.armed, ap.failsafe, ap.home, ap.mc.mode, ap.mc.position_target_ned_m,
                      ap.params.as_dict(), [ap.missions.items(kind) for kind in (0, 1, 2)], fs.setpoint,
                      fs.last_setpoint_s, fs.takeoff_alt_m, ap.last_gcs_heartbeat_s, ap.signing._key)


def _acks(ap) -> list[tuple[int, int]]:
    return [(m.command, m.result) for m in reference_parse(b"".join(ap.drain_outbox()))[0]
            if m.get_type() == "COMMAND_ACK"]


@st.composite
def _mock_case(draw):
    personality, case = draw(st.sampled_from(["ardupilot", "px4"])), draw(st.sampled_from(["ground", "flying"]))
    attacks = st.one_of(st.sampled_from(_MOCK_ATTACKS[case]),
                        messages(_ACTED_UPON, target_system=st.sampled_from([0, MOCK_SYSID]),
                                 target_component=st.sampled_from([0, 1])))
    items = draw(_scenario(GCS_ID, _MOCK_CAPTURED[case], STAMP0 + len(_MOCK_CAPTURED[case]), attacks,
                           _MOCK_HARMLESS))
    return personality, case, items


@_SETTINGS
@given(_mock_case(), _MODES, st.lists(st.integers(1, 90), max_size=12))
def test_mock_counts_every_rejection_and_only_genuine_commands_act(case_items, mode, cuts):
    personality, case, items = case_items
    ap, links = _mock(personality, case)
    chunks = _chunks(items, mode, cuts)
    oracle = SigningOracle(KEY, ap.signing.timestamp, UNSIGNED_OK_MSG_IDS, check_unknown=False)
    oracle.streams = dict(ap.signing._streams)
    expected = _expected(oracle, chunks, stream=mode == "stream")
    before_state, before = _mock_state(ap), ap.counters.copy()
    parser = make_parser()           # one peer, one parser, as the transport keeps
    for chunk in chunks:
        links._receive(parser, chunk, stream=mode == "stream")

    want = collections.Counter(_MOCK_REASONS[outcome] for outcome, _ in expected)
    assert {k: ap.counters[k] - before[k] for k in set(_MOCK_REASONS.values())} == \
        {k: want[k] for k in set(_MOCK_REASONS.values())}
    assert ap.counters["rx_parser_error"] == ap.counters["rx_handler_error"] == 0, ap.last_error
    accepted = [f for outcome, f in expected if outcome == "accepted"]
    harmless = {f for kind, f in items if kind in ("good", "future_stream", "replay")
                and f not in _MOCK_CAPTURED[case]}
    assert set(accepted) <= harmless                  # nothing forged, replayed or stale accepted
    # every accepted genuine request was answered, and with one datagram each none was lost
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)] * len(accepted)
    if mode == "datagram_each":
        assert {f for kind, f in items if kind == "good"} <= set(accepted)
    assert _mock_state(ap) == before_state


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
@pytest.mark.parametrize("case, index", [(c, i) for c in _MOCK_ATTACKS for i in range(len(_MOCK_ATTACKS[c]))])
def test_each_mock_attack_would_change_the_state_if_validly_signed(personality, case, index):
    """The 'state unchanged' assertion above can fail: each attack, signed with the key on the
    ground station's stream, acts."""
    ap, links = _mock(personality, case)
    before = _mock_state(ap)
    links._receive(make_parser(), sign(_MOCK_ATTACKS[case][index], KEY, STAMP0 + 100, *GCS_ID))
    assert ap.counters["rx_frames"] == len(_MOCK_CAPTURED[case]) + 1
    assert _mock_state(ap) != before


def test_mock_keeps_talking_after_a_genuine_maximum_timestamp():
    ap, links = _mock("ardupilot", "ground")
    links._receive(make_parser(), sign(_MOCK_HARMLESS[0], KEY, STAMP_MAX, *GCS_ID, link_id=4))
    assert _acks(ap) == [(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAV_RESULT_ACCEPTED)]
    _run(ap, T0_S + 10.0, 0.5)
    frames = ap.drain_outbox()
    assert frames and all(_signature_ok(f, KEY) for f in frames) and ap.counters["tx_error"] == 0


@pytest.mark.parametrize("wait_for", [True, False])
def test_the_key_goes_only_to_a_system_id_the_mission_waits_for(wait_for):
    """An unsigned autopilot heartbeat from system id 7 gets SETUP_SIGNING only once the
    mission waits for system id 7; before that it is refused and counted."""
    ep, _vl, _delivered, peer = _gcs()
    hb = encode(_heartbeat(True, 9), 7, 1)
    ep.receive_datagram(hb, ("127.0.0.1", 14600))
    assert ep.counters["setup_signing_refused"] == 1 and ep.counters["setup_signing_sent"] == 0

    async def _wait():
        with pytest.raises(LinkError, match="no autopilot HEARTBEAT from system id 7"):
            await ep.wait_heartbeat(7, 0.0)

    if wait_for:
        asyncio.run(_wait())
    ep.clock.t_s += 2.0  # past the once-a-second limit
    ep.receive_datagram(hb, ("127.0.0.1", 14600))
    setups = [m for _, f in ep._transport.sent for m in reference_parse(f)[0]
              if m.get_type() == "SETUP_SIGNING"]
    assert [m.target_system for m in setups] == ([7] if wait_for else [])
    assert ep.counters["setup_signing_refused"] == (1 if wait_for else 2)
