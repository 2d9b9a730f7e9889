"""Unsigned MAVLink 2 frames of the mock autopilots' messages, without pymavlink's per-frame work.

``msg.pack(mav)`` builds a header object, a bytearray, a CRC object and three ``struct`` calls
for every frame; the mock fleet sends about 36 telemetry frames a second per vehicle, and that
was a sixth of a lock-step mission's fleet step (``benchmarks/bench_mock_step.py``).
:func:`pack_unsigned_v2` builds the same bytes directly: the message's payload with its own
``struct`` (the fields in pymavlink's wire order), trailing zero bytes cut as MAVLink 2 does (one
byte kept), the v2 header, and the CRC over header and payload then ``CRC_EXTRA`` (fastcrc when
pymavlink has it). Messages with array fields (their pymavlink ``pack`` flattens the arrays) are
not handled: it returns None and the caller packs with pymavlink. Signed output is the caller's
business too (pymavlink signs; see :meth:`sitl_mock.autopilot.MockAutopilot.emit`).
``tests/sitl_mock/test_ap_frames.py`` checks it byte for byte against ``msg.pack``.
"""
from __future__ import annotations

import operator
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.generator import mavcrc

__all__ = ["pack_unsigned_v2"]

_V2_HEADER = struct.Struct("<BBBBBBBHB")
_MAGIC_V2 = 253
#: CRC_EXTRA values as the one-byte strings the CRC takes
_EXTRA_BYTES = tuple(bytes((k,)) for k in range(256))
#: message class -> (payload struct, field getter in wire order, msg id, CRC_EXTRA byte), for the
#: classes without array fields (built once at import; never changed)
_LAYOUTS = {
    cls: (cls.unpacker, operator.attrgetter(*cls.ordered_fieldnames), cls.id, _EXTRA_BYTES[cls.crc_extra])
    for cls in mavlink2.mavlink_map.values()
    if cls.ordered_fieldnames and not any(cls.array_lengths)
}


def _crc16(header_and_payload: bytes, extra: bytes) -> int:
    """MAVLink CRC of a frame without its magic byte, then the CRC_EXTRA byte ``extra``."""
    fast = mavcrc.mcrf4xx
    if fast is not None:
        return fast(extra, fast(memoryview(header_and_payload)[1:], 0xFFFF))
    crc = mavcrc.x25crc(header_and_payload[1:])
    crc.accumulate(extra)
    return crc.crc


def pack_unsigned_v2(msg, seq: int, sysid: int, compid: int) -> bytes | None:
    """The unsigned MAVLink 2 frame ``msg.pack(mav)`` gives for ``mav`` with that sequence
    number and identity and signing off; None for a message with array fields.

    Parameters
    ----------
    msg : pymavlink message
        As built by an ``*_encode`` method of the dialect.
    seq, sysid, compid : int
        Sequence number (0-255), system and component id of the sender.

    Returns
    -------
    bytes or None
    """
    layout = _LAYOUTS.get(type(msg))
    if layout is None:
        return None
    payload_struct, fields, msg_id, extra = layout
    values = fields(msg)
    payload = payload_struct.pack(*values) if type(values) is tuple else payload_struct.pack(values)
    stripped = payload.rstrip(b"\0") or payload[:1]
    head = _V2_HEADER.pack(_MAGIC_V2, len(stripped), 0, 0, seq, sysid, compid, msg_id & 0xFFFF, msg_id >> 16)
    frame = head + stripped
    return frame + _crc16(frame, extra).to_bytes(2, "little")
