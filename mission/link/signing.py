"""MAVLink 2 message signing for the ground station: key file, signing state, checks, SETUP_SIGNING.

The key is read from a key file named in the plan (``[security] signing_key_file = "path"``),
never from the command line. Key-file format (:func:`wire.signing.load_key_file`), tried in this order:

1. **64 hexadecimal characters** (surrounding whitespace and a final newline ignored): the key.
2. **exactly 32 bytes** that are not all printable ASCII: the raw key. 32 printable bytes are
   refused as ambiguous (write the key in hex, or end a passphrase with a newline).
3. otherwise **one line of UTF-8 text**, a passphrase (final ``\\n`` / ``\\r\\n`` removed):
   the key is ``SHA-256(passphrase)``, exactly what MAVProxy's ``signing setup PASSPHRASE`` and
   ``signing key PASSPHRASE`` do, so a vehicle set up with MAVProxy flies with the same words.

The file must not be world-readable (``chmod 600``): :class:`wire.signing.SigningError`
otherwise (unless ``allow_world_readable=True``, which only warns); a group-readable file gives a
:class:`wire.signing.SigningWarning`. The all-zero key is refused (it means "signing off" in
SETUP_SIGNING).

Sending: :meth:`SigningConfig.new_state` makes one pymavlink ``MAVLinkSigning`` per link;
:func:`apply_signing` gives it to every pymavlink encoder of that link (they then share one
timestamp, so timestamps are monotonic per link whatever the peer), and :func:`sign_frame` signs
frames built by hand with the same state. Timestamps are 10 us units since 2015-01-01 00:00 UTC
(:func:`wire.signing.signing_timestamp`); pymavlink adds one per frame and :func:`refresh_timestamp` keeps
them up with the clock.

Receiving: parse with a pymavlink parser that has *no* key (it then decodes signed frames without
checking them) and pass every decoded message to :meth:`SignatureVerifier.check`, which returns
``None`` or the reason of rejection, counted: ``unsigned``, ``bad_signature`` or ``replayed``
(timestamp not above the last one of its stream ``(link id, system id, component id)``, or a
new stream more than one minute behind our timestamp). The signature is checked before the
timestamp, unlike pymavlink's ``MAVLink.check_signature``, which records a frame's timestamp for
its stream before checking the signature, so that one forged frame with a huge timestamp makes
pymavlink reject every genuine frame of that stream afterwards.

Provisioning: :func:`setup_signing_message` builds the SETUP_SIGNING that gives a vehicle the key
(ArduPilot accepts it only while disarmed; once a vehicle signs, it must be signed with the
current key). SETUP_SIGNING carries the key in clear: send it only over a trusted link (USB,
wire, 127.0.0.1 for simulators) and never write it to a ``.tlog``.
"""
from __future__ import annotations

import hashlib
from collections import Counter

from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator import mavcrc

from mission.core.signing_config import SigningConfig
from wire.signing import SigningError, signing_timestamp

__all__ = [
    "SignatureVerifier", "apply_signing", "refresh_timestamp", "sign_frame",
    "setup_signing_message", "disable_signing_message",
]

_KEY_LEN = 32
_TIMESTAMP_MAX = (1 << 48) - 1
_NEW_STREAM_MAX_LAG = 6_000_000  # one minute in 10 us units (MAVLink spec)
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_SIG_LEN = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_V2 = mavlink.PROTOCOL_MARKER_V2
_V2_OVERHEAD = 10 + 2
_MSG_IDS: dict[str, int] = {cls.msgname: msg_id for msg_id, cls in mavlink.mavlink_map.items()}


def apply_signing(mav: mavlink.MAVLink, state: mavlink.MAVLinkSigning) -> mavlink.MAVLink:
    """Make the pymavlink encoder ``mav`` sign with ``state`` (shared, not copied); returns it.

    Only for encoders: a pymavlink object with a key also checks signatures when it *parses*
    (with the flaw described in the module docstring); parse with a keyless parser and
    :class:`SignatureVerifier`.
    """
    mav.signing = state
    return mav


def refresh_timestamp(state: mavlink.MAVLinkSigning, unix_s: float) -> int:
    """Bring ``state.timestamp`` up to the clock (never backwards); returns it."""
    now = signing_timestamp(unix_s)
    if now > state.timestamp:
        state.timestamp = now
    return state.timestamp


def _crc(frame_no_magic: bytes, crc_extra: int) -> int:
    fast = mavcrc.mcrf4xx
    if fast is not None:
        return fast(bytes((crc_extra,)), fast(bytes(frame_no_magic), 0xFFFF))
    crc = mavcrc.x25crc(frame_no_magic)
    crc.accumulate(bytes((crc_extra,)))
    return crc.crc


def _signature(key: bytes, signed_part) -> bytes:
    return hashlib.sha256(key + bytes(signed_part)).digest()[:6]


def sign_frame(frame: bytes, crc_extra: int, state: mavlink.MAVLinkSigning) -> bytes:
    """Sign a complete unsigned MAVLink 2 frame (header, payload, CRC) built by hand.

    Sets the signed incompatibility flag, recomputes the CRC with ``crc_extra`` and appends
    link id, timestamp and signature; ``state.timestamp`` then increases by one. Byte-identical
    to what pymavlink's ``msg.pack`` produces with the same state.

    Raises
    ------
    SigningError
        ``frame`` is not an unsigned MAVLink 2 frame.
    """
    if len(frame) < _V2_OVERHEAD or frame[0] != _V2 or frame[2] & _SIGNED \
            or len(frame) != _V2_OVERHEAD + frame[1]:
        raise SigningError("sign_frame needs one complete unsigned MAVLink 2 frame")
    body = bytearray(frame[:-2])
    body[2] |= _SIGNED
    body += _crc(memoryview(body)[1:], crc_extra).to_bytes(2, "little")
    body.append(state.link_id & 0xFF)
    # low 48 bits, as pymavlink packs it: a peer's valid timestamp of 2**48 - 1 must not make
    # every later send raise OverflowError (the peer then rejects the wrapped stamps as replayed)
    body += (int(state.timestamp) & _TIMESTAMP_MAX).to_bytes(6, "little")
    body += _signature(state.secret_key, body)
    state.timestamp += 1
    return bytes(body)


# ---------------------------------------------------------------------------- SETUP_SIGNING
def setup_signing_message(target_system: int, key: bytes, initial_timestamp: int,
                          target_component: int = mavlink.MAV_COMP_ID_AUTOPILOT1):
    """SETUP_SIGNING giving ``key`` to a vehicle (send it over a trusted link only).

    ``initial_timestamp`` is in 10 us units since 2015-01-01 (use the link state's
    ``timestamp``, or :func:`wire.signing.signing_timestamp` of the clock).
    """
    if len(key) != _KEY_LEN or not any(key):
        raise SigningError(f"SETUP_SIGNING needs a non-zero {_KEY_LEN}-byte key "
                           f"(use disable_signing_message to turn signing off)")
    return mavlink.MAVLink_setup_signing_message(int(target_system), int(target_component),
                                                 list(bytes(key)), int(initial_timestamp))


def disable_signing_message(target_system: int,
                            target_component: int = mavlink.MAV_COMP_ID_AUTOPILOT1):
    """SETUP_SIGNING with the all-zero key and timestamp: the vehicle stops signing."""
    return mavlink.MAVLink_setup_signing_message(int(target_system), int(target_component),
                                                 [0] * _KEY_LEN, 0)


# ---------------------------------------------------------------------------- checking
class SignatureVerifier:
    """Checks the signature of every received frame of one link; counts every outcome.

    Parameters
    ----------
    config : SigningConfig
    state : pymavlink MAVLinkSigning
        The link's signing state (:meth:`SigningConfig.new_state`): new streams are compared
        with its timestamp, which follows the highest good timestamp received (MAVLink spec).

    Attributes
    ----------
    counters : collections.Counter
        ``accepted`` (good signature), ``unsigned_allowed``, and the rejections ``unsigned``,
        ``bad_signature``, ``replayed``.
    unsigned_sysids : set of int
        System ids heard sending unsigned frames.
    signed_sysids : set of int
        System ids heard sending frames with a good signature.
    badly_signed_sysids : set of int
        System ids heard sending frames with a bad signature (another key, or forged).
    """

    def __init__(self, config: SigningConfig, state: mavlink.MAVLinkSigning) -> None:
        self.config = config
        self.state = state
        self.counters: Counter = Counter()
        self.unsigned_sysids: set[int] = set()
        self.signed_sysids: set[int] = set()
        self.badly_signed_sysids: set[int] = set()
        self._streams: dict[tuple[int, int, int], int] = {}

    def needs_setup(self, sysid: int) -> bool:
        """True if ``sysid`` was heard unsigned and never with a good signature.

        Only such a system may be sent SETUP_SIGNING: anyone can forge an unsigned frame from
        a system that already signs, and would receive the key.
        """
        return sysid in self.unsigned_sysids and sysid not in self.signed_sysids

    def diagnose(self, sysid: int) -> str:
        """Why nothing from ``sysid`` may have been accepted (for error messages; "" if unknown)."""
        if sysid in self.signed_sysids:
            return ""
        if sysid in self.badly_signed_sysids:
            return (f"system id {sysid} sends frames signed with another key (or forged): check "
                    f"the plan's [security] signing_key_file")
        if sysid in self.unsigned_sysids:
            return (f"system id {sysid} sends unsigned frames, rejected because signing is on: it "
                    f"refused SETUP_SIGNING (armed?) or [security] setup_signing is false")
        return ""

    def check(self, msg) -> str | None:
        """None to accept a decoded pymavlink message, else ``unsigned``, ``bad_signature``
        or ``replayed`` (counted). Never raises."""
        return self.check_frame(msg.get_msgbuf())

    def check_frame(self, frame) -> str | None:
        """Same as :meth:`check` for the raw bytes of one frame."""
        reason = self._check(frame)
        self.counters[reason or "accepted"] += 1
        return None if reason == "unsigned_allowed" else reason

    def _check(self, buf) -> str | None:
        n = len(buf)
        if n >= _V2_OVERHEAD and buf[0] == _V2:
            src = (buf[5], buf[6])
            msg_id = buf[7] | buf[8] << 8 | buf[9] << 16
            signed = bool(buf[2] & _SIGNED) and n >= _V2_OVERHEAD + _SIG_LEN
        elif n >= 8:  # MAVLink 1: never signed
            src, msg_id, signed = (buf[3], buf[4]), buf[5], False
        else:
            return "unsigned"
        if not signed:
            self.unsigned_sysids.add(src[0])
            return "unsigned_allowed" if self.config.allows_unsigned(msg_id) else "unsigned"
        if _signature(self.state.secret_key, buf[:-6]) != bytes(buf[-6:]):
            self.badly_signed_sysids.add(src[0])
            return "bad_signature"
        stamp = int.from_bytes(bytes(buf[-12:-6]), "little")
        stream = (buf[-13], src[0], src[1])
        last = self._streams.get(stream)
        if last is not None:
            if stamp <= last:
                return "replayed"
        elif stamp + _NEW_STREAM_MAX_LAG < self.state.timestamp:
            return "replayed"
        self._streams[stream] = stamp
        self.signed_sysids.add(src[0])
        if stamp > self.state.timestamp:
            self.state.timestamp = stamp
        return None

