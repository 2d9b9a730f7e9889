"""sitl_mock.ap_frames packs the same bytes as pymavlink, and the autopilot still signs with pymavlink."""
from __future__ import annotations

import random

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sitl_mock.ap_frames import pack_unsigned_v2
from sitl_mock.ap_telemetry import BUILDERS
from tests.sitl_mock.test_mock_autopilot import Harness

_INT_RANGES = {"B": (0, 255), "b": (-128, 127), "H": (0, 65535), "h": (-32768, 32767),
               "I": (0, 2**32 - 1), "i": (-2**31, 2**31 - 1), "Q": (0, 2**64 - 1), "q": (-2**63, 2**63 - 1)}


def _random_message(cls, rng: random.Random, zeros: bool):
    """An instance of ``cls`` with random field values (many zeros when ``zeros``: the cut tail)."""
    values = []
    fmt = cls.unpacker.format.lstrip("<")
    by_name = dict(zip(cls.ordered_fieldnames, fmt))
    for name in cls.fieldnames:
        code = by_name[name]
        if zeros and rng.random() < 0.6:
            values.append(0.0 if code in "fd" else 0)
        elif code in "fd":
            values.append(rng.uniform(-1e4, 1e4))
        else:
            values.append(rng.randint(*_INT_RANGES[code]))
    return cls(*values)


def _telemetry_classes():
    classes = [mav.mavlink_map[msg_id] for msg_id in BUILDERS]
    return [c for c in classes if not any(c.array_lengths)]


@pytest.mark.parametrize("cls", _telemetry_classes() + [mav.MAVLink_command_ack_message,
                                                        mav.MAVLink_mission_count_message],
                         ids=lambda c: c.msgname)
def test_frames_are_byte_identical_to_pymavlink(cls):
    rng = random.Random(cls.id)
    for k in range(200):
        msg = _random_message(cls, rng, zeros=k % 2 == 0)
        seq, sysid, compid = rng.randrange(256), rng.randint(1, 255), rng.choice((1, 190))
        enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        enc.seq = seq
        assert pack_unsigned_v2(msg, seq, sysid, compid) == msg.pack(enc)


def test_all_zero_payload_keeps_one_byte_as_pymavlink():
    msg = mav.MAVLink_extended_sys_state_message(0, 0)
    enc = mav.MAVLink(None, srcSystem=3, srcComponent=1)
    enc.seq = 7
    frame = pack_unsigned_v2(msg, 7, 3, 1)
    assert frame == msg.pack(enc) and frame[1] == 1


def test_messages_with_arrays_are_left_to_pymavlink():
    msg = mav.MAVLink_battery_status_message(0, 1, 3, 32767, [4000] * 10, -1, -1, -1, 80)
    assert pack_unsigned_v2(msg, 0, 1, 1) is None


def test_signed_autopilot_frames_are_signed_by_pymavlink_and_verify():
    """With a key every frame the autopilot emits is signed (13 more bytes) and a receiver with
    the key accepts it; unsigned frames would be rejected by that receiver."""
    key = bytes(range(32))
    h = Harness("px4")
    h.ap.set_signing_key(key, 1_750_000_000.0)
    h.run(1.0)
    assert h.ap.send_message_now(mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, h.t)
    assert h.ap.send_message_now(mav.MAVLINK_MSG_ID_ATTITUDE, h.t)
    frames = h.ap.drain_outbox()
    assert len(frames) == 2
    rx = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    rx.signing.secret_key = key
    rx.signing.sign_outgoing = False
    rx.robust_parsing = True
    for frame in frames:
        assert frame[2] & mav.MAVLINK_IFLAG_SIGNED and len(frame) == 10 + frame[1] + 2 + 13
        assert [m.get_type() for m in rx.parse_buffer(frame)] in (
            ["LOCAL_POSITION_NED"], ["ATTITUDE"])
    unsigned = pack_unsigned_v2(mav.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0), 0, 1, 1)
    assert [m.get_type() for m in rx.parse_buffer(unsigned) or []] != ["ATTITUDE"]
