"""The mission log: JSON lines written and flushed as they happen.

One JSON object per line; every record has ``t_s`` (mission clock) and ``type``:

``plan``       the plan flown (first record; no secret: signing appears as ``signing: true`` and
               the key's ``fingerprint``, see :meth:`mission.core.signing_config.SigningConfig.to_json`)
``phase``      a phase starts: ``phase``
``event``      something worth knowing: ``level`` (info|warning|error), ``message``, extra fields
``status``     per-vehicle status: ``vehicles`` (list of dicts)
``iteration``  one seeking iteration: ``k``, ``centre_enu``, ``gradient``, ``new_centre_enu``,
               ``estimate_enu`` with ``estimate_region95_m`` and ``estimate_basis`` (its 95 %
               region; ``estimate_map``, the plan-view posterior, for a seeker that has one),
               ``spread_m``, ``readings`` (sysid, seq, time_s, value,
               position_enu_m), ``positions_enu`` (telemetry), ``distance_flown_m``
``status_change``  one vehicle's status changed: ``sysid``, ``status``, ``previous``, ``reason``,
               ``phase`` (:meth:`mission.flight.state.MissionState.set_status`)
``summary``    the end result (see :class:`mission.flight.result.MissionResult`)

Each line is flushed (and ``os.fsync``-ed for ``phase``/``summary`` records) as soon as it is
written, so a crash loses nothing already logged. :func:`read_mission_log` reads a log back,
ignoring a truncated last line.

A write that fails (disk full, file size limit: Python ignores SIGXFSZ, so the write raises
``EFBIG``) never raises into the mission: the log keeps the error (:attr:`MissionLog.error`), stops
writing and calls its ``on_error`` once (:func:`mission.flight.operator_stop.run_until_stopped`
brings the vehicles home and says so on whatever output still works).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from collections import deque
from collections.abc import Callable, Iterator
from enum import Enum
from pathlib import Path, PurePath
from typing import IO

import numpy as np
from pymavlink.dialects.v20.ardupilotmega import MAVLink_message

from mission.core.redaction import (
    REDACTED,
    SECRET_NAMES,
    describe_bytes,
    is_secret_field,
)

__all__ = ["RECENT_RECORDS", "RECENT_KINDS", "MissionLog", "dataclass_json", "iter_mission_log", "read_mission_log",
           "to_jsonable"]

#: How many of the last event, phase and command records a log keeps in memory (:attr:`MissionLog.recent`,
#: published in the mission state as ``events`` for the live map)
RECENT_RECORDS = 30
RECENT_KINDS = frozenset({"event", "phase", "command"})


def to_jsonable(obj):
    """Convert a value into JSON types for a log, a summary or a publication; never a secret.

    numpy arrays and scalars become lists and numbers (NaN and infinities: None), tuples and sets
    lists, objects with a ``to_json()`` method what it returns, dataclasses dicts of their fields
    (:func:`dataclass_json`: fields declared with
    :func:`mission.core.redaction.secret_field` are redacted), byte strings their length only,
    paths and enums their text, exceptions their type and message, MAVLink messages their fields.
    A dict entry named in :data:`mission.core.redaction.SECRET_NAMES` (``secret_key``,
    ``password``...) is redacted wherever it is. Any other object becomes
    ``<TypeName>``: its ``str()`` could hold anything (a MAVLink SETUP_SIGNING message holds the
    key), so it is never written.
    """
    t = type(obj)   # the commonest leaves first, by exact type (what the general path gives them)
    if t is float:
        return round(obj, 6) if math.isfinite(obj) else None
    if t is str or t is int or t is bool or obj is None:
        return obj
    return _jsonable_any(obj)


def _jsonable_any(obj):
    """:func:`to_jsonable` of any value (the general path; containers recurse through :func:`to_jsonable`)."""
    if isinstance(obj, dict):
        return {str(k): REDACTED if k in SECRET_NAMES else _degrees(v) if str(k).endswith("_deg")
                else to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted((to_jsonable(v) for v in obj), key=repr)
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f" and obj.ndim == 1 and np.isfinite(obj).all():
            return [round(v, 6) for v in obj.tolist()]  # the common case, without the recursion
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return round(f, 6) if math.isfinite(f) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, MAVLink_message):  # its own to_json() would write SETUP_SIGNING's key
        return to_jsonable(obj.to_dict())
    if hasattr(obj, "to_json"):
        return to_jsonable(obj.to_json())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclass_json(obj)
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return describe_bytes(obj)
    if isinstance(obj, (PurePath, Enum)):
        return str(obj)
    if isinstance(obj, BaseException):
        return f"{type(obj).__name__}: {obj}"
    return f"<{type(obj).__name__}>"


def _degrees(value):
    """An angle entry (``*_deg``): 9 decimals (0.1 mm on the ground) instead of 6 (0.1 m), also
    in a list of them (a fence file's ``source_latlon_deg`` vertices)."""
    if isinstance(value, (np.floating, float)) and math.isfinite(float(value)):
        return round(float(value), 9)
    if isinstance(value, (list, tuple)):
        return [_degrees(v) for v in value]
    return to_jsonable(value)


def dataclass_json(obj) -> dict:
    """The fields of dataclass instance ``obj`` through :func:`to_jsonable`, secret ones redacted.

    Unlike ``dataclasses.asdict``, a nested value's own ``to_json()`` is used (a signing
    configuration writes its fingerprint, never its key); a ``*_deg`` field keeps 9 decimals, as a
    ``*_deg`` dict entry does.
    """
    return {f.name: REDACTED if is_secret_field(f) else _degrees(getattr(obj, f.name)) if f.name.endswith("_deg")
            else to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}


class MissionLog:
    """Append-only JSON-lines writer.

    Parameters
    ----------
    path : str or pathlib.Path
        File to create (parent directories are made); an existing file is appended to.
    clock
        Provides ``time()`` for the ``t_s`` field.

    Attributes
    ----------
    error : OSError or None
        The first write that failed; from then on nothing more is written (``dropped`` counts
        the records lost).
    on_error : callable or None
        Called once with that error.
    recent : collections.deque
        The last :data:`RECENT_RECORDS` event, phase and command records, shortened and numbered
        (``seq``), for the state publication's ``events``.
    """

    def __init__(self, path: str | Path, clock):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock = clock
        self._fh: IO[str] | None = open(self.path, "a", encoding="utf-8")
        self.records = 0
        self.error: OSError | None = None
        self.dropped = 0
        self.on_error: Callable[[OSError], None] | None = None
        self.recent: deque = deque(maxlen=RECENT_RECORDS)
        self._seq = 0

    def write(self, kind: str, sync: bool = False, **fields) -> dict:
        """Write one record of type ``kind`` and flush it; returns the record written."""
        record = {"t_s": round(float(self.clock.time()), 4), "type": kind}
        record.update(to_jsonable(fields))
        if kind in RECENT_KINDS:
            self._remember(record)
        if self._fh is None:
            self.dropped += self.error is not None
            return record
        try:
            self._fh.write(json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n")
            self._fh.flush()
        except OSError as exc:
            self._fail(exc)
            return record
        if sync:
            try:
                os.fsync(self._fh.fileno())
            except OSError:
                pass
        self.records += 1
        return record

    def _remember(self, record: dict) -> None:
        """Keep a short copy of an event, phase or command record in :attr:`recent` (numbered)."""
        self._seq += 1
        short = {"seq": self._seq, "t_s": record["t_s"], "type": record["type"]}
        for key in ("level", "message", "phase", "command", "sender", "accepted", "reason"):
            if key in record:
                short[key] = str(record[key])[:300] if isinstance(record[key], str) else record[key]
        self.recent.append(short)

    def _fail(self, exc: OSError) -> None:
        """The first failed write: stop writing (what is buffered is lost), tell ``on_error``."""
        self.error, self.dropped = exc, 1
        fh, self._fh = self._fh, None
        try:
            fh.close()
        except OSError:
            pass  # the same failure, flushing what was buffered
        if self.on_error is not None:
            self.on_error(exc)

    def phase(self, name: str, **fields) -> dict:
        """Record the start of a phase (synced to disk)."""
        return self.write("phase", sync=True, phase=name, **fields)

    def event(self, message: str, level: str = "info", **fields) -> dict:
        """Record an event."""
        return self.write("event", level=level, message=message, **fields)

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if self._fh is not None:
            try:
                self._fh.flush()
                os.fsync(self._fh.fileno())
            except OSError:
                pass
            try:
                self._fh.close()
            except OSError as exc:  # the last records could not be written
                self.error = self.error or exc
            self._fh = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def iter_mission_log(path: str | Path, prefilter: tuple[str, ...] | None = None) -> Iterator[dict]:
    """Yield the records of a mission log; a truncated or corrupt line is skipped.

    Parameters
    ----------
    path : str or Path
        The ``mission.jsonl`` file.
    prefilter : tuple of str, optional
        A fast path for a reader that wants some records only: a line holding none of these
        substrings is skipped without being parsed. The caller's filter on the records must be
        one such a line cannot pass (e.g. ``("plan", "\\u")`` for ``type == "plan"``: the
        type's text, or a JSON escape that could spell it).
    """
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if prefilter is not None and not any(sub in line for sub in prefilter):
                continue
            line = line.strip()
            if not line:
                continue
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and "type" in rec:
                yield rec


def read_mission_log(path: str | Path) -> list[dict]:
    """All records of a mission log (see :func:`iter_mission_log`).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        The file holds no mission-log record at all.
    """
    records = list(iter_mission_log(path))
    if not records:
        raise ValueError(f"{path}: not a swarmseek mission log (no JSON-lines record found)")
    return records
