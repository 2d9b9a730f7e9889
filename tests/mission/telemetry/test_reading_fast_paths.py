"""The reading store's fast paths give exactly what the general code gives.

* ``decode_reading``'s typical-payload path (every field already of its exact type) returns the
  same dict, with the same types, as the general field check, and leaves every other payload to it;
* :meth:`Reading.accepted` builds the same frozen reading as ``Reading(...)``;
* orjson (the optional JSON accelerator) reads what it accepts exactly as :func:`json.loads` does,
  and ``decode_reading`` gives every payload the same result or rejection reason with or without it.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from mission.telemetry import reading_format
from mission.telemetry.reading_format import SCHEMA, Reading, ReadingRejected, _checked_fields, _typical_fields

_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10), st.integers(),
                    st.booleans(), st.none(), st.text(max_size=5), st.just(10 ** 400),
                    st.lists(st.integers(), max_size=2))
_NAMES = ("schema", "fleet", "sysid", "seq", "time_s", "lat_deg", "lon_deg", "alt_m", "value")


@st.composite
def _docs(draw):
    doc = {"schema": SCHEMA, "fleet": "f", "sysid": 3, "seq": 1, "time_s": 1.5, "lat_deg": 45.0,
           "lon_deg": 5.0, "alt_m": 230.0, "value": 0.25}
    for name in draw(st.lists(st.sampled_from(_NAMES[1:]), max_size=4, unique=True)):
        if draw(st.integers(0, 5)) == 0:
            del doc[name]
        else:
            doc[name] = draw(_VALUES)
    return doc


def _checked(doc):
    try:
        return _checked_fields(doc)
    except ReadingRejected as exc:
        return exc.reason


@settings(max_examples=1000, deadline=None)
@given(_docs())
def test_typical_payload_path_agrees_with_the_general_check(doc):
    fast = _typical_fields(doc)
    if fast is None:
        return
    slow = _checked(doc)
    assert isinstance(slow, dict)
    assert list(fast.items()) == list(slow.items())
    assert [type(v) for v in fast.values()] == [type(v) for v in slow.values()]


def test_typical_payload_path_takes_exact_types_only():
    doc = {"schema": SCHEMA, "fleet": "f", "sysid": 3, "seq": 1, "time_s": 1.5, "lat_deg": 45.0,
           "lon_deg": 5.0, "alt_m": 230.0, "value": 0.25}
    assert _typical_fields(doc) == doc
    for name, value in (("alt_m", 230), ("sysid", True), ("seq", 1.0), ("value", math.nan), ("time_s", math.inf)):
        assert _typical_fields({**doc, name: value}) is None, name
    assert _typical_fields({k: v for k, v in doc.items() if k != "value"}) is None


def test_accepted_builds_the_same_frozen_reading():
    pos = np.array([1.0, 2.0, 3.0])
    fields = dict(sysid=3, seq=7, time_s=1.5, lat_deg=45.0, lon_deg=5.0, alt_m=230.0, value=0.25,
                  position_enu_m=pos, received_s=2.0)
    fast, slow = Reading.accepted(**fields), Reading(**fields)
    assert type(fast) is Reading and fast == slow and repr(fast) == repr(slow)
    assert list(vars(fast).items()) == list(vars(slow).items())
    assert dataclasses.asdict(fast).keys() == dataclasses.asdict(slow).keys()
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.seq = 8


# ---------------------------------------------------------------------- orjson against json
import orjson  # noqa: E402 - a dependency (pyproject.toml): a missing one must fail, not skip
_DIGITS = "0123456789"
#: a JSON number, ``-?(0|[1-9][0-9]{0,24})(\.[0-9]{1,24})?([eE][+-]?[0-9]{1,3})?``, built from its parts
#: (st.from_regex of that pattern draws the same language about 5 times slower: 14 s of CI for 2000 numbers)
_NUMBER = st.builds(
    lambda *parts: "".join(parts),
    st.sampled_from(["", "-"]),
    st.one_of(st.just("0"), st.builds(str.__add__, st.sampled_from("123456789"), st.text(_DIGITS, max_size=24))),
    st.one_of(st.just(""), st.text(_DIGITS, min_size=1, max_size=24).map("." .__add__)),
    st.one_of(st.just(""), st.builds(lambda e, sign, digits: e + sign + digits, st.sampled_from("eE"),
                                     st.sampled_from(["", "+", "-"]), st.text(_DIGITS, min_size=1, max_size=3))))
_JSON_VALUES = st.recursive(
    # integers within 64 bits: beyond, orjson reads floats (test_orjson_reads_every_json_number...)
    st.one_of(st.none(), st.booleans(), st.integers(-(1 << 63), (1 << 64) - 1), st.floats(allow_nan=True),
              st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=4), inner, max_size=3)),
    max_leaves=12)


def _typed(value) -> str:
    """A text image with the types (1 and 1.0 and True differ), NaN-safe."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k!r}:{_typed(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ",".join(_typed(v) for v in value) + "]"
    return f"{type(value).__name__}:{value!r}"


def _both(text: str):
    try:
        fast = orjson.loads(text.encode("utf-8", "surrogatepass"))
    except (ValueError, TypeError):
        fast = None
    return fast, json.loads(text)


# the branches' edges every run, not by chance: 64-bit integer limits and one past them (orjson's
# float), beyond the float range (refused), below it (0.0), signed zeros
@example("18446744073709551615")
@example("18446744073709551616")
@example("-9223372036854775808")
@example("-9223372036854775809")
@example("123456789012345678901234567890")
@example("1e999")
@example("-1E+400")
@example("1.7976931348623157e308")
@example("4.9e-325")
@example("-0")
@example("-0.0")
@example("0e999")
@settings(max_examples=1000, deadline=None)
@given(_NUMBER)
def test_orjson_reads_every_json_number_as_json_does(number):
    fast, slow = _both('{"v": %s}' % number)
    if fast is None:   # refused (e.g. beyond the float range): json decides
        return
    fast, slow = fast["v"], slow["v"]
    if isinstance(slow, int) and isinstance(fast, float):
        # an integer beyond 64 bits: orjson's float is the correctly rounded one that a float
        # field gets from json (float(int)); an integer field is never taken from orjson
        assert abs(slow) >= 1 << 63 and fast == float(slow)
    else:
        assert _typed(fast) == _typed(slow)


@settings(max_examples=500, deadline=None)
@given(_JSON_VALUES, st.booleans())
def test_orjson_reads_any_document_as_json_does(value, spaced):
    text = json.dumps({"schema": SCHEMA, "x": value}, indent=1 if spaced else None, ensure_ascii=spaced)
    fast, slow = _both(text)
    if fast is not None:
        assert _typed(fast) == _typed(slow)


def _decoded(payload, use_orjson: bool):
    saved = reading_format.orjson
    reading_format.orjson = reading_format.orjson if use_orjson else None
    try:
        return _typed(reading_format.decode_reading(payload))
    except ReadingRejected as exc:
        return exc.reason
    finally:
        reading_format.orjson = saved


_GOOD = json.dumps({"schema": SCHEMA, "fleet": "f", "sysid": 3, "seq": 1, "time_s": 1.5, "lat_deg": 45.0,
                    "lon_deg": 5.0, "alt_m": 230.0, "value": 0.25}).encode()


@settings(max_examples=1000, deadline=None)
@given(st.one_of(
    st.binary(max_size=60),
    st.builds(lambda cut, junk: _GOOD[:cut] + junk + _GOOD[cut:], st.integers(0, len(_GOOD)), st.binary(max_size=6)),
    st.sampled_from([_GOOD, b"\xef\xbb\xbf" + _GOOD, _GOOD.replace(b"0.25", b"NaN"), _GOOD.replace(b"0.25", b"1e999"),
                     _GOOD.replace(b'"f"', b'"\\ud800"'), _GOOD.replace(b"230.0", b"230"),
                     _GOOD.replace(b"1,", b"18446744073709551617,"), _GOOD.replace(b"230.0", b"20000000000000000001"),
                     b"[1, 2]", b'"x"', b" " + _GOOD + b"\n"])))
def test_decode_reading_gives_the_same_result_or_reason_with_and_without_orjson(payload):
    for form in (payload, bytearray(payload), memoryview(payload), payload.decode("utf-8", "replace")):
        assert _decoded(form, True) == _decoded(form, False)
