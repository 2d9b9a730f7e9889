"""Readings: decoding, every rejection reason counted, time alignment, zenoh subscription."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.geodesy import enu_to_geodetic
from mission.telemetry.reading_format import (
    REJECT_REASONS,
    SCHEMA,
    ReadingRejected,
    decode_reading,
    sensor_key,
)
from mission.telemetry.readings import ReadingStore

ORIGIN = (45.19, 5.72, 230.0)
FLEET = "demo"


class _Clock:
    def __init__(self, t=1_763_717_000.0):
        self.t = t
        self.speedup = 1.0

    def time(self):
        return self.t


def _payload(sysid=3, seq=1, t=1_763_717_000.0, enu=(1.0, 2.0, 10.0), value=0.5, **over) -> dict:
    lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), ORIGIN)
    d = {"schema": SCHEMA, "fleet": FLEET, "sysid": sysid, "seq": seq, "time_s": t,
         "lat_deg": float(lat), "lon_deg": float(lon), "alt_m": float(alt), "value": value}
    d.update(over)
    return d


def _enc(d) -> bytes:
    return json.dumps(d).encode()


@pytest.fixture()
def clock():
    return _Clock()


@pytest.fixture()
def store(clock):
    telemetry = {3: np.array([1.0, 2.0, 10.0]), 4: np.array([0.0, 0.0, 10.0])}
    return ReadingStore(FLEET, [3, 4], ORIGIN, clock, telemetry_position=telemetry.get,
                        max_age_s=2.0, max_position_error_m=5.0)


def test_accepts_a_good_reading_with_its_enu_position(store):
    r = store.offer(sensor_key(FLEET, 3), _enc(_payload()))
    assert r is not None
    assert np.allclose(r.position_enu_m, [1.0, 2.0, 10.0], atol=1e-6)
    assert store.counts() == {"accepted": 1, "rejected": {k: 0 for k in REJECT_REASONS}}


@pytest.mark.parametrize("key, payload, reason", [
    (sensor_key(FLEET, 3), b"{not json", "malformed"),
    (sensor_key(FLEET, 3), b"\xff\xfe\x00", "malformed"),
    (sensor_key(FLEET, 3), b"[1, 2, 3]", "malformed"),
    (sensor_key(FLEET, 3), _enc({k: v for k, v in _payload().items() if k != "value"}), "malformed"),
    (sensor_key(FLEET, 3), _enc(_payload(value="high")), "malformed"),
    (sensor_key(FLEET, 3), _enc(_payload(seq=1.5)), "malformed"),
    (sensor_key(FLEET, 3), _enc(_payload(lat_deg=91.0)), "malformed"),
    (sensor_key(FLEET, 3), _enc(_payload(schema="swarmseek.sensor.v0")), "wrong_schema"),
    (sensor_key(FLEET, 3), _enc(_payload(fleet="other")), "wrong_fleet"),
    ("swarmseek/other/vehicle/3/sensor", _enc(_payload()), "bad_key"),
    ("swarmseek/demo/vehicle/x/sensor", _enc(_payload()), "bad_key"),
    (sensor_key(FLEET, 9), _enc(_payload(sysid=9)), "unknown_vehicle"),
    (sensor_key(FLEET, 4), _enc(_payload(sysid=3)), "sysid_mismatch"),
    (sensor_key(FLEET, 3), b'{"schema": "swarmseek.sensor.v1", "fleet": "demo", "sysid": 3, "seq": 1, '
                           b'"time_s": 1763717000.0, "lat_deg": 45.19, "lon_deg": 5.72, "alt_m": 230.0, '
                           b'"value": NaN}', "not_finite"),
    (sensor_key(FLEET, 3), _enc(_payload(value=math.inf)), "not_finite"),
    (sensor_key(FLEET, 3), _enc(_payload(t=1_763_717_000.0 - 10.0)), "late"),
    (sensor_key(FLEET, 3), _enc(_payload(t=1_763_717_000.0 + 10.0)), "late"),
    (sensor_key(FLEET, 3), _enc(_payload(enu=(30.0, 2.0, 10.0))), "position_far"),
])
def test_each_bad_reading_is_rejected_and_counted_by_reason(store, key, payload, reason):
    assert store.offer(key, payload) is None
    counts = store.counts()
    assert counts["accepted"] == 0
    assert counts["rejected"][reason] == 1
    assert sum(counts["rejected"].values()) == 1
    assert reason in store.last_errors()


def test_duplicate_and_old_sequence_numbers(store, clock):
    key = sensor_key(FLEET, 3)
    assert store.offer(key, _enc(_payload(seq=5))) is not None
    assert store.offer(key, _enc(_payload(seq=5, t=clock.t + 0.1))) is None
    assert store.offer(key, _enc(_payload(seq=4, t=clock.t + 0.1))) is None
    assert store.offer(key, _enc(_payload(seq=6, t=clock.t + 0.1))) is not None
    rejected = store.counts()["rejected"]
    assert (rejected["duplicate"], rejected["old_seq"]) == (1, 1)


def test_a_sender_restart_is_accepted_after_a_pause(clock):
    s = ReadingStore(FLEET, [3], ORIGIN, clock, max_age_s=60.0, seq_reset_after_s=5.0)
    key = sensor_key(FLEET, 3)
    assert s.offer(key, _enc(_payload(seq=100))) is not None
    clock.t += 10.0
    assert s.offer(key, _enc(_payload(seq=0, t=clock.t))) is not None
    assert s.latest(3).seq == 0


def test_removed_vehicle_becomes_unknown(store):
    store.remove_vehicle(4)
    assert store.offer(sensor_key(FLEET, 4), _enc(_payload(sysid=4, enu=(0, 0, 10)))) is None
    assert store.counts()["rejected"]["unknown_vehicle"] == 1
    assert store.sysids == [3]


def test_alignment_picks_the_nearest_reading_within_the_window(clock):
    s = ReadingStore(FLEET, [3, 4, 5], ORIGIN, clock, max_age_s=100.0)
    t0 = clock.t
    for seq, dt in enumerate([-1.0, -0.2, 0.05, 0.6]):
        assert s.offer(sensor_key(FLEET, 3), _enc(_payload(3, seq, t0 + dt, value=dt))) is not None
    assert s.offer(sensor_key(FLEET, 4), _enc(_payload(4, 0, t0 - 0.9, value=1.0))) is not None
    got = s.aligned(t0, window_s=0.5)
    assert set(got) == {3}
    assert got[3].value == pytest.approx(0.05)
    assert set(s.aligned(t0, window_s=1.0)) == {3, 4}
    assert s.aligned(t0 + 0.5, window_s=0.2)[3].value == pytest.approx(0.6)
    assert set(s.aligned(t0, window_s=1.0, sysids=[4, 5])) == {4}


def test_out_of_order_arrivals_are_kept_in_time_order(clock):
    s = ReadingStore(FLEET, [3], ORIGIN, clock, max_age_s=100.0)
    key = sensor_key(FLEET, 3)
    # a later seq taken earlier (sender clock jitter) is still stored in time order
    s.offer(key, _enc(_payload(seq=1, t=clock.t)))
    s.offer(key, _enc(_payload(seq=2, t=clock.t - 0.5)))
    times = [r.time_s for r in s.history(3)]
    assert times == sorted(times) and len(times) == 2


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.binary(max_size=300), st.text(max_size=300).map(str.encode),
                 st.dictionaries(st.sampled_from(list(_payload()) + ["x"]),
                                 st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                                           st.text(max_size=5)), max_size=12).map(_enc)))
def test_fuzzed_payloads_never_crash_and_are_counted(payload):
    store = ReadingStore(FLEET, [3], ORIGIN, _Clock(), max_age_s=2.0)
    result = store.offer(sensor_key(FLEET, 3), payload)
    counts = store.counts()
    assert counts["accepted"] + sum(counts["rejected"].values()) == 1
    assert (result is None) == (counts["accepted"] == 0)


def test_decode_reading_types():
    d = decode_reading(_enc(_payload(seq=7.0)))
    assert isinstance(d["seq"], int) and d["seq"] == 7
    with pytest.raises(ReadingRejected, match="wrong_schema"):
        decode_reading(_enc(_payload(schema=None)))


def test_zenoh_subscriber_feeds_the_store():
    """Real zenoh session pair on free loopback ports; publish until the subscriber matches."""
    import zenoh

    from mission.sim.embedded import free_port_block
    from mission.telemetry.readings import ReadingSubscriber

    port = free_port_block(1, kinds=("tcp",))

    def conf(listen=(), connect=()):
        c = zenoh.Config()
        c.insert_json5("scouting/multicast/enabled", "false")
        c.insert_json5("listen/endpoints", json.dumps(list(listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(connect)))
        return c

    pub_session = zenoh.open(conf(listen=[f"tcp/127.0.0.1:{port}"]))
    sub_session = zenoh.open(conf(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        clock = _Clock(time.time())
        store = ReadingStore(FLEET, [3], ORIGIN, clock, max_age_s=600.0)
        sub = ReadingSubscriber(sub_session, store)
        pub = pub_session.declare_publisher(sensor_key(FLEET, 3),
                                            congestion_control=zenoh.CongestionControl.BLOCK)
        pub_bad = pub_session.declare_publisher(sensor_key(FLEET, 9))
        deadline = time.monotonic() + 30.0
        seq = 0
        while store.counts()["accepted"] < 3 and time.monotonic() < deadline:
            seq += 1
            pub.put(_enc(_payload(seq=seq, t=clock.t)))
            pub_bad.put(b"garbage")
            time.sleep(0.05)  # publishing pace, not a wait for a condition
        assert store.counts()["accepted"] >= 3
        assert store.counts()["rejected"]["unknown_vehicle"] + store.counts()["rejected"]["malformed"] >= 1
        assert store.latest(3).seq <= seq
        sub.close()
    finally:
        sub_session.close()
        pub_session.close()
