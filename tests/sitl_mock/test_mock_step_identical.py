"""The mock fleet's per-step fast paths fly exactly what the plain code flew.

``tests/sitl_mock/data/mock_trajectory_golden.json`` was recorded by the mock before its
per-step fast paths (``tests/support/mock_trajectory.py`` says how to rewrite it after a
deliberate change of behaviour): four vehicles of both personalities through take-off,
position and velocity setpoints, a GPS glitch, geofences, gusts and noise, and a landing, over a
Gaussian field and over the intermittent plume.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from sitl_mock.fields_config import FIELD_NAMES, make_field
from sitl_mock.fields_gaussian import sigma1
from sitl_mock.fleet import MockFleet
from tests.support.mock_trajectory import FIELDS, GOLDEN_PATH, KEEP_EVERY_STEPS, record_scenario, summarise


@pytest.fixture(scope="module", params=FIELDS)
def field_run(request):
    return request.param, record_scenario(request.param)


@pytest.fixture(scope="module")
def golden():
    return json.loads(GOLDEN_PATH.read_text())


def test_scenario_flies_take_off_to_landing_without_errors(field_run):
    """The scenario exercises what it claims (else equality below would prove little)."""
    _name, run = field_run
    assert run["errors"] == []
    pos = np.array(run["positions"])                        # (steps, vehicles, 3) NED m
    assert (pos[:, :, 2].min(axis=0) < -11.0).all()         # every vehicle climbed past 11 m
    assert np.allclose(pos[1499, :, :2], [[15, -10], [18, -8], [21, -6], [24, -4]], atol=0.3)
    assert (pos[-1, :, 2] == 0.0).all()                     # and landed
    values = np.array([r["value"] for r in run["readings"]])
    assert len(values) == 4 * 10 * 60                       # 10 Hz readings, 60 s, 4 vehicles
    assert (values > 0.01).mean() > 0.2                     # the sensors were in the signal


def test_positions_match_the_recording_of_the_plain_code(field_run, golden):
    name, run = field_run
    summary, expected = summarise(run), golden[name]
    assert summary["steps"] == expected["steps"]
    kept = np.array(summary["positions_every_0_5_s"])
    assert kept.shape == (expected["steps"] // KEEP_EVERY_STEPS, 4, 3)
    np.testing.assert_allclose(kept, np.array(expected["positions_every_0_5_s"]), rtol=0, atol=1e-9)
    assert summary["positions_sha256"] == expected["positions_sha256"]  # every step, every bit


def test_telemetry_frames_and_readings_are_byte_identical_to_the_recording(field_run, golden):
    name, run = field_run
    summary, expected = summarise(run), golden[name]
    assert summary["frames_per_vehicle"] == expected["frames_per_vehicle"]
    assert summary["frames_sha256"] == expected["frames_sha256"]
    assert summary["readings"] == expected["readings"]
    assert summary["readings_sha256"] == expected["readings_sha256"]  # every field but lat, lon, alt
    # lat, lon, alt: within rounding of the recording (their last bits depend on the CPU's numpy loops;
    # alt comes out of ECEF metres, whose ulp is 1e-9 m); the sums over every reading see any one of
    # them moved by 1e-9 deg (0.1 mm) or 1e-5 m
    fsum_off = np.abs(np.subtract(summary["readings_geodetic_fsum"], expected["readings_geodetic_fsum"]))
    assert (fsum_off <= [1e-9, 1e-9, 1e-5]).all(), fsum_off
    sample_off = np.abs(np.subtract(summary["readings_geodetic_every_8"], expected["readings_geodetic_every_8"]))
    assert (sample_off <= [1e-12, 1e-12, 1e-7]).all(), sample_off.max(axis=0)


def test_a_changed_step_is_caught(field_run, golden):
    """The comparison can fail: one position moved by a micrometre changes the digest."""
    name, run = field_run
    moved = {**run, "positions": [list(step) for step in run["positions"]]}
    n, e, d = moved["positions"][1234][2]
    moved["positions"][1234][2] = (n + 1e-6, e, d)
    assert summarise(moved)["positions_sha256"] != golden[name]["positions_sha256"]


@pytest.mark.parametrize("name", FIELD_NAMES)
def test_a_batch_of_points_gives_each_points_value_bit_for_bit(name):
    """What lets the fleet evaluate its field once per step for all vehicles."""
    rng = np.random.default_rng(3)
    field = make_field(name, (10.0, 5.0, 8.0), extra_sources=[(-4.0, 12.0, 6.0)])
    pts = np.column_stack([rng.uniform(-30, 60, 50), rng.uniform(-30, 60, 50), rng.uniform(0, 15, 50)])
    for t_s in (1_750_000_000.0, 1_750_000_012.34):
        single = [float(field.value(p, t_s)) for p in pts]
        assert np.asarray(field.value(pts, t_s)).tolist() == single


class _PointOnly:
    """A field that refuses batches (a plug-in written for one point at a time)."""

    def __init__(self):
        self.inner = sigma1()

    def value(self, points, t_s=0.0):
        if np.ndim(points) != 1:
            raise ValueError("one point at a time")
        return self.inner.value(points, t_s)


class _Broken:
    def value(self, points, t_s=0.0):
        raise RuntimeError("field broken")


class _Readings:
    def __init__(self):
        self.readings = []

    def publish(self, reading):
        self.readings.append(reading)

    def close(self):
        """Nothing to release."""


def _sampled(field):
    fleet = MockFleet(3, field=field, udp_base_port=0, tcp_base_port=0, zenoh=False)
    sink = _Readings()
    fleet.publish_readings_to(sink)
    fleet.step_until(fleet.next_step_s)
    return sink.readings, fleet.errors


def test_a_field_that_refuses_batches_is_asked_point_by_point():
    readings, errors = _sampled(_PointOnly())
    assert errors == []
    assert [r["sysid"] for r in readings] == [1, 2, 3]
    field = sigma1()
    fleet = MockFleet(3, field=field, udp_base_port=0, tcp_base_port=0, zenoh=False)
    expected = [float(field.value(v.true_position_enu(), 0.0)) for v in fleet.vehicles]
    assert [r["value"] for r in readings] == pytest.approx(expected, abs=1e-12)


def test_a_failing_field_costs_each_vehicle_its_reading_and_is_kept_as_evidence():
    readings, errors = _sampled(_Broken())
    assert readings == []
    assert len(errors) == 3 and all("field broken" in e for e in errors)


def test_readings_go_to_a_sink_only_on_a_fleet_without_zenoh():
    """``publish_readings_to`` hands readings to the sink, and is refused on a zenoh fleet."""
    readings, errors = _sampled(sigma1())
    assert readings and errors == []
    fleet = MockFleet(1, field=sigma1(), udp_base_port=0, tcp_base_port=0,
                      zenoh_listen=["tcp/127.0.0.1:7447"])  # not started: nothing listens
    with pytest.raises(ValueError, match="does not publish on zenoh"):
        fleet.publish_readings_to(_Readings())
