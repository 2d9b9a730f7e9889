"""A fast path for the commonest received datagram: one whole, valid MAVLink 2 frame.

A UDP autopilot sends one frame per datagram, and nearly all of them are fixed-layout telemetry
(HEARTBEAT, SYS_STATUS, LOCAL_POSITION_NED, GLOBAL_POSITION_INT, ATTITUDE ...). pymavlink's
``MAVLink.parse_buffer`` decodes such a datagram through its byte-stream state machine (buffer
copies, two passes, a CRC object); :func:`decode_single_frame` decodes it directly and returns the
*same* message object pymavlink would (same class, fields, ``_header``, ``_msgbuf``,
``_payload``, ``_crc``, ``_signed``), or None whenever the datagram is anything else, so that the
caller hands it to pymavlink, which then produces its usual result (``BAD_DATA`` with its reason,
``UNKNOWN``, several messages, a partial frame ...). The fast path returns a message only when:

* the datagram is exactly one MAVLink 2 frame: magic 0xFD, incompatibility flags 0 or
  ``MAVLINK_IFLAG_SIGNED`` (then the 13-byte signature block follows the CRC), and its length is
  exactly header + payload length byte + CRC (+ signature);
* the message id is a known message of pymavlink's dialect (``ardupilotmega``) whose fields are
  all scalars (no arrays, no strings): about two thirds of the dialect, every high-rate message;
* its CRC-16/MCRF4XX over the header (without the magic) and payload, then the message's
  ``CRC_EXTRA``, matches (fastcrc, as pymavlink itself uses when present; without fastcrc the
  fast path is off).

A MAVLink 2 payload truncated of its trailing zero bytes is zero-padded to the message's size, and
a payload longer than it is cut, exactly as pymavlink does. A signed frame is decoded like
pymavlink's key-less parser does (``_signed`` False, signature not checked): the endpoint's
:class:`~mission.link.signing.SignatureVerifier` checks it afterwards on ``_msgbuf``, whichever
path decoded it.

Both ends of a link use it: the ground station's endpoint (``mission.link.endpoint_receive``), its
``audit`` tlog reader and the mock autopilots' UDP links (``sitl_mock.transport``). This module is
the project's one wrapper around pymavlink's private message fields (:func:`_with_frame` sets
them); everything else reads a message's frame through pymavlink's public getters
(``get_header()``, ``get_msgbuf()``, ``get_srcSystem()``...).
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator import mavcrc

__all__ = ["decode_single_frame", "FAST_MSG_IDS"]

_V2 = mavlink.PROTOCOL_MARKER_V2
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIG_LEN = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_HEADER = mavlink.MAVLink_header


def _decoder_table() -> dict:
    """msg id -> (class, CRC_EXTRA as bytes, unpack, payload size, field order or None)."""
    table = {}
    for msg_id, cls in mavlink.mavlink_map.items():
        lengths = list(cls.lengths)
        fmt = cls.unpacker.format
        if any(n != 1 for n in lengths) or "s" in fmt or len(lengths) != len(cls.orders):
            continue  # arrays or strings: pymavlink's general path
        order = tuple(cls.orders)
        table[msg_id] = (cls, bytes((cls.crc_extra,)), cls.unpacker.unpack, cls.unpacker.size,
                         None if order == tuple(range(len(order))) else order)
    return table


#: message ids decoded by the fast path (empty without fastcrc)
_TABLE = _decoder_table() if mavcrc.mcrf4xx is not None else {}
FAST_MSG_IDS = frozenset(_TABLE)


def decode_single_frame(data):
    """The pymavlink message of a datagram holding exactly one valid, known MAVLink 2 frame, else None.

    Parameters
    ----------
    data : bytes
        One datagram.

    Returns
    -------
    pymavlink message or None
        Identical to what a fresh robust pymavlink parser's ``parse_buffer(data)`` returns as its
        only message; None means "not decided here": parse ``data`` with pymavlink.
    """
    n = len(data)
    if n < 12 or data[0] != _V2:
        return None
    flags = data[2]
    if flags == 0:
        end = n - 2
    elif flags == _SIGNED:
        end = n - 2 - _SIG_LEN
    else:
        return None
    mlen = data[1]
    if end != 10 + mlen:
        return None
    msg_id = data[7] | data[8] << 8 | data[9] << 16
    entry = _TABLE.get(msg_id)
    if entry is None:
        return None
    cls, crc_extra, unpack, size, order = entry
    crc = data[end] | data[end + 1] << 8
    crcfn = mavcrc.mcrf4xx
    if crcfn(crc_extra, crcfn(memoryview(data)[1:end], 0xFFFF)) != crc:
        return None  # pymavlink reports it (BAD_DATA "invalid MAVLink CRC ...")
    payload = data[10:end]
    if mlen < size:
        payload += bytes(size - mlen)
    elif mlen > size:
        payload = payload[:size]
    fields = unpack(payload)
    if order is not None:
        fields = [fields[i] for i in order]
    msgbuf = bytearray(data)
    return _with_frame(cls(*fields), msgbuf, msgbuf[6:end], crc,
                       _HEADER(msg_id, flags, data[3], mlen, data[4], data[5], data[6]))


def _with_frame(msg, msgbuf: bytearray, payload: bytearray, crc: int, header):
    """``msg`` given the frame fields pymavlink's parser sets when it decodes a frame.

    pymavlink has public getters for them (``get_msgbuf()``, ``get_header()``, ``get_payload()``,
    ``get_crc()``: what the rest of the ground station uses) but no setter: these four lines are
    the only place in ``mission`` that touches pymavlink's private message fields.
    """
    msg._msgbuf = msgbuf
    msg._payload = payload
    msg._crc = crc
    msg._header = header
    return msg
