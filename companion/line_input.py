"""Lines of text from a serial device or standard input, one reading a line.

:class:`LineSplitter` cuts a byte stream into lines (``\\n``; a ``\\r`` before it is dropped
with the other whitespace) and refuses a line longer than ``max_bytes`` (a device at the wrong
baud rate sends no newline); :func:`parse_reading_line` turns a line into a number or says why
not. :class:`SerialSource` (pyserial) and :class:`StdinSource` give chunks of bytes with a short
timeout, so that the caller's loop keeps its own deadlines.
"""
from __future__ import annotations

import math
import os
import select

__all__ = ["BAD_LINE_REASONS", "InputError", "LineSplitter", "SerialSource", "StdinSource", "parse_reading_line"]

#: why a line is not a reading
BAD_LINE_REASONS = ("empty", "not_a_number", "not_finite", "too_long")
#: read timeout of the sources: the longest a caller's loop waits without a byte
READ_TIMEOUT_S = 0.2


class InputError(RuntimeError):
    """The input cannot be opened or read (no such serial device, device unplugged)."""


def parse_reading_line(line: bytes | str) -> tuple[float | None, str | None]:
    """``(value, None)`` for a line holding one finite number, else ``(None, reason)``.

    Parameters
    ----------
    line : bytes or str
        One line without its newline (bytes are read as UTF-8; undecodable bytes make it
        ``not_a_number``). Surrounding whitespace (also ``\\r``) is ignored.

    Returns
    -------
    tuple
        The value (float), or the reason, one of ``empty``, ``not_a_number``, ``not_finite``.
    """
    text = line.decode("utf-8", errors="replace") if isinstance(line, (bytes, bytearray)) else line
    text = text.strip()
    if not text:
        return None, "empty"
    try:
        value = float(text)
    except ValueError:
        return None, "not_a_number"
    if not math.isfinite(value):
        return None, "not_finite"
    return value, None


class LineSplitter:
    """Cuts a byte stream into lines.

    Parameters
    ----------
    max_bytes : int
        A line longer than this is dropped whole and given as None (``too_long``).
    """

    def __init__(self, max_bytes: int = 256):
        self.max_bytes = int(max_bytes)
        self._buf = bytearray()
        self._dropping = False  # inside a too-long line, until its newline

    def feed(self, chunk: bytes) -> list[bytes | None]:
        """The lines completed by ``chunk`` (None for each too-long line)."""
        out: list[bytes | None] = []
        self._buf += chunk
        while (i := self._buf.find(b"\n")) >= 0:
            line = bytes(self._buf[:i])
            del self._buf[:i + 1]
            if self._dropping:
                self._dropping = False  # the end of a line already counted
            else:
                out.append(line if len(line) <= self.max_bytes else None)
        if len(self._buf) > self.max_bytes:
            if not self._dropping:
                out.append(None)
            self._dropping = True
            self._buf.clear()
        return out

    def finish(self) -> list[bytes | None]:
        """At the end of the input: the last line if it had no newline."""
        rest, self._buf = bytes(self._buf), bytearray()
        return [] if self._dropping or not rest else [rest]


class SerialSource:
    """A serial device (pyserial), read with a short timeout.

    Parameters
    ----------
    device : str
        Device path (``/dev/ttyUSB0``) or any pyserial URL.
    baud : int
        Baud rate.

    Raises
    ------
    InputError
        The device cannot be opened.
    """

    def __init__(self, device: str, baud: int):
        import serial

        self.name = device
        try:
            self._port = serial.serial_for_url(device, baudrate=baud, timeout=READ_TIMEOUT_S)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise InputError(f"cannot open serial device {device!r}: {exc}") from None

    def read(self) -> bytes | None:
        """Bytes received within the timeout (``b""`` when none); a serial device has no end.

        Raises
        ------
        InputError
            The device failed (unplugged).
        """
        import serial

        try:
            return self._port.read(max(1, self._port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise InputError(f"serial device {self.name!r} failed: {exc}") from None

    def close(self) -> None:
        """Close the device."""
        self._port.close()


class StdinSource:
    """Standard input (a pipe, a file or a terminal), read with a short timeout."""

    name = "standard input"

    def __init__(self, fd: int = 0):
        self._fd = fd

    def read(self) -> bytes | None:
        """Bytes available within the timeout (``b""`` when none), None at the end of the input.

        Raises
        ------
        InputError
            Standard input cannot be read (closed, not a file).
        """
        try:
            ready, _, _ = select.select([self._fd], [], [], READ_TIMEOUT_S)
            if not ready:
                return b""
            chunk = os.read(self._fd, 4096)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read standard input: {exc}") from None
        return chunk if chunk else None

    def close(self) -> None:
        """Nothing to close (standard input belongs to the process)."""
