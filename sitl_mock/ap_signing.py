"""MAVLink 2 message signing of a mock autopilot (what ArduPilot's ``GCS_Signing.cpp`` does).

A vehicle without a key accepts everything (signed or not) and sends unsigned frames. Once it has
a key (from ``SETUP_SIGNING``, accepted only while disarmed as ArduPilot does, or set from
Python) it signs every frame it sends and accepts a received frame only if

* it is signed (the ``0x01`` incompatibility flag and the 13-byte signature block): unsigned
  frames are rejected as ``rx_unsigned``, except RADIO_STATUS and RADIO (the radio modems inject
  them unsigned; ArduPilot's accept list);
* its signature is ``SHA-256(key + frame without the 6 signature bytes)[:6]``: else
  ``rx_bad_signature`` (a wrong key, a tampered byte);
* its timestamp is greater than the last one accepted on its stream ``(link id, system id,
  component id)``, or, for a stream not heard yet, at most one minute behind the vehicle's own
  timestamp: else ``rx_replayed``.

The signature is checked before the timestamp and a stream's timestamp only moves on a good
signature, so forged frames cannot poison a stream (pymavlink's own ``check_signature`` records
the timestamp before it checks the signature). Timestamps are in units of 10 microseconds since
2015-01-01 00:00 UTC; the vehicle's own timestamp follows its simulated clock, is never behind the
``initial_timestamp`` of SETUP_SIGNING nor behind any timestamp it accepted, and increases by one
per frame sent.

An all-zero key (with ``initial_timestamp`` 0, as the MAVLink spec says) turns signing off. When
signing is on, SETUP_SIGNING itself must be signed with the current key to be accepted. Both
personalities behave like ArduPilot here (the mock has no USB port, ArduPilot's "channel 0
accepts anything"; PX4's ``MAV_SIGN_CFG`` modes are not modelled). The key survives a simulated
reboot (ArduPilot keeps it in flash). Everything runs in the fleet thread except
:meth:`VehicleSigning.set_key` called from Python, which is ordered so that a concurrent send
never signs without a key; prefer setting keys before the fleet starts.

Key files (64 hex characters, 32 raw bytes or a passphrase hashed with SHA-256) are read by
:func:`wire.signing.load_key_file`, the ground station's reader too; a bad key is a
:class:`wire.signing.SigningError`.
"""
from __future__ import annotations

import hashlib

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from wire.signing import SigningError, signing_timestamp

__all__ = [
    "UNSIGNED_OK_MSG_IDS",
    "VehicleSigning",
    "frame_signature",
]

#: messages accepted unsigned while signing is on (ArduPilot's accept list: radio modems).
UNSIGNED_OK_MSG_IDS = frozenset({mavlink2.MAVLINK_MSG_ID_RADIO_STATUS, mavlink2.MAVLINK_MSG_ID_RADIO})
_SIGNED_FLAG = mavlink2.MAVLINK_IFLAG_SIGNED
_SIGNATURE_LEN = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN  # link id (1) + timestamp (6) + signature (6)
_V2_MIN_LEN = 10 + 2
_NEW_STREAM_MAX_LAG = 6_000_000  # one minute in 10 us units (MAVLink spec)
_TIMESTAMP_MAX = (1 << 48) - 1
_KEY_LEN = 32

def frame_signature(key: bytes, signed_part: bytes) -> bytes:
    """The 6-byte signature of a frame: ``SHA-256(key + signed_part)[:6]``.

    ``signed_part`` is the frame from its magic byte to the timestamp included (everything but
    the last 6 bytes of a signed frame).
    """
    return hashlib.sha256(bytes(key) + bytes(signed_part)).digest()[:6]


def _check_key(key) -> bytes:
    if not isinstance(key, (bytes, bytearray)) or len(key) != _KEY_LEN:
        raise SigningError(f"a signing key is {_KEY_LEN} bytes, got "
                              f"{len(key) if isinstance(key, (bytes, bytearray)) else type(key).__name__}")
    return bytes(key)


class VehicleSigning:
    """Signing state of one vehicle: key, own timestamp, per-stream timestamps, counters.

    Parameters
    ----------
    mav : pymavlink MAVLink
        The vehicle's encoder; its ``signing`` attributes are set so that ``msg.pack(mav)``
        signs every frame once a key is set.
    counters : collections.Counter
        Where rejections and SETUP_SIGNING outcomes are counted.
    unsigned_ok_msg_ids : frozenset of int
        Message ids accepted unsigned while signing is on.
    """

    def __init__(self, mav, counters, unsigned_ok_msg_ids=UNSIGNED_OK_MSG_IDS):
        self.mav = mav
        self.counters = counters
        self.unsigned_ok_msg_ids = frozenset(unsigned_ok_msg_ids)
        self._key: bytes | None = None
        self._streams: dict[tuple[int, int, int], int] = {}

    @property
    def enabled(self) -> bool:
        """True while the vehicle has a key (signs and checks)."""
        return self._key is not None

    @property
    def timestamp(self) -> int:
        """The vehicle's own signing timestamp (the next frame it sends carries it)."""
        return int(self.mav.signing.timestamp)

    def set_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Turn signing on with ``key`` (32 bytes), or off with None or the all-zero key.

        The own timestamp becomes at least ``initial_timestamp``; the streams heard so far
        are forgotten when the key changes.
        """
        signing = self.mav.signing
        if key is None or not any(_check_key(key)):
            signing.sign_outgoing = False  # first: a concurrent pack() must not sign without key
            signing.secret_key = None
            self._key = None
            self._streams.clear()
            return
        key = _check_key(key)
        if key != self._key:
            self._streams.clear()
        signing.timestamp = max(int(signing.timestamp), min(int(initial_timestamp), _TIMESTAMP_MAX))
        signing.link_id = 0
        signing.secret_key = key
        signing.sign_outgoing = True
        self._key = key

    def advance_clock(self, unix_s: float) -> None:
        """Bring the own timestamp up to the (simulated) time ``unix_s`` (never backwards)."""
        if self._key is not None:
            now = signing_timestamp(unix_s)
            if now > self.mav.signing.timestamp:
                self.mav.signing.timestamp = now

    def check(self, msg) -> str | None:
        """None to accept ``msg``; else the counter name of why it is rejected.

        Accepts everything while signing is off.
        """
        key = self._key
        if key is None:
            return None
        buf = msg.get_msgbuf()
        header = msg.get_header()
        if (len(buf) < _V2_MIN_LEN + _SIGNATURE_LEN or buf[0] != mavlink2.PROTOCOL_MARKER_V2
                or not header.incompat_flags & _SIGNED_FLAG):
            if msg.get_msgId() in self.unsigned_ok_msg_ids:
                self.counters["rx_unsigned_accepted"] += 1
                return None
            return "rx_unsigned"
        if frame_signature(key, buf[:-6]) != bytes(buf[-6:]):
            return "rx_bad_signature"
        stamp = int.from_bytes(buf[-12:-6], "little")
        stream = (buf[-13], header.srcSystem, header.srcComponent)
        last = self._streams.get(stream)
        signing = self.mav.signing
        if last is not None:
            if stamp <= last:
                return "rx_replayed"
        elif stamp + _NEW_STREAM_MAX_LAG < signing.timestamp:
            return "rx_replayed"
        self._streams[stream] = stamp
        if stamp > signing.timestamp:
            signing.timestamp = stamp
        return None

    def handle_setup(self, msg, armed: bool) -> str:
        """Act on a SETUP_SIGNING that passed :meth:`check`; returns the outcome counted.

        ``"signing_setup_refused_armed"`` (ArduPilot ignores it while armed and says so),
        ``"signing_disabled"`` (all-zero key) or ``"signing_setup_accepted"``.
        """
        if armed:
            outcome = "signing_setup_refused_armed"
        else:
            key = bytes(bytearray(msg.secret_key))
            if not any(key):
                self.set_key(None)
                outcome = "signing_disabled"
            else:
                self.set_key(key, int(msg.initial_timestamp))
                outcome = "signing_setup_accepted"
        self.counters[outcome] += 1
        return outcome
