"""The pre-built setpoint frame packer gives pymavlink's ``pack()`` bytes, and the endpoint sends them."""
from __future__ import annotations

import random

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.link.setpoint_frame import SetpointFramer
from mission.link.signing import apply_signing, sign_frame

_LOCAL = mavlink.MAVLink_set_position_target_local_ned_message
_GLOBAL = mavlink.MAVLink_set_position_target_global_int_message


def _random_fields(rng: random.Random, msg_id: int):
    t_ms = rng.choice([0, 1, rng.randrange(1 << 32), (1 << 32) - 1])
    if msg_id == _LOCAL.id:
        xyz = [rng.choice([0.0, -0.0, rng.uniform(-1e4, 1e4), rng.uniform(-1e-3, 1e-3)]) for _ in range(3)]
    else:
        xyz = [rng.randrange(-900_000_000, 900_000_001), rng.randrange(-1_800_000_000, 1_800_000_001),
               rng.choice([0.0, rng.uniform(-500.0, 9000.0)])]
    yaw = rng.choice([0.0, rng.uniform(-3.2, 3.2)])
    mask = rng.choice([0, 0x9F8, 0xDF8, rng.randrange(1 << 16)])
    return t_ms, xyz, yaw, mask


@pytest.mark.parametrize("msg_cls,frames", [(_LOCAL, (mavlink.MAV_FRAME_LOCAL_NED, 7, 255)),
                                            (_GLOBAL, (mavlink.MAV_FRAME_GLOBAL_INT, 6))])
def test_frames_are_byte_identical_to_pymavlink_pack(msg_cls, frames):
    rng = random.Random(20261126 + msg_cls.id)
    for _ in range(3000):
        src = (rng.randrange(256), rng.randrange(256))
        target = (rng.randrange(256), rng.randrange(256))
        coordinate_frame = rng.choice(frames)
        seq = rng.randrange(256)
        t_ms, (x, y, z), yaw, mask = _random_fields(rng, msg_cls.id)
        yaw_rate = rng.choice([0.0, rng.uniform(-1.0, 1.0)])
        framer = SetpointFramer(msg_cls.id, *src, *target, coordinate_frame)
        mav = mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
        mav.seq = seq
        if msg_cls is _LOCAL:
            msg = _LOCAL(t_ms, *target, coordinate_frame, mask, x, y, z, 0, 0, 0, 0, 0, 0, yaw, yaw_rate)
        else:
            msg = _GLOBAL(t_ms, *target, coordinate_frame, mask, x, y, z, 0, 0, 0, 0, 0, 0, yaw, yaw_rate)
        assert framer.frame(seq, t_ms, x, y, z, yaw, mask, yaw_rate) == msg.pack(mav), (seq, t_ms, x, y, z)


def test_every_sequence_number_matches_one_encoder_sending_in_turn():
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    framer = SetpointFramer(_LOCAL.id, 255, 190, 3, 1, mavlink.MAV_FRAME_LOCAL_NED)
    for k in range(600):   # the sequence number wraps twice
        seq = mav.seq
        want = _LOCAL(k, 3, 1, mavlink.MAV_FRAME_LOCAL_NED, 0x9F8, 0.5 * k, -k, -20.0,
                      0, 0, 0, 0, 0, 0, 0.0, 0.0).pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF   # as the endpoint does after pymavlink's pack
        assert framer.frame(seq, k, 0.5 * k, -k, -20.0, 0.0, 0x9F8) == want


def test_signed_setpoints_match_pymavlink_signing():
    """The endpoint signs the framer's frame: the same bytes as pymavlink's signed ``pack``."""
    def state():
        s = mavlink.MAVLinkSigning()
        s.secret_key, s.link_id, s.timestamp, s.sign_outgoing = bytes(range(32)), 4, 1_000_000, True
        return s

    ours = state()
    theirs = apply_signing(mavlink.MAVLink(None, srcSystem=255, srcComponent=190), state())
    framer = SetpointFramer(_LOCAL.id, 255, 190, 3, 1, mavlink.MAV_FRAME_LOCAL_NED)
    for k in range(50):
        seq = theirs.seq
        want = _LOCAL(k, 3, 1, 1, 0xDF8, 1.0, 2.0, -3.0, 0, 0, 0, 0, 0, 0, 0.25, 0.0).pack(theirs)
        theirs.seq = (theirs.seq + 1) & 0xFF
        assert sign_frame(framer.frame(seq, k, 1.0, 2.0, -3.0, 0.25, 0xDF8), framer.crc_extra, ours) == want


@pytest.mark.parametrize("args,match", [
    ((mavlink.MAVLINK_MSG_ID_HEARTBEAT, 255, 190, 1, 1, 1), "no setpoint framer for message id 0"),
    ((_LOCAL.id, 255, 190, 1, 1, 0), "coordinate frame must be 1-255"),
    ((_LOCAL.id, 256, 190, 1, 1, 1), "ids must be 0-255"),
])
def test_bad_framer_arguments_are_refused_by_name(args, match):
    with pytest.raises(ValueError, match=match):
        SetpointFramer(*args)


def test_the_whole_frame_crc_branch_gives_the_same_frames():
    """Without fastcrc (no CRC states kept) the framer takes the CRC of the whole frame: same bytes."""
    fast = SetpointFramer(_GLOBAL.id, 255, 190, 9, 1, mavlink.MAV_FRAME_GLOBAL_INT)
    whole = SetpointFramer(_GLOBAL.id, 255, 190, 9, 1, mavlink.MAV_FRAME_GLOBAL_INT)
    whole._crc_fast = None
    rng = random.Random(3)
    for seq in range(256):
        t_ms, (x, y, z), yaw, mask = _random_fields(rng, _GLOBAL.id)
        assert whole.frame(seq, t_ms, x, y, z, yaw, mask) == fast.frame(seq, t_ms, x, y, z, yaw, mask)
