"""SensorPublisher over a real zenoh link between two sessions on 127.0.0.1."""
from __future__ import annotations

import json
import queue

import numpy as np
import pytest
import zenoh

from companion.sensor_wire import SensorPublisher, sensor_key
from sitl_mock.faults import FaultSet
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.sensor import SignalSensor
from wire.zenoh_config import zenoh_config
from tests.support.wait_helpers import wait_until
from mission.sim.embedded import free_port_block

TIMEOUT_S = 30.0


def _free_tcp_port() -> int:
    return free_port_block(1, kinds=("tcp",))


@pytest.fixture
def two_sessions():
    port = _free_tcp_port()
    listener = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{port}"))
    try:
        connector = zenoh.open(zenoh_config(connect=f"tcp/127.0.0.1:{port}"))
    except BaseException:
        listener.close()
        raise
    try:
        yield listener, connector
    finally:
        connector.close()
        listener.close()


def test_subscriber_on_another_session_receives_every_reading(two_sessions):
    pub_session, sub_session = two_sessions
    received: queue.Queue = queue.Queue()
    sub = sub_session.declare_subscriber(
        "swarmseek/demo/vehicle/*/sensor",
        lambda s: received.put((str(s.key_expr), str(s.encoding), s.payload.to_bytes())))
    sensors = {sid: SignalSensor(sigma2(), 0.01, np.random.default_rng(sid), FaultSet(), "demo", sid)
               for sid in (1, 2)}
    publisher = SensorPublisher(pub_session, "demo", [1, 2])
    try:
        assert publisher.sysids == [1, 2]
        wait_until(lambda: publisher.has_subscribers(1) and publisher.has_subscribers(2), TIMEOUT_S,
                   what="the remote subscriber to match")
        sent = []
        for i in range(20):
            for sid, sensor in sensors.items():
                r = sensor.sample(1.7e9 + 0.1 * i, (float(i), 0.0, 5.0), 45.0, 5.0, 230.0)
                publisher.publish(r)
                sent.append(r)
        got = [received.get(timeout=TIMEOUT_S) for _ in sent]
        assert publisher.published == len(sent)
    finally:
        publisher.close()
        sub.undeclare()
    for key, encoding, payload in got:
        reading = json.loads(payload)
        assert key == sensor_key("demo", reading["sysid"])
        assert encoding == "application/json"
    by_sysid = {sid: [json.loads(p) for k, _, p in got if k == sensor_key("demo", sid)] for sid in (1, 2)}
    for sid in (1, 2):
        assert [r["seq"] for r in by_sysid[sid]] == list(range(20))  # reliable and in order
        assert by_sysid[sid] == [r for r in sent if r["sysid"] == sid]


def test_publisher_rejects_foreign_readings_and_bad_sysids(two_sessions):
    session, _ = two_sessions
    with pytest.raises(ValueError, match="sysid"):
        SensorPublisher(session, "demo", [0])
    with pytest.raises(ValueError, match="twice"):
        SensorPublisher(session, "demo", [1, 1])
    with SensorPublisher(session, "demo", [1]) as publisher:
        with pytest.raises(ValueError, match="no sensor publisher for sysid 7"):
            publisher.publish({"fleet": "demo", "sysid": 7, "value": 1.0})
        with pytest.raises(ValueError, match="fleet 'other'"):
            publisher.publish({"fleet": "other", "sysid": 1, "value": 1.0})
        assert publisher.published == 0
    publisher.close()  # idempotent
    assert publisher.sysids == []
