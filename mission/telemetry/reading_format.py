"""Wire format of sensor readings: schema, zenoh keys, payload decoding and rejection reasons.

Readings arrive on ``swarmseek/<fleet>/vehicle/<sysid>/sensor`` as the JSON payload of
``docs/interfaces.md`` (schema ``swarmseek.sensor.v1``). This module holds what can be checked
from one sample alone (key shape, JSON types, finiteness, ranges) and the accepted
:class:`Reading`; :mod:`mission.telemetry.readings` adds the per-fleet checks (vehicle, sequence,
age, position) and the history. Each name is imported from the module that defines it.
"""
from __future__ import annotations

import json
import math
from math import isfinite
from dataclasses import dataclass

import numpy as np

try:  # optional accelerator (see _orjson_loads); the standard library decides without it
    import orjson
except ImportError:  # pragma: no cover - depends on the environment
    orjson = None

__all__ = [
    "SCHEMA",
    "REJECT_REASONS",
    "Reading",
    "ReadingRejected",
    "decode_reading",
    "sensor_key",
    "sensor_key_expr",
    "sysid_from_key",
]

SCHEMA = "swarmseek.sensor.v1"
REJECT_REASONS = ("malformed", "wrong_schema", "wrong_fleet", "bad_key", "unknown_vehicle",
                  "sysid_mismatch", "not_finite", "duplicate", "old_seq", "late", "position_far")
_FIELDS = {"schema": str, "fleet": str, "sysid": int, "seq": int, "time_s": float,
           "lat_deg": float, "lon_deg": float, "alt_m": float, "value": float}


class ReadingRejected(ValueError):
    """A reading that cannot be used; ``reason`` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, detail: str):
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


@dataclass(frozen=True)
class Reading:
    """One accepted sensor reading.

    Attributes
    ----------
    sysid, seq : int
    time_s : float
        Sender's clock when the sample was taken.
    lat_deg, lon_deg, alt_m : float
        Where it was taken.
    value : float
    position_enu_m : numpy.ndarray
        Where it was taken, mission ENU frame.
    received_s : float
        Mission clock when it was accepted.
    """

    sysid: int
    seq: int
    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    value: float
    position_enu_m: np.ndarray
    received_s: float

    @classmethod
    def accepted(cls, sysid: int, seq: int, time_s: float, lat_deg: float, lon_deg: float, alt_m: float,
                 value: float, position_enu_m: np.ndarray, received_s: float) -> "Reading":
        """The same reading as ``Reading(...)`` with these fields, built without the frozen
        ``__init__``'s nine ``object.__setattr__`` calls (the reading store makes one per sample)."""
        reading = object.__new__(cls)
        reading.__dict__.update(sysid=sysid, seq=seq, time_s=time_s, lat_deg=lat_deg, lon_deg=lon_deg,
                                alt_m=alt_m, value=value, position_enu_m=position_enu_m, received_s=received_s)
        return reading

    def to_json(self) -> dict:
        """A JSON-friendly dict (for the mission log)."""
        return {"sysid": self.sysid, "seq": self.seq, "time_s": self.time_s, "value": self.value,
                "position_enu_m": [round(float(x), 4) for x in self.position_enu_m]}


def sensor_key(fleet: str, sysid: int) -> str:
    """``swarmseek/<fleet>/vehicle/<sysid>/sensor``."""
    return f"swarmseek/{fleet}/vehicle/{sysid}/sensor"


def sensor_key_expr(fleet: str) -> str:
    """Key expression matching every vehicle's readings of a fleet."""
    return f"swarmseek/{fleet}/vehicle/*/sensor"


def sysid_from_key(key: str, fleet: str) -> int:
    """The sysid of a sensor key of ``fleet``.

    Parameters
    ----------
    key : str
        A zenoh key, expected ``swarmseek/<fleet>/vehicle/<sysid>/sensor``.
    fleet : str
        The mission's fleet.

    Returns
    -------
    int
        The sysid, 1 to 255.

    Raises
    ------
    ReadingRejected
        ``bad_key``: another shape, another fleet, or a sysid not in canonical decimal form.
    """
    parts = key.split("/")
    if (len(parts) != 5 or parts[0] != "swarmseek" or parts[1] != fleet or parts[2] != "vehicle"
            or parts[4] != "sensor"):
        raise ReadingRejected("bad_key", f"unexpected key {key!r}")
    chunk = parts[3]
    # the canonical decimal form only (as sensor_key writes it): no sign, leading zero,
    # whitespace, underscore or non-ASCII digit, which int() would all accept
    if not (len(chunk) <= 3 and chunk.isascii() and chunk.isdigit() and chunk == str(int(chunk))):
        raise ReadingRejected("bad_key", f"sysid {chunk[:12]!r} in key {key[:80]!r} is not a canonical "
                              "integer")
    sysid = int(chunk)
    if not 1 <= sysid <= 255:
        raise ReadingRejected("bad_key", f"sysid {sysid} in key {key!r} is out of range")
    return sysid


def decode_reading(payload: bytes | str) -> dict:
    """Decode and type-check one payload (no fleet or vehicle checks).

    Parameters
    ----------
    payload : bytes or str
        UTF-8 JSON.

    Returns
    -------
    dict
        The fields of the schema, typed (``sysid``, ``seq`` int; the rest float / str).

    Raises
    ------
    ReadingRejected
        ``malformed``, ``wrong_schema`` or ``not_finite``.
    """
    out = _fast_decode(payload)
    if out is None:
        out = _general_decode(payload)
    if not (-90.0 <= out["lat_deg"] <= 90.0 and -180.0 <= out["lon_deg"] <= 180.0):
        raise ReadingRejected("malformed", "latitude/longitude out of range")
    return out


def _general_decode(payload) -> dict:
    """:func:`json.loads` of the payload, then the schema and every field checked and converted."""
    try:
        if isinstance(payload, memoryview):
            payload = bytes(payload)
        text = payload.decode("utf-8") if isinstance(payload, (bytes, bytearray)) else payload
        doc = json.loads(text)
    except (UnicodeDecodeError, ValueError, TypeError, RecursionError) as exc:
        raise ReadingRejected("malformed", f"not UTF-8 JSON ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise ReadingRejected("malformed", f"expected a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != SCHEMA:
        raise ReadingRejected("wrong_schema", f"schema {str(doc.get('schema'))[:40]!r}, expected {SCHEMA!r}")
    out = _typical_fields(doc)
    return out if out is not None else _checked_fields(doc)


def _fast_decode(payload) -> dict | None:
    """The fields of a typical payload decoded by orjson (:func:`_orjson_loads`), else None.

    Only a document of our schema whose fields all have their exact types is taken from orjson
    (:func:`_typical_fields`): orjson reads an integer beyond 64 bits as a float where
    :func:`json.loads` keeps it an integer, so a document that needs any conversion is left to
    :func:`_general_decode`, which gives it the same result or reason as without orjson.
    """
    doc = _orjson_loads(payload)
    if doc is None or doc.get("schema") != SCHEMA:
        return None
    return _typical_fields(doc)


def _orjson_loads(payload):
    """``orjson.loads(payload)`` when orjson is installed and accepts it, else None.

    orjson is several times faster than :func:`json.loads` and returns the same value on what it
    accepts (strict UTF-8, correctly rounded floats, the last of duplicate keys; checked by
    ``tests/mission/telemetry/test_reading_fast_paths.py``), except integers beyond 64 bits, which it reads as
    floats (hence :func:`_fast_decode`'s exact-type rule). What it refuses (NaN and Infinity
    literals, lone surrogates, numbers beyond the float range, bad input) goes to
    :func:`json.loads` as before.
    """
    if orjson is None:
        return None
    try:
        doc = orjson.loads(payload)
    except (ValueError, TypeError):   # orjson.JSONDecodeError is a ValueError
        return None
    return doc if isinstance(doc, dict) else None   # anything else: for the general path


def _typical_fields(doc: dict) -> dict | None:
    """The schema's fields of ``doc`` when each already has its exact type (str, int, finite
    float), as every well-behaved sender writes them; None otherwise (:func:`_checked_fields`
    then converts or names the first bad field). Same result as :func:`_checked_fields`."""
    try:
        schema, fleet, sysid, seq = doc["schema"], doc["fleet"], doc["sysid"], doc["seq"]
        time_s, lat, lon, alt, value = doc["time_s"], doc["lat_deg"], doc["lon_deg"], doc["alt_m"], doc["value"]
    except KeyError:
        return None
    if (type(fleet) is str and type(sysid) is int and type(seq) is int and type(time_s) is float
            and type(lat) is float and type(lon) is float and type(alt) is float and type(value) is float
            and isfinite(time_s) and isfinite(lat) and isfinite(lon) and isfinite(alt) and isfinite(value)):
        return {"schema": schema, "fleet": fleet, "sysid": sysid, "seq": seq, "time_s": time_s,
                "lat_deg": lat, "lon_deg": lon, "alt_m": alt, "value": value}
    return None


def _checked_fields(doc: dict) -> dict:
    """The schema's fields of ``doc``, converted to their types (``ReadingRejected`` on the first bad one)."""
    out: dict = {}
    for name, kind in _FIELDS.items():
        if name not in doc:
            raise ReadingRejected("malformed", f"field {name!r} missing")
        v = doc[name]
        if kind is str:
            if not isinstance(v, str):
                raise ReadingRejected("malformed", f"field {name!r} must be a string")
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            # json.loads turns NaN / Infinity literals into floats; strings are malformed
            raise ReadingRejected("malformed", f"field {name!r} must be a number")
        elif kind is int:
            if not isinstance(v, int):
                if isinstance(v, float) and math.isfinite(v) and v.is_integer():
                    v = int(v)
                else:
                    raise ReadingRejected("malformed", f"field {name!r} must be an integer")
        else:
            try:
                v = float(v)
            except OverflowError:  # a JSON integer beyond the float range (> ~1.8e308)
                raise ReadingRejected("not_finite", f"field {name!r} is too large for a float") from None
            if not math.isfinite(v):
                raise ReadingRejected("not_finite", f"field {name!r} is {v}")
        out[name] = v
    return out
