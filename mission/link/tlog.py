"""Telemetry logs (``.tlog``): every MAVLink frame sent and received, one file per vehicle.

The format is the one MAVProxy writes and MAVExplorer, QGroundControl and
``pymavlink.mavutil.mavlink_connection(path)`` read: a sequence of records, each an 8-byte
big-endian count of microseconds since the Unix epoch followed by one raw MAVLink frame.

Writes are buffered and never touch the disk on the caller's thread (the event loop): a record is
queued in memory and one writer thread per :class:`TlogSet` writes the queue and flushes the files
every ``flush_interval_s`` (and at :meth:`TlogSet.flush` / :meth:`TlogSet.close`), so a crash loses
at most about a second of frames and a slow disk (a loaded host's dirty-page throttling) stalls the
writer thread, not the ground station's heartbeat, setpoints or receive path. Only a vehicle's first
frame opens its file on the caller's thread.

Frames the ground station cannot attribute to one of its vehicles (system ids not in the plan,
frames for a vehicle from an address other than the one it is pinned to, frames of unknown
message ids whose CRC cannot be checked) go to ONE :class:`QuarantineLog` per mission
(``quarantine.tlog``, shared by the endpoints through their
:class:`~mission.link.endpoint_registry.SysidRegistry`), capped at
:data:`QUARANTINE_MAX_BYTES` (5 MB); what comes beyond the cap is counted, not written.
"""
from __future__ import annotations

import os
import struct
import threading
import time
from pathlib import Path
from typing import BinaryIO, Callable

__all__ = ["QUARANTINE_MAX_BYTES", "QUARANTINE_NAME", "QuarantineLog", "TlogSet", "tlog_record",
           "read_tlog_records"]

_STAMP = struct.Struct(">Q")

#: size cap of the quarantine log (records, stamps included): 5 MB
QUARANTINE_MAX_BYTES = 5_000_000
#: file name stem of the quarantine log (``quarantine.tlog``, ``quarantine-2.tlog`` if taken)
QUARANTINE_NAME = "quarantine"


def tlog_record(frame: bytes, t_s: float) -> bytes:
    """Return one tlog record: the 8-byte big-endian microsecond stamp then the frame.

    Parameters
    ----------
    frame : bytes
        One complete MAVLink frame.
    t_s : float
        Unix-epoch seconds.
    """
    return _STAMP.pack(int(t_s * 1e6)) + bytes(frame)


def read_tlog_records(path: str | os.PathLike) -> list[tuple[float, bytes]]:
    """Split a tlog into ``(t_s, frame)`` records without decoding (for tests and tools).

    Frames are delimited by their own MAVLink header (v1 ``0xFE`` or v2 ``0xFD``, including
    the 13-byte signature when the signed flag is set).

    Raises
    ------
    ValueError
        If the file is truncated or a record does not start with a MAVLink magic byte.
    """
    data = Path(path).read_bytes()
    out = []
    i = 0
    while i < len(data):
        if i + 10 > len(data):
            raise ValueError(f"{path}: truncated record at byte {i}")
        (stamp_us,) = _STAMP.unpack_from(data, i)
        magic = data[i + 8]
        length = data[i + 9]
        if magic == 0xFD:
            incompat = data[i + 10] if i + 10 < len(data) else 0
            size = 12 + length + (13 if incompat & 0x01 else 0)
        elif magic == 0xFE:
            size = 8 + length
        else:
            raise ValueError(f"{path}: record at byte {i} starts with 0x{magic:02X}, not a MAVLink frame")
        end = i + 8 + size
        if end > len(data):
            raise ValueError(f"{path}: truncated frame at byte {i}")
        out.append((stamp_us * 1e-6, data[i + 8:end]))
        i = end
    return out


class TlogSet:
    """One ``.tlog`` file per vehicle system id, created on that vehicle's first frame.

    Files are named ``vehicle-<sysid>.tlog`` in ``directory``; an existing file is never
    overwritten: the name gets a suffix ``-2``, ``-3``... instead.

    Parameters
    ----------
    directory : str or path-like
        Where the files go (created if missing).
    time_fn : callable, optional
        Returns the stamp in Unix-epoch seconds; default ``time.time`` (pass ``clock.time``
        to stamp on a simulated timeline).
    flush_interval_s : float
        Flush every file at most this long (wall seconds) after its last flush.
    buffer_bytes : int
        Size of each file's write buffer.
    """

    def __init__(self, directory: str | os.PathLike, *, time_fn: Callable[[], float] | None = None,
                 flush_interval_s: float = 1.0, buffer_bytes: int = 32768) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._time_fn = time_fn or time.time
        self._flush_interval_s = float(flush_interval_s)
        self._buffer_bytes = int(buffer_bytes)
        self._files: dict[int, BinaryIO] = {}
        self._paths: dict[int, Path] = {}
        self.records_written = 0
        self.closed = False
        #: the first write or flush error of the writer thread (then nothing more is written)
        self.error: OSError | None = None
        self._pending: list[tuple[BinaryIO, bytes]] = []
        self._queue_lock = threading.Lock()  # the queue: the callers append, the writer swaps it out
        self._io_lock = threading.Lock()     # one drain at a time, in order
        self._wake = threading.Event()
        self._writer: threading.Thread | None = None

    def path(self, sysid: int) -> Path | None:
        """The file of ``sysid``, or None if nothing was logged for it yet."""
        return self._paths.get(sysid)

    def paths(self) -> dict[int, Path]:
        """All files so far, by system id."""
        return dict(self._paths)

    def _open(self, sysid: int) -> BinaryIO:
        n = 1
        while True:
            suffix = "" if n == 1 else f"-{n}"
            path = self.directory / f"vehicle-{sysid}{suffix}.tlog"
            try:
                fh = open(path, "xb", buffering=self._buffer_bytes)
            except FileExistsError:
                n += 1
                continue
            self._files[sysid] = fh
            self._paths[sysid] = path
            return fh

    def write(self, sysid: int, frame: bytes, t_s: float | None = None) -> None:
        """Queue one frame for ``sysid``'s file, stamped ``t_s`` (default: now); the writer thread
        writes it (:meth:`flush` to have it written now).

        Does nothing once closed (frames racing a shutdown are not an error).
        """
        if self.closed:
            return
        fh = self._files.get(sysid)
        if fh is None:
            fh = self._open(sysid)
        record = _STAMP.pack(int((self._time_fn() if t_s is None else t_s) * 1e6)) + bytes(frame)
        with self._queue_lock:
            self._pending.append((fh, record))
        self.records_written += 1
        if self._writer is None:
            self._writer = threading.Thread(target=self._run, name=f"tlog writer {self.directory}", daemon=True)
            self._writer.start()

    def _run(self) -> None:
        """The writer thread: drain the queue every flush interval (sooner when woken) until closed."""
        while not self.closed:
            self._wake.wait(self._flush_interval_s)
            self._wake.clear()
            self._drain()

    def _drain(self) -> None:
        """Write what is queued, in order, and flush the files written to."""
        with self._io_lock:
            with self._queue_lock:
                batch, self._pending = self._pending, []
            if self.error is not None:
                return
            touched = {}
            try:
                for fh, record in batch:
                    fh.write(record)
                    touched[id(fh)] = fh
                for fh in touched.values():
                    fh.flush()
            except (OSError, ValueError) as exc:  # disk full, file too large, a file closed under it
                self.error = exc if isinstance(exc, OSError) else OSError(str(exc))

    def flush(self) -> None:
        """Write what is queued and flush every file to the operating system, on the caller's
        thread (tests, tools; the mission's endpoints leave it to the writer thread)."""
        self._drain()

    def close(self) -> None:
        """Write what is queued, flush and close every file; later writes are ignored."""
        if self.closed:
            return
        self.closed = True
        self._wake.set()
        if self._writer is not None:
            self._writer.join()
        self._drain()
        for fh in self._files.values():
            try:
                fh.close()
            except OSError as exc:
                self.error = self.error or exc


class QuarantineLog:
    """One capped ``.tlog`` for the frames of unknown or suspect senders (opened on the first one).

    Parameters
    ----------
    directory : str or path-like
        Where ``quarantine.tlog`` goes (``quarantine-2.tlog``... if taken).
    time_fn : callable, optional
        Returns the stamp in Unix-epoch seconds; default ``time.time``.
    max_bytes : int
        Size cap; a record that would cross it is dropped and counted.

    Attributes
    ----------
    counters : dict of str to int
        ``records`` (written), ``bytes`` (written, stamps included), ``dropped`` (beyond the cap).
    """

    def __init__(self, directory: str | os.PathLike, *, time_fn: Callable[[], float] | None = None,
                 max_bytes: int = QUARANTINE_MAX_BYTES) -> None:
        self.directory = Path(directory)
        self.max_bytes = int(max_bytes)
        self._time_fn = time_fn or time.time
        self._fh: BinaryIO | None = None
        self.path: Path | None = None
        self.counters = {"records": 0, "bytes": 0, "dropped": 0}
        self.closed = False

    def _open(self) -> BinaryIO:
        self.directory.mkdir(parents=True, exist_ok=True)
        n = 1
        while True:
            path = self.directory / f"{QUARANTINE_NAME}{'' if n == 1 else f'-{n}'}.tlog"
            try:
                self._fh = open(path, "xb", buffering=32768)
            except FileExistsError:
                n += 1
                continue
            self.path = path
            return self._fh

    def write(self, frame: bytes) -> bool:
        """Append one frame stamped now; False (counted ``dropped``) beyond the cap or once closed."""
        size = 8 + len(frame)
        if self.closed or self.counters["bytes"] + size > self.max_bytes:
            self.counters["dropped"] += 1
            return False
        fh = self._fh if self._fh is not None else self._open()
        fh.write(_STAMP.pack(int(self._time_fn() * 1e6)))
        fh.write(frame)
        self.counters["records"] += 1
        self.counters["bytes"] += size
        return True

    def flush(self) -> None:
        """Flush the file's buffer (if the file exists)."""
        if self._fh is not None and not self.closed:
            self._fh.flush()

    def close(self) -> None:
        """Flush and close; later writes are counted as dropped."""
        if self.closed:
            return
        self.closed = True
        if self._fh is not None:
            self._fh.close()
