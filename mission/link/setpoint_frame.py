"""A pre-built MAVLink 2 frame packer for the setpoint messages (the coordinator's commonest send).

At N = 100 vehicles and 20 Hz the ground station sends 2000 SET_POSITION_TARGET_* frames a
second, each the same message from the same system to the same vehicle: only the sequence
number, the time, the position, the yaw and the type mask change. :class:`SetpointFramer` packs
the whole frame (header, payload, CRC) with one ``struct`` call and one CRC over it, the constant
fields (magic, flags, our system and component ids, the message id, the vehicle's target system,
component and coordinate frame, the zero velocities and accelerations) fixed when it is built.
The frame is byte-identical to pymavlink's ``msg.pack(mav)`` of the same message with the same
``mav.seq`` (``tests/mission/link/test_setpoint_frame.py`` compares them over random setpoints and
every sequence number).

MAVLink 2 truncates a payload's trailing zero bytes; the last byte of both messages' payloads is
the coordinate frame, never 0 for the frames used here (LOCAL_NED 1, GLOBAL_INT 5, GLOBAL_RELATIVE_ALT_INT 6),
so the frame always has its full length (the constructor refuses frame 0). Unsigned frames only:
a signed link appends the signature to this frame (:func:`mission.link.signing.sign_frame`).
"""
from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator import mavcrc

__all__ = ["SetpointFramer", "SETPOINT_MESSAGES"]

#: the messages a framer builds: SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT
SETPOINT_MESSAGES = {cls.id: cls for cls in (mavlink.MAVLink_set_position_target_local_ned_message,
                                             mavlink.MAVLink_set_position_target_global_int_message)}


class SetpointFramer:
    """MAVLink 2 frames of one setpoint message from one sender to one vehicle.

    Parameters
    ----------
    msg_id : int
        84 (SET_POSITION_TARGET_LOCAL_NED) or 86 (SET_POSITION_TARGET_GLOBAL_INT).
    src_system, src_component : int
        The sender's (the ground station's) system and component ids.
    target_system, target_component : int
        The vehicle's.
    coordinate_frame : int
        ``MAV_FRAME_*`` (not 0: see the module docstring).

    Raises
    ------
    ValueError
        Another message id, a coordinate frame of 0, or an id out of 0-255.
    """

    def __init__(self, msg_id: int, src_system: int, src_component: int, target_system: int,
                 target_component: int, coordinate_frame: int) -> None:
        cls = SETPOINT_MESSAGES.get(msg_id)
        if cls is None:
            raise ValueError(f"no setpoint framer for message id {msg_id} (known: {sorted(SETPOINT_MESSAGES)})")
        if not 0 < coordinate_frame < 256:
            raise ValueError(f"coordinate frame must be 1-255 (a frame of 0 would be truncated), got {coordinate_frame}")
        ids = (src_system, src_component, target_system, target_component)
        if not all(0 <= i < 256 for i in ids):
            raise ValueError(f"system and component ids must be 0-255, got {ids}")
        fmt = cls.unpacker.format.lstrip("<")
        # payload in wire order: time_boot_ms, x|lat_int, y|lon_int, z|alt, 6 zero floats
        # (velocities, accelerations), yaw, yaw_rate, type_mask, then the constant tail:
        # target system, target component, coordinate frame
        if fmt[:4] not in ("Ifff", "Iiif") or fmt[4:] != "ffffffffHBBB":
            raise ValueError(f"unexpected wire format {cls.unpacker.format!r} for message {msg_id}")
        self._body = struct.Struct("<" + fmt[:4] + "24x" + "ffH")
        self._tail = bytes((target_system, target_component, coordinate_frame))
        size = self._body.size + len(self._tail)
        #: the 10-byte header of each sequence number, and the CRC state after it (without the magic)
        self._heads = tuple(bytes((0xFD, size, 0, 0, seq, src_system, src_component, msg_id & 0xFF,
                                   (msg_id >> 8) & 0xFF, msg_id >> 16)) for seq in range(256))
        fast = mavcrc.mcrf4xx
        self._crc_fast = fast
        self._head_crcs = tuple(fast(h[1:], 0xFFFF) for h in self._heads) if fast is not None else ()
        self._tail_extra = self._tail + bytes((cls.crc_extra,))
        self.crc_extra = cls.crc_extra
        self.msg_id = msg_id

    def frame(self, seq: int, time_boot_ms: int, x, y, z, yaw: float, type_mask: int,
              yaw_rate: float = 0.0) -> bytes:
        """The frame with sequence number ``seq`` (0-255).

        ``x, y, z`` are the message's own: metres NED for LOCAL_NED, ``lat_int``, ``lon_int``
        (degE7, ints) and ``alt`` (metres) for GLOBAL_INT.
        """
        body = self._body.pack(time_boot_ms, x, y, z, yaw, yaw_rate, type_mask)
        fast = self._crc_fast
        if fast is None:   # no fastcrc: pymavlink's x25 over the whole frame
            frame = self._heads[seq] + body + self._tail
            return frame + crc16(frame, self.crc_extra).to_bytes(2, "little")
        crc = fast(self._tail_extra, fast(body, self._head_crcs[seq]))
        return self._heads[seq] + body + self._tail + crc.to_bytes(2, "little")


#: CRC_EXTRA values as the one-byte strings the CRC takes (not rebuilt for every frame)
_EXTRA_BYTES = tuple(bytes((k,)) for k in range(256))


def crc16(frame: bytes, crc_extra: int) -> int:
    """MAVLink CRC of a frame without its magic byte, then ``crc_extra`` (fastcrc when available)."""
    fast = mavcrc.mcrf4xx
    if fast is not None:
        return fast(_EXTRA_BYTES[crc_extra], fast(memoryview(frame)[1:], 0xFFFF))
    crc = mavcrc.x25crc(frame[1:])
    crc.accumulate(bytes((crc_extra,)))
    return crc.crc
