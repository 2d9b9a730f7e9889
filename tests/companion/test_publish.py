"""The real sensor's publisher (companion.publisher.Publisher) and its line input, against the
mock autopilot and the ground station's own reading store on a real zenoh session."""
from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from companion.autopilot import AutopilotError
from companion.line_input import LineSplitter, parse_reading_line
from companion.publisher import Publisher, PublisherError
from formation.geodesy import geodetic_to_enu
from mission.telemetry.reading_format import decode_reading, sensor_key
from tests.companion.publish_support import HOME_ENU, ORIGIN, NoFixAutopilot, free_tcp_port, ground_station, mock_autopilot
from tests.support.wait_helpers import wait_until

TIMEOUT_S = 60.0


@pytest.mark.parametrize("line, expected", [
    (b"1.5", (1.5, None)), (b"  -2e-3\r", (-0.002, None)), ("42", (42.0, None)), (b"", (None, "empty")),
    (b" \t\r", (None, "empty")), (b"abc", (None, "not_a_number")), (b"1.5 ppm", (None, "not_a_number")),
    (b"\xff\xfe", (None, "not_a_number")), (b"nan", (None, "not_finite")), (b"-inf", (None, "not_finite")),
    (b"1e999", (None, "not_finite")),
])
def test_a_line_is_one_finite_number_or_a_reason(line, expected):
    assert parse_reading_line(line) == expected


def test_lines_are_cut_across_chunks_and_a_runaway_line_is_dropped_once():
    splitter = LineSplitter(max_bytes=8)
    assert splitter.feed(b"1.5\r\n2") == [b"1.5\r"]
    assert splitter.feed(b".5\n\n") == [b"2.5", b""]
    assert splitter.feed(b"x" * 9) == [None]          # too long: told once ...
    assert splitter.feed(b"y" * 20 + b"zz\n3\n") == [b"3"]  # ... and its tail up to the newline dropped
    assert splitter.feed(b"4") == []
    assert splitter.finish() == [b"4"]                # the last line without a newline, at the end


def test_readings_reach_the_ground_station_with_the_autopilots_position():
    with mock_autopilot("pub") as (_fleet, mavlink), ground_station("pub") as (store, endpoint, _payloads):
        with Publisher("pub", mavlink=mavlink, zenoh_connect=[endpoint], heartbeat_timeout_s=TIMEOUT_S) as pub:
            assert pub.sysid == 1 and pub.key == sensor_key("pub", 1)
            assert pub.wait_for_subscriber(TIMEOUT_S)
            wait_until(pub.telemetry.latest, TIMEOUT_S, "the autopilot's first position fix")
            t_before = time.time()
            sent = [0.25, 3, np.float32(1.5), 7.0]
            assert all(pub.put(v) for v in sent)
            bad = [math.nan, math.inf, "3.0", None, True, [1.0]]
            assert [pub.put(v) for v in bad] == [False] * len(bad)
            assert pub.put(1.0, time_s=math.nan) is False
            assert pub.last_problem == "time_s is not a finite number: 'nan'"
            wait_until(lambda: len(store.history(1)) == len(sent), TIMEOUT_S, "the readings at the ground station")
            assert pub.counts == {"published": 4, "bad_value": 7, "no_position": 0, "stale_position": 0}
            assert "published 4; held 0" in pub.summary() and "bad values 7" in pub.summary()
    readings = store.history(1)
    assert store.counts()["rejected"] == dict.fromkeys(store.counts()["rejected"], 0)
    assert [r.seq for r in readings] == [0, 1, 2, 3]
    assert [r.value for r in readings] == [0.25, 3.0, 1.5, 7.0]
    for r in readings:
        assert t_before <= r.time_s <= time.time()
        np.testing.assert_allclose(geodetic_to_enu(r.lat_deg, r.lon_deg, r.alt_m, ORIGIN), HOME_ENU, atol=0.05)


def test_the_payload_is_the_ground_stations_schema_with_exact_types():
    """The payload on the wire is the schema of docs/interfaces.md, with its exact JSON types
    (ints stay ints, every float a float), and the ground station decodes it unchanged."""
    with mock_autopilot("pub") as (_fleet, mavlink), ground_station("pub") as (store, endpoint, payloads):
        with Publisher("pub", 1, mavlink=mavlink, zenoh_connect=[endpoint], heartbeat_timeout_s=TIMEOUT_S) as pub:
            assert pub.wait_for_subscriber(TIMEOUT_S)
            wait_until(pub.telemetry.latest, TIMEOUT_S, "the autopilot's first position fix")
            assert pub.put(5)
            wait_until(lambda: payloads, TIMEOUT_S, "the payload")
    ((key, payload),) = payloads
    doc = json.loads(payload)
    assert key == "swarmseek/pub/vehicle/1/sensor"
    assert list(doc) == ["schema", "fleet", "sysid", "seq", "time_s", "lat_deg", "lon_deg", "alt_m", "value"]
    assert (doc["schema"], doc["fleet"], doc["sysid"], doc["seq"], doc["value"]) == (
        "swarmseek.sensor.v1", "pub", 1, 0, 5.0)
    assert [type(doc[k]).__name__ for k in ("sysid", "seq", "time_s", "value")] == ["int", "int", "float", "float"]
    assert decode_reading(payload) == doc


def test_a_silent_autopilot_holds_readings_as_stale():
    with mock_autopilot("pub") as (fleet, mavlink), ground_station("pub") as (store, endpoint, _payloads):
        pub = Publisher("pub", mavlink=mavlink, zenoh_connect=[endpoint], max_fix_age_s=0.3,
                        heartbeat_timeout_s=TIMEOUT_S)
        with pub:
            wait_until(pub.telemetry.latest, TIMEOUT_S, "the autopilot's first position fix")
            fleet.stop()  # the autopilot falls silent
            wait_until(lambda: time.monotonic() - pub.telemetry.latest().received_s > 0.3, TIMEOUT_S,
                       "the last fix to grow old")
            assert pub.put(1.0) is False
            assert pub.counts["stale_position"] == 1 and pub.counts["published"] == 0
            assert pub.last_problem.startswith("latest position fix ")
            assert pub.last_reason == "stale_position"
        with pytest.raises(RuntimeError, match="closed"):
            pub.put(1.0)


def test_before_the_first_fix_readings_are_held_and_counted():
    told = []
    with NoFixAutopilot(sysid=5) as autopilot, ground_station("pub", sysids=(5,)) as (store, endpoint, _payloads):
        with Publisher("pub", 5, mavlink=autopilot.connection, zenoh_connect=[endpoint], log=told.append,
                       heartbeat_timeout_s=TIMEOUT_S) as pub:
            wait_until(lambda: pub.telemetry.stream.no_fix > 0, TIMEOUT_S, "a position without a fix")
            assert [pub.put(v) for v in (1.0, 2.0)] == [False, False]
            assert pub.counts["no_position"] == 2 and pub.counts["published"] == 0
            assert pub.last_problem == "no position fix from the autopilot yet"
            assert pub.last_reason == "no_position"
            assert "held 2 (no position yet 2, stale position 0)" in pub.summary()
    assert "autopilot has no position fix yet (lat = lon = 0); waiting" in told
    assert store.history(5) == []


def test_bad_arguments_and_unreachable_peers_are_clear_errors():
    with pytest.raises(ValueError, match="sysid must be an integer in 1..255"):
        Publisher("pub", 256, mavlink="tcp:127.0.0.1:1")
    with pytest.raises(ValueError, match="fleet"):
        Publisher("a/b", 1, mavlink="tcp:127.0.0.1:1")
    port = free_tcp_port()  # nobody listens there
    with pytest.raises(AutopilotError, match="cannot open MAVLink connection"):
        Publisher("pub", 1, mavlink=f"tcp:127.0.0.1:{port}", zenoh_connect=["tcp/127.0.0.1:7447"], retries=1)
    with NoFixAutopilot() as autopilot:
        with pytest.raises(AutopilotError, match="no heartbeat from autopilot sysid 9 within 1 s"):
            Publisher("pub", 9, mavlink=autopilot.connection, zenoh_connect=["tcp/127.0.0.1:7447"],
                      heartbeat_timeout_s=1.0)
        with pytest.raises(PublisherError, match="bad zenoh settings"):
            Publisher("pub", 5, mavlink=autopilot.connection, heartbeat_timeout_s=TIMEOUT_S)  # no endpoint
