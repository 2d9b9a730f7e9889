"""Hypothesis strategies and helpers shared by the fuzz tests (MAVLink frames and mutations).

Valid frames are real pymavlink encodings of messages of the ``ardupilotmega`` dialect with
random field values (NaN and infinities included); :func:`mutated` then breaks them (bit flips,
truncation, splicing, wrong CRC, wrong length, bad incompat flags, inserted or deleted bytes).
:func:`reference_parse` is an independent robust parser: what it yields for a byte string is
what the code under test must account for, frame by frame.

Signing (MAVLink 2): :func:`sign` encodes a signed frame at a chosen timestamp, link id and key;
:func:`mutate_signed` breaks one region of a signed frame (header, payload, CRC, signed flag,
link id, timestamp, signature) or truncates it; :class:`SigningOracle` is an independent model of
the receiver's signature check (mavlink.io "Message signing"): the outcome each decoded frame must
get, in order.
"""
from __future__ import annotations

import hashlib
import math

from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["run_autopilot", 
    "ALL_MESSAGE_CLASSES",
    "FakeClock",
    "message_class",
    "messages",
    "encode",
    "frames",
    "mutated",
    "MUTATIONS",
    "reference_parse",
    "is_bad",
    "is_valid_for",
    "state_repr",
    "SIGNED_REGIONS",
    "sign",
    "mutate_signed",
    "SigningOracle",
]

_M = mavlink
ALL_MESSAGE_CLASSES = tuple(sorted(_M.mavlink_map.values(), key=lambda c: c.id))

_INT_RANGES = {
    "int8_t": (-(1 << 7), (1 << 7) - 1), "uint8_t": (0, (1 << 8) - 1),
    "int16_t": (-(1 << 15), (1 << 15) - 1), "uint16_t": (0, (1 << 16) - 1),
    "int32_t": (-(1 << 31), (1 << 31) - 1), "uint32_t": (0, (1 << 32) - 1),
    "int64_t": (-(1 << 63), (1 << 63) - 1), "uint64_t": (0, (1 << 64) - 1),
}
_SPECIAL_FLOATS = (0.0, -0.0, 1.0, -1.0, math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e-45)


class FakeClock:
    """A settable clock with the project's clock interface (``time``, ``sleep``, ``speedup``)."""

    speedup = 1.0

    def __init__(self, t_s: float = 1_763_717_000.0):
        self.t_s = float(t_s)

    def time(self) -> float:
        """Current time (seconds)."""
        return self.t_s

    async def sleep(self, dt_s: float) -> None:
        """Advance the clock instead of waiting."""
        self.t_s += max(0.0, float(dt_s))

    def sleep_blocking(self, dt_s: float) -> None:
        """Advance the clock instead of waiting."""
        self.t_s += max(0.0, float(dt_s))


def message_class(name: str):
    """The pymavlink class of message ``name`` (e.g. ``"COMMAND_LONG"``)."""
    return _M.mavlink_map[getattr(_M, f"MAVLINK_MSG_ID_{name}")]


def _scalar(ftype: str):
    if ftype == "float":
        return st.one_of(st.sampled_from(_SPECIAL_FLOATS), st.floats(width=32))
    if ftype == "double":
        return st.one_of(st.sampled_from(_SPECIAL_FLOATS), st.floats())
    lo, hi = _INT_RANGES[ftype]
    return st.one_of(st.sampled_from((0, 1, lo, hi)), st.integers(lo, hi))


def _field(ftype: str, length: int):
    if ftype == "char":
        return st.binary(max_size=max(length, 1))
    if length:
        return st.lists(_scalar(ftype), min_size=length, max_size=length)
    return _scalar(ftype)


def messages(classes=ALL_MESSAGE_CLASSES, **fixed):
    """Strategy: a message of one of ``classes`` with random field values.

    Parameters
    ----------
    classes : sequence of pymavlink message classes
    **fixed : strategy or value
        Field name -> value or strategy, applied when the class has that field as a scalar
        (e.g. ``target_system=st.just(1)``).
    """
    def build(cls):
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
        kwargs = {}
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
            if name in fixed and not lengths[name] and ftype != "char":
                value = fixed[name]
                kwargs[name] = value if isinstance(value, st.SearchStrategy) else st.just(value)
            else:
                kwargs[name] = _field(ftype, lengths[name])
        return st.fixed_dictionaries(kwargs).map(lambda kw: cls(**kw))

    return st.sampled_from(list(classes)).flatmap(build)


def encode(msg, sysid: int = 255, compid: int = 190, seq: int = 0, mavlink1: bool = False) -> bytes:
    """Encode ``msg`` as a MAVLink 2 (or 1) frame from ``sysid``/``compid``."""
    enc = _M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    enc.seq = seq & 0xFF
    return bytes(msg.pack(enc, force_mavlink1=mavlink1 and msg.get_msgId() < 256))


def frames(classes=ALL_MESSAGE_CLASSES, sysid=st.just(255), compid=st.just(190), **fixed):
    """Strategy: valid frames (bytes) of random messages; MAVLink 1 for about one in five."""
    return st.builds(encode, messages(classes, **fixed), sysid, compid, st.integers(0, 255),
                     st.integers(0, 4).map(lambda k: k == 0))


def _bitflip(frame: bytes, draw) -> bytes:
    out = bytearray(frame)
    for pos in draw(st.lists(st.integers(0, len(out) * 8 - 1), min_size=1, max_size=4, unique=True)):
        out[pos // 8] ^= 1 << (pos % 8)
    return bytes(out)


def _truncate(frame: bytes, draw) -> bytes:
    return frame[:draw(st.integers(1, len(frame) - 1))]


def _splice(frame: bytes, draw) -> bytes:
    other = draw(st.binary(min_size=1, max_size=64))
    return frame[:draw(st.integers(1, len(frame) - 1))] + other


def _bad_crc(frame: bytes, draw) -> bytes:
    crc = int.from_bytes(frame[-2:], "little") ^ draw(st.integers(1, 0xFFFF))
    return frame[:-2] + crc.to_bytes(2, "little")


def _bad_length(frame: bytes, draw) -> bytes:
    length = draw(st.integers(0, 255).filter(lambda n: n != frame[1]))
    return frame[:1] + bytes((length,)) + frame[2:]


def _bad_incompat(frame: bytes, draw) -> bytes:
    if frame[0] != 0xFD:
        return _bad_crc(frame, draw)
    return frame[:2] + bytes((draw(st.integers(2, 255)),)) + frame[3:]


def _insert(frame: bytes, draw) -> bytes:
    pos = draw(st.integers(1, len(frame) - 1))
    return frame[:pos] + draw(st.binary(min_size=1, max_size=8)) + frame[pos:]


def _delete(frame: bytes, draw) -> bytes:
    pos = draw(st.integers(1, len(frame) - 1))
    return frame[:pos] + frame[pos + 1:]


#: name -> mutation(frame, draw) of a valid frame into a (nearly always) invalid one
MUTATIONS = {"bitflip": _bitflip, "truncate": _truncate, "splice": _splice, "bad_crc": _bad_crc,
             "bad_length": _bad_length, "bad_incompat": _bad_incompat, "insert": _insert,
             "delete": _delete}


@st.composite
def mutated(draw, frame_strategy, max_frames: int = 4) -> bytes:
    """Strategy: 1..``max_frames`` frames of ``frame_strategy``, each broken by a random mutation."""
    parts = []
    for frame in draw(st.lists(frame_strategy, min_size=1, max_size=max_frames)):
        parts.append(MUTATIONS[draw(st.sampled_from(sorted(MUTATIONS)))](frame, draw))
    return b"".join(parts)


def reference_parse(chunks) -> tuple[list, int]:
    """Parse with a fresh robust parser: ``(messages, bytes left unparsed)``.

    ``chunks`` is one byte string or a list of them fed one after the other (datagram or read
    boundaries matter: a run of junk bytes is one BAD_DATA per chunk).
    """
    parser = _M.MAVLink(None)
    parser.robust_parsing = True
    msgs = []
    for chunk in [chunks] if isinstance(chunks, (bytes, bytearray)) else chunks:
        msgs.extend(parser.parse_buffer(chunk) or [])
    return msgs, parser.buf_len()


def is_bad(msg) -> bool:
    """True for what the parser yields for undecodable input (bad data, unknown message id)."""
    return msg.get_type() == "BAD_DATA" or msg.get_type().startswith("UNKNOWN")


def is_valid_for(msg, sysid: int) -> bool:
    """True when ``msg`` decoded and is not addressed to another system (0 is broadcast)."""
    return not is_bad(msg) and getattr(msg, "target_system", 0) in (0, sysid)


def state_repr(*values) -> str:
    """A comparable text image of state values (NaN-safe, arrays included)."""
    out = []
    for v in values:
        if hasattr(v, "tolist"):
            v = v.tolist()
        out.append(repr(v))
    return "|".join(out)


# ------------------------------------------------------------------------- MAVLink 2 signing
_SIG_BLOCK = 13                      # link id (1) + timestamp (6) + signature (6)
_STAMP_MAX = (1 << 48) - 1
_NEW_STREAM_LAG = 6_000_000          # a new stream may be one minute (10 us units) behind
#: parts of a signed frame :func:`mutate_signed` can break (``truncate`` cuts the frame short)
SIGNED_REGIONS = ("header", "payload", "crc", "signed_flag", "link_id", "timestamp", "signature",
                  "truncate")


def sign(msg, key: bytes, timestamp: int, sysid: int = 255, compid: int = 190, link_id: int = 0,
         seq: int = 0) -> bytes:
    """Encode ``msg`` as a MAVLink 2 frame signed with ``key`` at ``timestamp`` (10 us units since
    2015-01-01, taken modulo 2**48 as on the wire) on link ``link_id``."""
    enc = _M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    enc.seq = seq & 0xFF
    enc.signing.secret_key = bytes(key)
    enc.signing.link_id = link_id & 0xFF
    enc.signing.timestamp = int(timestamp) & _STAMP_MAX
    enc.signing.sign_outgoing = True
    return bytes(msg.pack(enc))


def mutate_signed(frame: bytes, region: str, draw) -> bytes:
    """Break ``region`` (one of :data:`SIGNED_REGIONS`) of the signed MAVLink 2 ``frame``.

    One to three bit flips inside the region; ``signed_flag`` clears the signed incompatibility
    flag (the signature block then reads as trailing bytes); ``truncate`` keeps a strict prefix.
    """
    n = len(frame)
    if region == "truncate":
        return frame[:draw(st.integers(1, n - 1))]
    out = bytearray(frame)
    if region == "signed_flag":
        out[2] &= 0xFE
        return bytes(out)
    lo, hi = {"header": (1, 10), "payload": (10, n - 15), "crc": (n - 15, n - 13),
              "link_id": (n - 13, n - 12), "timestamp": (n - 12, n - 6), "signature": (n - 6, n)}[region]
    bits = draw(st.lists(st.integers(lo * 8, hi * 8 - 1), min_size=1, max_size=3, unique=True))
    for bit in bits:
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


class SigningOracle:
    """What a MAVLink 2 receiver holding ``key`` must decide for each decoded frame, in order.

    Written from the specification, independently of the code under test: a frame must be signed
    (else ``unsigned``, or ``unsigned_allowed`` for ``unsigned_ok_ids``), its signature
    ``SHA-256(key + frame[:-6])[:6]`` right (else ``bad_signature``), its timestamp above the last
    accepted one of its stream ``(link id, sysid, compid)`` or, for a new stream, at most one
    minute behind the receiver's timestamp (else ``replayed``); an accepted timestamp moves the
    receiver's timestamp up.

    Parameters
    ----------
    key : bytes
    timestamp : int
        The receiver's timestamp when the frames start arriving.
    unsigned_ok_ids : frozenset of int
        Message ids accepted unsigned (RADIO_STATUS and RADIO by default).
    check_unknown : bool
        True when frames of unknown message ids go through the signature check (the ground
        station); False when they are rejected as ``unknown`` first (the mock).
    """

    def __init__(self, key: bytes, timestamp: int,
                 unsigned_ok_ids=frozenset({_M.MAVLINK_MSG_ID_RADIO_STATUS, _M.MAVLINK_MSG_ID_RADIO}),
                 check_unknown: bool = True):
        self.key = bytes(key)
        self.timestamp = int(timestamp)
        self.unsigned_ok_ids = frozenset(unsigned_ok_ids)
        self.check_unknown = check_unknown
        self.streams: dict[tuple[int, int, int], int] = {}

    def outcome(self, msg) -> str:
        """``bad_crc``, ``malformed``, ``unknown``, ``unsigned``, ``unsigned_allowed``,
        ``bad_signature``, ``replayed`` or ``accepted`` for the next decoded ``msg``."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return "bad_crc" if "crc" in str(msg.reason).lower() else "malformed"
        if kind.startswith("UNKNOWN") and not self.check_unknown:
            return "unknown"
        buf = bytes(msg.get_msgbuf())
        if buf[0] == _M.PROTOCOL_MARKER_V2:
            msg_id, signed = int.from_bytes(buf[7:10], "little"), bool(buf[2] & 1)
        else:
            msg_id, signed = buf[5], False
        if not signed:
            return "unsigned_allowed" if msg_id in self.unsigned_ok_ids else "unsigned"
        if hashlib.sha256(self.key + buf[:-6]).digest()[:6] != buf[-6:]:
            return "bad_signature"
        stamp = int.from_bytes(buf[-12:-6], "little")
        stream = (buf[-_SIG_BLOCK], buf[5], buf[6])
        last = self.streams.get(stream)
        if stamp <= (last if last is not None else self.timestamp - _NEW_STREAM_LAG - 1):
            return "replayed"
        self.streams[stream] = stamp
        self.timestamp = max(self.timestamp, stamp)
        return "accepted"


def run_autopilot(ap, t_s: float, duration_s: float, dt_s: float = 0.02) -> float:
    """Step a mock autopilot, its dynamics and its telemetry for ``duration_s``; the time after."""
    for _ in range(int(round(duration_s / dt_s))):
        ap.step(t_s, dt_s)
        ap.mc.step(dt_s)
        ap.send_telemetry(t_s)
        t_s += dt_s
    return t_s
