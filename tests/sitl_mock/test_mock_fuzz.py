"""Fuzzed input: random and mutated bytes change nothing; random valid messages never crash."""
from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings, strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.transport import make_parser

_SETTINGS = settings(max_examples=60, deadline=None,
                     suppress_health_check=[HealthCheck.function_scoped_fixture])


def _autopilot(personality="ardupilot"):
    mc = Multicopter(DynamicsParams(), np.random.default_rng(0))
    ap = MockAutopilot(1, personality, mc, (45.19, 5.72, 230.0), 0.0)
    for k in range(150):  # position estimate ready, telemetry flowing
        ap.step(k * 0.02, 0.02)
        mc.step(0.02)
        ap.send_telemetry(k * 0.02)
    ap.drain_outbox()
    return ap


def _state(ap):
    return (ap.mode_name, ap.armed, ap.params.as_dict(), ap.missions.items(),
            tuple(ap.mc.position_ned_m), ap.sysid)


def _valid_frames():
    gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    msgs = [
        gcs.command_long_encode(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 21196, 0, 0, 0, 0, 0),
        gcs.command_long_encode(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0),
        gcs.param_set_encode(1, 1, b"FS_GCS_ENABLE", 1.0, mav.MAV_PARAM_TYPE_INT8),
        gcs.set_mode_encode(1, 1, 9),
        gcs.mission_count_encode(1, 1, 2, 0),
        gcs.mission_clear_all_encode(1, 1, 0),
    ]
    return [m.pack(gcs) for m in msgs]


_FRAMES = _valid_frames()


def _feed(ap, data: bytes) -> None:
    parser = make_parser()
    for msg in parser.parse_buffer(data) or []:
        ap.handle_message(msg, 3.0)


@_SETTINGS
@given(st.binary(min_size=1, max_size=600))
def test_random_bytes_change_nothing(data):
    ap = _autopilot()
    before = _state(ap)
    _feed(ap, data)
    assert _state(ap) == before
    assert ap.counters["rx_handler_error"] == 0


@_SETTINGS
@given(st.integers(0, len(_FRAMES) - 1), st.lists(st.tuples(st.integers(0, 10_000), st.integers(1, 255)),
                                                  min_size=1, max_size=4))
def test_mutated_frames_change_nothing_and_are_counted(which, flips):
    ap = _autopilot()
    frame = bytearray(_FRAMES[which])
    for pos, xor in flips:
        frame[1 + pos % (len(frame) - 1)] ^= xor  # keep the start marker: a real frame, corrupted
    assume(bytes(frame) != _FRAMES[which])
    before = _state(ap)
    _feed(ap, bytes(frame))
    assert _state(ap) == before
    bad = ap.counters["rx_bad_crc"] + ap.counters["rx_malformed"] + ap.counters["rx_unknown_msg"]
    assert bad >= 1 or ap.counters["rx_frames"] == 0


def test_valid_frames_still_work_after_garbage():
    ap = _autopilot()
    _feed(ap, b"\xfd\x09garbage" + bytes(range(40)))
    parser = make_parser()
    for msg in parser.parse_buffer(b"\x00\x01" + _FRAMES[0]) or []:
        ap.handle_message(msg, 3.0)
    assert ap.armed


_finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                           st.sampled_from([0.0, 1.0, -1.0, math.nan]))


@_SETTINGS
@given(st.sampled_from(["ardupilot", "px4"]), st.integers(0, 65535),
       st.lists(_finite_or_not, min_size=7, max_size=7), st.integers(0, 2 ** 16 - 1),
       st.integers(0, 25))
def test_random_valid_messages_never_crash_the_handlers(personality, command, params, mask, frame):
    ap = _autopilot(personality)
    gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    msgs = [
        gcs.command_long_encode(1, 1, command, 0, *params),
        gcs.command_int_encode(1, 1, frame, command, 0, 0, *params[:4], 0, 0, params[6]),
        gcs.set_position_target_local_ned_encode(0, 1, 1, frame, mask, *params[:6], 0, 0, 0,
                                                 params[6], 0),
        gcs.set_position_target_global_int_encode(0, 1, 1, frame, mask, 451900000, 57200000,
                                                  *params[:4], 0, 0, 0, params[6], 0),
        gcs.mission_item_int_encode(1, 1, command % 5, frame, command, 0, 1, *params[:4], 0, 0,
                                    params[6], 0),
    ]
    parser = make_parser()
    for m in msgs:
        for parsed in parser.parse_buffer(m.pack(gcs)) or []:
            ap.handle_message(parsed, 3.0)
    for k in range(25):
        ap.step(3.0 + k * 0.02, 0.02)
        ap.mc.step(0.02)
        ap.send_telemetry(3.0 + k * 0.02)
    assert ap.counters["rx_handler_error"] == 0, dict(ap.counters)
    assert np.all(np.isfinite(ap.mc.position_ned_m))
