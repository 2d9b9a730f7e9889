"""Fuzzing the coordinator's zenoh sensor-payload decoding: nothing escapes, every payload is
accepted or counted under one reason, accepted readings are sane.

Entry point: ``mission.telemetry.readings.ReadingStore.offer(key, payload)`` (what the zenoh callback
``ReadingSubscriber._on_sample`` calls with every sample), and ``decode_reading(payload)`` under
it. The mock has no zenoh input path (it only publishes), so its side is covered by a round trip:
whatever ``companion.sensor_wire.encode_reading`` can produce, the coordinator must accept. The
socket-level test publishes garbage through a real zenoh session pair.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.support.fuzz_helpers import FakeClock
from formation.geodesy import enu_to_geodetic
from mission.sim.embedded import free_port_block
from mission.telemetry.reading_format import (
    REJECT_REASONS,
    SCHEMA,
    Reading,
    ReadingRejected,
    decode_reading,
    sensor_key,
)
from mission.telemetry.readings import ReadingStore, ReadingSubscriber
from companion.sensor_wire import encode_reading
from tests.support.wait_helpers import wait_until

FLEET = "demo"
ORIGIN = (45.19, 5.72, 230.0)
T0_S = 1_763_717_000.0
MAX_AGE_S = 5.0
_SETTINGS = settings(max_examples=100, deadline=2000,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_FLOAT_FIELDS = ("time_s", "lat_deg", "lon_deg", "alt_m", "value")
_INT_FIELDS = ("sysid", "seq")


def _store(telemetry: bool = True) -> ReadingStore:
    tel = {3: np.array([1.0, 2.0, 10.0]), 4: np.array([-3.0, 0.0, 12.0])}
    return ReadingStore(FLEET, [3, 4], ORIGIN, FakeClock(T0_S), max_age_s=MAX_AGE_S,
                        telemetry_position=tel.get if telemetry else None, max_position_error_m=10.0)


def _doc(sysid: int = 3, seq: int = 1, dt_s: float = 0.0, enu=(1.0, 2.0, 10.0), value: float = 0.5) -> dict:
    lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), ORIGIN)
    return {"schema": SCHEMA, "fleet": FLEET, "sysid": sysid, "seq": seq, "time_s": T0_S + dt_s,
            "lat_deg": float(lat), "lon_deg": float(lon), "alt_m": float(alt), "value": value}


# ------------------------------------------------------------------------------ strategies
_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12)
#: numbers a float field may hold in JSON (integers beyond the float range included)
_numbers = st.one_of(st.floats(), st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324]),
                     st.integers(-(10 ** 400), 10 ** 400), st.integers(-(1 << 64), 1 << 64))
_wrong_types = st.one_of(st.none(), st.booleans(), st.text(max_size=30), st.lists(st.integers(), max_size=3),
                         st.dictionaries(st.text(max_size=4), st.integers(), max_size=3),
                         st.text(min_size=5000, max_size=20000, alphabet="aé\u202e\U0001F600\x00"))


@st.composite
def _near_valid_doc(draw) -> dict:
    """A valid reading with a few fields broken: missing, extra, mistyped, non-finite, huge."""
    doc = _doc(draw(st.sampled_from([3, 4, 9])), draw(st.integers(-3, 5)), draw(st.floats(-8.0, 8.0)),
               (draw(st.floats(-30, 30)), draw(st.floats(-30, 30)), draw(st.floats(-5, 40))),
               draw(st.floats(-1e3, 1e3)))
    for _ in range(draw(st.integers(0, 3))):
        name = draw(st.sampled_from(sorted(doc) + ["extra", "\u00e9t\u00e9", ""]))
        action = draw(st.sampled_from(["drop", "number", "wrong_type", "json", "huge_int"]))
        if action == "drop":
            doc.pop(name, None)
        elif action == "number":
            doc[name] = draw(_numbers)
        elif action == "wrong_type":
            doc[name] = draw(_wrong_types)
        elif action == "json":
            doc[name] = draw(_json)
        else:
            doc[name] = draw(st.integers(-(10 ** 1000), 10 ** 1000))
    return doc


def _encoded(doc_strategy):
    return st.builds(lambda d, compact: json.dumps(d, separators=(",", ":") if compact else None).encode(),
                     doc_strategy, st.booleans())


_raw_payloads = st.one_of(
    st.binary(max_size=200),
    st.text(max_size=200).map(str.encode),
    _json.map(lambda v: json.dumps(v).encode()),
    st.integers(1, 50_000).map(lambda n: b"[" * n + b"]" * n),           # deep nesting
    st.integers(1, 50_000).map(lambda n: b'{"a":' * n + b"1" + b"}" * n),
    st.just("9" * 5000).map(str.encode),                                  # over the int-digits limit
    _encoded(_near_valid_doc()).map(lambda b: b[:len(b) // 2]),           # truncated JSON
    _encoded(_near_valid_doc()).map(lambda b: b"\xef\xbb\xbf" + b),       # UTF-8 BOM
    _near_valid_doc().map(lambda d: json.dumps(d).encode("utf-16")),
)
_payloads = st.one_of(_encoded(_near_valid_doc()), _encoded(_near_valid_doc()), _raw_payloads)
_keys = st.one_of(
    st.sampled_from([sensor_key(FLEET, 3), sensor_key(FLEET, 4)]),
    st.sampled_from([sensor_key(FLEET, 9), sensor_key("other", 3), "swarmseek/demo/vehicle/\u0663/sensor",
                     "swarmseek/demo/vehicle/03/sensor", "swarmseek/demo/vehicle/+3/sensor",
                     "swarmseek/demo/vehicle/ 4/sensor", "swarmseek/demo/vehicle/3", "", "/" * 9,
                     "swarmseek/demo/vehicle/99999999999999999999/sensor"]),
    st.text(max_size=60))


# ------------------------------------------------------------------------------ properties
@_SETTINGS
@given(st.lists(st.tuples(_keys, _payloads), min_size=1, max_size=12), st.booleans())
def test_every_payload_is_accepted_or_counted_under_one_reason(offers, telemetry):
    store = _store(telemetry)
    for n, (key, payload) in enumerate(offers, start=1):
        before = store.counts()
        result = store.offer(key, payload)
        after = store.counts()
        assert after["accepted"] + sum(after["rejected"].values()) == n
        assert (result is not None) == (after["accepted"] == before["accepted"] + 1)
        if result is not None:
            assert isinstance(result, Reading) and result.sysid in (3, 4)
            assert all(math.isfinite(v) for v in (result.time_s, result.value, result.lat_deg, result.lon_deg,
                                                   result.alt_m))
            assert np.all(np.isfinite(result.position_enu_m))
            assert abs(result.time_s - T0_S) <= MAX_AGE_S
            if telemetry:
                assert np.linalg.norm(result.position_enu_m - store.telemetry_position(result.sysid)) <= 10.0
    assert set(store.counts()["rejected"]) == set(REJECT_REASONS)


@_SETTINGS
@given(_payloads)
def test_decode_reading_returns_typed_fields_or_raises_a_reason(payload):
    try:
        doc = decode_reading(payload)
    except ReadingRejected as exc:
        assert exc.reason in REJECT_REASONS
        assert str(exc).startswith(exc.reason)
        return
    assert set(doc) == {"schema", "fleet", "sysid", "seq", "time_s", "lat_deg", "lon_deg", "alt_m", "value"}
    assert all(type(doc[k]) is int for k in _INT_FIELDS)
    assert all(type(doc[k]) is float and math.isfinite(doc[k]) for k in _FLOAT_FIELDS)


@_SETTINGS
@given(st.sampled_from([3, 4]), st.integers(0, 2 ** 53), st.floats(-MAX_AGE_S, MAX_AGE_S),
       st.floats(-89.9, 89.9), st.floats(-179.9, 179.9), st.floats(-1e4, 1e5),
       st.floats(allow_nan=False, allow_infinity=False))
def test_whatever_the_mock_encodes_the_coordinator_accepts(sysid, seq, dt_s, lat, lon, alt, value):
    """The mock's side of the contract: its payloads (``encode_reading``) always decode."""
    reading = {"schema": SCHEMA, "fleet": FLEET, "sysid": sysid, "seq": seq, "time_s": T0_S + dt_s,
               "lat_deg": lat, "lon_deg": lon, "alt_m": alt, "value": value}
    store = _store(telemetry=False)
    accepted = store.offer(sensor_key(FLEET, sysid), encode_reading(reading))
    assert accepted is not None, store.last_errors()
    assert (accepted.sysid, accepted.seq, accepted.time_s, accepted.value) == (sysid, seq, T0_S + dt_s, value)


@pytest.mark.parametrize("name, value, reason", [
    ("value", math.nan, "not_finite"),
    ("time_s", math.inf, "not_finite"),
    ("alt_m", -math.inf, "not_finite"),
    ("value", "0.5", "malformed"),
    ("seq", 1.5, "malformed"),
    ("sysid", True, "malformed"),
    ("lat_deg", 91.0, "malformed"),
    ("fleet", "x" * 100_000, "wrong_fleet"),
    ("schema", {"v": 1}, "wrong_schema"),
    ("time_s", T0_S - 60.0, "late"),
    ("sysid", 4, "sysid_mismatch"),
])
def test_each_broken_field_is_counted_under_its_reason(name, value, reason):
    store = _store()
    doc = _doc()
    doc[name] = value
    assert store.offer(sensor_key(FLEET, 3), json.dumps(doc).encode()) is None
    assert store.counts()["rejected"][reason] == 1
    assert store.counts()["accepted"] == 0


@pytest.mark.parametrize("name", ["value", "time_s", "alt_m"])
def test_an_integer_too_large_for_a_float_is_counted_not_raised(name):
    store = _store()
    doc = _doc()
    doc[name] = 10 ** 400
    assert store.offer(sensor_key(FLEET, 3), json.dumps(doc).encode()) is None
    assert store.counts()["rejected"]["not_finite"] + store.counts()["rejected"]["malformed"] == 1


@pytest.mark.parametrize("chunk", ["03", "\u0663", "+3", " 3", "3\n", "\uff13", "0", "003"])
def test_only_the_canonical_key_of_a_vehicle_is_accepted(chunk):
    store = _store()
    assert store.offer(f"swarmseek/{FLEET}/vehicle/{chunk}/sensor", json.dumps(_doc()).encode()) is None
    assert store.counts()["rejected"]["bad_key"] == 1


# ------------------------------------------------------------------------------ over zenoh
def _zenoh_config(listen=(), connect=()):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


def _garbage_payloads(count: int) -> list[bytes]:
    out = []
    for i in range(count):
        doc = _doc(seq=i)
        kind = i % 8
        if kind == 0:
            out.append(bytes((i * 37 + k) % 256 for k in range(i % 50 + 1)))
        elif kind == 1:
            out.append(json.dumps(doc).encode()[: i % 40])
        elif kind == 2:
            doc["value"] = math.nan
            out.append(json.dumps(doc).encode())
        elif kind == 3:
            doc.pop("time_s")
            out.append(json.dumps(doc).encode())
        elif kind == 4:
            out.append(b"[" * (1000 + i) + b"]" * (1000 + i))
        elif kind == 5:
            doc["fleet"] = "\u202e" * 3000
            out.append(json.dumps(doc).encode())
        elif kind == 6:
            out.append(json.dumps([doc]).encode())
        else:
            doc["time_s"] = "yesterday"
            out.append(json.dumps(doc).encode())
    return out


def test_garbage_published_over_zenoh_is_counted_and_a_good_reading_still_gets_in():
    import zenoh

    port = free_port_block(1, kinds=("tcp",))
    pub_session = zenoh.open(_zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]))
    sub_session = zenoh.open(_zenoh_config(connect=[f"tcp/127.0.0.1:{port}"]))
    sub = None
    try:
        store = _store(telemetry=False)
        sub = ReadingSubscriber(sub_session, store)
        keys = [sensor_key(FLEET, 3), sensor_key(FLEET, 9), "swarmseek/demo/vehicle/x3/sensor"]
        pubs = [pub_session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                for k in keys]
        for pub in pubs:
            wait_until(lambda: pub.matching_status.matching, 30.0, "the subscriber to match")
        garbage = _garbage_payloads(240)
        for i, payload in enumerate(garbage):
            pubs[i % 3].put(payload)
        pubs[0].put(json.dumps(_doc(seq=10_000)).encode())
        total = len(garbage) + 1
        wait_until(lambda: sum(store.counts()["rejected"].values()) + store.counts()["accepted"] >= total,
                   60.0, f"{total} samples counted")
        counts = store.counts()
        assert counts["accepted"] == 1 and store.latest(3).seq == 10_000
        assert sum(counts["rejected"].values()) == len(garbage)
        assert counts["rejected"]["bad_key"] == len(garbage) // 3
        assert counts["rejected"]["malformed"] > 0 and counts["rejected"]["not_finite"] > 0
        for pub in pubs:
            pub.undeclare()
    finally:
        if sub is not None:
            sub.close()
        sub_session.close()
        pub_session.close()
