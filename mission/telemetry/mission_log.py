"""The mission log: JSON lines written and flushed as they happen.

One JSON object per line; every record has ``t_s`` (mission clock) and ``type``:

``plan``       the plan flown (first record)
``phase``      a phase starts: ``phase``
``event``      something worth knowing: ``level`` (info|warning|error), ``message``, extra fields
``status``     per-vehicle status: ``vehicles`` (list of dicts)
``iteration``  one seeking iteration: ``k``, ``centre_enu``, ``gradient``, ``new_centre_enu``,
               ``estimate_enu``, ``spread_m``, ``readings`` (sysid, seq, time_s, value,
               position_enu_m), ``positions_enu`` (telemetry), ``distance_flown_m``
``status_change``  one vehicle's status changed: ``sysid``, ``status``, ``previous``, ``reason``,
               ``phase`` (:meth:`mission.flight.state.MissionState.set_status`)
``summary``    the end result (see :class:`mission.flight.result.MissionResult`)

Each line is flushed (and ``os.fsync``-ed for ``phase``/``summary`` records) as soon as it is
written, so a crash loses nothing already logged. :func:`read_mission_log` reads a log back,
ignoring a truncated last line.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import IO, Iterator

import numpy as np

__all__ = ["MissionLog", "iter_mission_log", "read_mission_log", "to_jsonable"]


def to_jsonable(obj):
    """Convert numpy arrays/scalars, tuples, dataclass-like values into JSON types (NaN -> None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
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
    if hasattr(obj, "to_json"):
        return to_jsonable(obj.to_json())
    return str(obj)


class MissionLog:
    """Append-only JSON-lines writer.

    Parameters
    ----------
    path : str or pathlib.Path
        File to create (parent directories are made); an existing file is appended to.
    clock
        Provides ``time()`` for the ``t_s`` field.
    """

    def __init__(self, path: str | Path, clock):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock = clock
        self._fh: IO[str] | None = open(self.path, "a", encoding="utf-8")
        self.records = 0

    def write(self, kind: str, sync: bool = False, **fields) -> dict:
        """Write one record of type ``kind`` and flush it; returns the record written."""
        record = {"t_s": round(float(self.clock.time()), 4), "type": kind}
        record.update(to_jsonable(fields))
        if self._fh is None:
            return record
        self._fh.write(json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n")
        self._fh.flush()
        if sync:
            try:
                os.fsync(self._fh.fileno())
            except OSError:
                pass
        self.records += 1
        return record

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
            self._fh.close()
            self._fh = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def iter_mission_log(path: str | Path) -> Iterator[dict]:
    """Yield the records of a mission log; a truncated or corrupt line is skipped."""
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        for line in fh:
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
