"""Simulated sensor: payload schema, noise, faults (stuck, bias, spikes, noise override)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sitl_mock.faults import FaultSet
from sitl_mock.fields_gaussian import sigma1, sigma2
from companion.sensor_wire import SENSOR_SCHEMA, encode_reading, sensor_key
from sitl_mock.sensor import SignalSensor
from wire.zenoh_config import zenoh_config

PAYLOAD_KEYS = {"schema", "fleet", "sysid", "seq", "time_s", "lat_deg", "lon_deg", "alt_m", "value"}
GEO = (45.19, 5.72, 230.0)


def _sensor(noise_std=0.0, seed=0, faults=None, field=None, sysid=3):
    return SignalSensor(field or sigma1((10.0, -5.0, 20.0)), noise_std, np.random.default_rng(seed),
                        faults or FaultSet(), "demo", sysid)


def _values(sensor, n, pos=(0.0, 0.0, 10.0)):
    return np.array([sensor.sample(1.7e9 + i, pos, *GEO)["value"] for i in range(n)])


def test_reading_has_exactly_the_documented_fields_and_round_trips_json():
    s = _sensor()
    r = s.sample(1763717000.25, (1.0, 2.0, 3.0), 45.1901, 5.7201, 230.4)
    assert set(r) == PAYLOAD_KEYS
    assert r["schema"] == SENSOR_SCHEMA == "swarmseek.sensor.v1"
    assert (r["fleet"], r["sysid"], r["seq"]) == ("demo", 3, 0)
    assert isinstance(r["sysid"], int) and isinstance(r["seq"], int)
    payload = encode_reading(r)
    decoded = json.loads(payload.decode("utf-8"))
    assert decoded == r
    assert decoded["time_s"] == 1763717000.25
    assert decoded["lat_deg"] == 45.1901 and decoded["alt_m"] == 230.4


@pytest.mark.parametrize("field", [sigma1((10.0, -5.0, 20.0)), sigma2((0.0, 0.0, 0.0))])
def test_noise_free_value_is_the_field_at_the_true_position(field):
    s = _sensor(field=field)
    pos = np.array([3.0, -4.0, 12.0])
    assert s.sample(0.0, pos, *GEO)["value"] == pytest.approx(float(field.value(pos)))


def test_seq_increases_by_one_per_reading():
    s = _sensor()
    seqs = [s.sample(float(i), (0.0, 0.0, 0.0), *GEO)["seq"] for i in range(20)]
    assert seqs == list(range(20))


@pytest.mark.parametrize("noise_std", [0.01, 0.5])
def test_noise_has_the_configured_std(noise_std):
    s = _sensor(noise_std=noise_std)
    truth = s.true_value((0.0, 0.0, 10.0))
    v = _values(s, 2000)
    assert v.mean() == pytest.approx(truth, abs=4 * noise_std / math.sqrt(2000))
    assert v.std() == pytest.approx(noise_std, rel=0.1)


def test_fault_noise_override_replaces_the_sensor_noise():
    faults = FaultSet()
    s = _sensor(noise_std=0.01, faults=faults)
    faults.set("sensor_noise_std", "2.0")
    assert _values(s, 2000).std() == pytest.approx(2.0, rel=0.1)
    faults.set("sensor_noise_std", 0.0)
    assert _values(s, 50).std() == pytest.approx(0.0, abs=1e-12)


def test_stuck_sensor_repeats_its_last_value_then_recovers():
    faults = FaultSet()
    s = _sensor(noise_std=0.3, faults=faults)
    last = s.sample(0.0, (0.0, 0.0, 0.0), *GEO)["value"]
    faults.sensor_stuck = True
    stuck = [s.sample(float(i), (5.0 * i, 0.0, 0.0), *GEO) for i in range(1, 10)]
    assert all(r["value"] == last for r in stuck)
    assert [r["seq"] for r in stuck] == list(range(1, 10))  # still a fresh reading each time
    faults.sensor_stuck = False
    assert len(set(_values(s, 10))) == 10


def test_stuck_before_any_reading_samples_once():
    s = _sensor(faults=FaultSet(sensor_stuck=True), noise_std=0.2)
    v = _values(s, 5)
    assert np.all(v == v[0])


@pytest.mark.parametrize("bias", [-3.0, 0.5])
def test_bias_is_added(bias):
    plain, biased = _sensor(noise_std=0.1, seed=4), _sensor(noise_std=0.1, seed=4, faults=FaultSet(sensor_bias=bias))
    np.testing.assert_allclose(_values(biased, 50) - _values(plain, 50), bias)


@pytest.mark.parametrize("prob", [0.1, 0.5])
def test_spikes_have_the_configured_size_rate_and_both_signs(prob):
    s = _sensor(faults=FaultSet(sensor_spike_prob=prob, sensor_spike_size=7.0))
    truth = s.true_value((0.0, 0.0, 10.0))
    dev = _values(s, 3000) - truth
    spikes = dev[np.abs(dev) > 1e-9]
    np.testing.assert_allclose(np.abs(spikes), 7.0)
    assert len(spikes) / 3000 == pytest.approx(prob, abs=0.04)
    assert (spikes > 0).any() and (spikes < 0).any()


def test_reproducible_with_a_seed():
    faults = FaultSet(sensor_spike_prob=0.2, sensor_spike_size=1.0)
    a, b, c = (_sensor(noise_std=0.3, seed=s, faults=faults) for s in (1, 1, 2))
    va, vb, vc = _values(a, 100), _values(b, 100), _values(c, 100)
    np.testing.assert_array_equal(va, vb)
    assert not np.array_equal(va, vc)


@pytest.mark.parametrize("args,match", [
    ((math.nan, (0.0, 0.0, 0.0), *GEO), "t_s"),
    ((0.0, (0.0, math.inf, 0.0), *GEO), "true_position_enu"),
    ((0.0, (0.0, 0.0), *GEO), "true_position_enu"),
    ((0.0, (0.0, 0.0, 0.0), math.nan, 5.0, 1.0), "lat_deg"),
])
def test_sample_rejects_bad_input(args, match):
    s = _sensor()
    with pytest.raises(ValueError, match=match):
        s.sample(*args)
    assert s.seq == 0


@pytest.mark.parametrize("kw,match", [
    ({"noise_std": -1.0}, "noise_std"),
    ({"sysid": 0}, "sysid"),
    ({"sysid": 256}, "sysid"),
])
def test_sensor_rejects_bad_construction(kw, match):
    with pytest.raises(ValueError, match=match):
        _sensor(**kw)


def test_encode_rejects_non_finite_values():
    with pytest.raises(ValueError, match="non-finite"):
        encode_reading({"value": math.nan})


@pytest.mark.parametrize("fleet,sysid,key", [("demo", 3, "swarmseek/demo/vehicle/3/sensor"),
                                             ("field-team_2", 255, "swarmseek/field-team_2/vehicle/255/sensor")])
def test_sensor_key(fleet, sysid, key):
    assert sensor_key(fleet, sysid) == key


@pytest.mark.parametrize("fleet,sysid,match", [("", 1, "fleet"), ("a/b", 1, "fleet"), ("demo*", 1, "fleet"),
                                               ("demo", 0, "sysid"), ("demo", True, "sysid")])
def test_sensor_key_rejects_bad_parts(fleet, sysid, match):
    with pytest.raises(ValueError, match=match):
        sensor_key(fleet, sysid)


def test_zenoh_config_sets_explicit_endpoints_and_no_multicast():
    conf = zenoh_config(listen="tcp/127.0.0.1:7447", connect=["tcp/127.0.0.1:7448"])
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7448"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


@pytest.mark.parametrize("kw,match", [({}, "at least one"), ({"listen": "127.0.0.1:7447"}, "PROTO/ADDRESS"),
                                      ({"connect": ["tcp:127.0.0.1:1"]}, "PROTO/ADDRESS")])
def test_zenoh_config_rejects_missing_or_bad_endpoints(kw, match):
    with pytest.raises(ValueError, match=match):
        zenoh_config(**kw)
