"""MAVLink 2 signing shared by the ground station (:mod:`mission.link.signing`) and the mock
autopilots (:mod:`sitl_mock.ap_signing`): key files and signing timestamps.

Timestamps (:func:`signing_timestamp`) are 10 microsecond units since 2015-01-01 00:00 UTC
(:data:`SIGNING_EPOCH_UNIX_S`), clipped to 48 bits.

Key-file format, tried in this order: 64 hexadecimal characters (surrounding whitespace
ignored); exactly 32 bytes that are not all printable ASCII (the raw key; 32 printable bytes are
refused as ambiguous); otherwise one line of UTF-8 text, a passphrase, whose SHA-256 is the key
(MAVProxy's ``signing setup PASSPHRASE``). The file must not be world-readable.
"""
from __future__ import annotations

import hashlib
import os
import stat
import warnings
from pathlib import Path

__all__ = ["SIGNING_EPOCH_UNIX_S", "SigningError", "SigningWarning", "load_key_file", "passphrase_to_key",
           "signing_timestamp"]

#: 2015-01-01 00:00:00 UTC, the origin of MAVLink signing timestamps.
SIGNING_EPOCH_UNIX_S = 1_420_070_400
_KEY_LEN = 32
_KEY_FILE_MAX_BYTES = 4096
_TIMESTAMP_MAX = (1 << 48) - 1


def signing_timestamp(unix_s: float) -> int:
    """Signing timestamp of a Unix time: 10 us units since 2015-01-01 UTC, clipped to 48 bits."""
    return max(0, min(int((float(unix_s) - SIGNING_EPOCH_UNIX_S) * 100_000), _TIMESTAMP_MAX))


class SigningError(ValueError):
    """A signing key, key file or ``[security]`` setting that cannot be used.

    Attributes
    ----------
    problems : list of (str, str)
        ``(key_path, why)`` pairs (one ``("(key file)", why)`` for key-file errors), the shape
        :class:`mission.core.plan.PlanError` takes.
    """

    def __init__(self, message: str, problems: list[tuple[str, str]] | None = None):
        super().__init__(message)
        self.problems = list(problems) if problems else [("(key file)", message)]


class SigningWarning(UserWarning):
    """A usable but weakly protected key file (group-readable, or world-readable if allowed)."""


def passphrase_to_key(passphrase: str) -> bytes:
    """The 32-byte key of a passphrase: ``SHA-256(UTF-8 bytes)``, as MAVProxy computes it."""
    if not isinstance(passphrase, str) or not passphrase:
        raise SigningError("a signing passphrase must be a non-empty string")
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def load_key_file(path, *, allow_world_readable: bool = False) -> bytes:
    """Read a signing key file (format in the module docstring).

    Parameters
    ----------
    path : str or path-like
    allow_world_readable : bool
        Accept a world-readable file with a :class:`SigningWarning` instead of refusing it.

    Returns
    -------
    bytes
        The 32-byte key.

    Raises
    ------
    SigningError
        Missing, unreadable, not a regular file, world-readable, too large, empty, several
        lines, ambiguous 32 printable bytes, not UTF-8, or the all-zero key. The message names
        the file and says what to do.
    """
    p = Path(path)
    where = str(p)
    try:
        st = p.stat()
    except OSError as exc:
        raise SigningError(f"signing key file {where!r}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise SigningError(f"signing key file {where!r} is not a regular file")
    if os.name == "posix":
        mode = stat.S_IMODE(st.st_mode)
        if mode & stat.S_IROTH:
            text = (f"signing key file {where!r} is world-readable (mode {mode:o}); "
                    f"run: chmod 600 {p}")
            if not allow_world_readable:
                raise SigningError(text)
            warnings.warn(text, SigningWarning, stacklevel=2)
        elif mode & stat.S_IRGRP:
            warnings.warn(f"signing key file {where!r} is group-readable (mode {mode:o}); "
                          f"consider: chmod 600 {p}", SigningWarning, stacklevel=2)
    if st.st_size > _KEY_FILE_MAX_BYTES:
        raise SigningError(f"signing key file {where!r} is {st.st_size} bytes; a key file holds "
                           f"64 hex characters, 32 raw bytes or a one-line passphrase")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise SigningError(f"signing key file {where!r}: {exc.strerror or exc}") from None
    key = _decode_key(data, where)
    if not any(key):
        raise SigningError(f"signing key file {where!r} holds the all-zero key, which means "
                           f"'signing off' in SETUP_SIGNING")
    return key


def _decode_key(data: bytes, where: str) -> bytes:
    stripped = data.strip()
    if len(stripped) == 2 * _KEY_LEN:
        try:
            return bytes.fromhex(stripped.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == _KEY_LEN:
        if all(32 <= b < 127 for b in data):
            raise SigningError(
                f"signing key file {where!r} is ambiguous: 32 printable bytes could be a raw key "
                f"or a passphrase; write the key as 64 hex characters or end the passphrase with "
                f"a newline")
        return bytes(data)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise SigningError(f"signing key file {where!r} is neither 64 hex characters, 32 raw "
                           f"bytes nor a UTF-8 passphrase ({len(data)} bytes)") from None
    line = text.rstrip("\r\n")
    if not line.strip():
        raise SigningError(f"signing key file {where!r} is empty (no passphrase)")
    if "\n" in line or "\r" in line:
        raise SigningError(f"signing key file {where!r} has several lines; a passphrase is one line")
    return passphrase_to_key(line)
