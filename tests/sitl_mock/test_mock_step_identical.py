"""The mock fleet's per-step fast paths fly exactly what the plain code flew.

``tests/sitl_mock/data/mock_trajectory_golden.json`` was recorded by the mock before its
per-step fast paths (``tests/support/mock_trajectory.py`` says how to rewrite it after a
deliberate change of behaviour): four vehicles of both personalities through take-off,
position and velocity setpoints, a GPS glitch, geofences, gusts and noise, and a landing.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.support.mock_trajectory import GOLDEN_PATH, KEEP_EVERY_STEPS, record_scenario, summarise


@pytest.fixture(scope="module")
def run():
    return record_scenario()


@pytest.fixture(scope="module")
def golden():
    return json.loads(GOLDEN_PATH.read_text())


def test_scenario_flies_take_off_to_landing_without_errors(run):
    """The scenario exercises what it claims (else equality below would prove little)."""
    assert run["errors"] == []
    pos = np.array(run["positions"])                        # (steps, vehicles, 3) NED m
    assert (pos[:, :, 2].min(axis=0) < -11.0).all()         # every vehicle climbed past 11 m
    assert np.allclose(pos[1499, :, :2], [[15, -10], [18, -8], [21, -6], [24, -4]], atol=0.3)
    assert (pos[-1, :, 2] == 0.0).all()                     # and landed
    assert len(run["readings"]) == 4 * 10 * 60              # 10 Hz readings, 60 s, 4 vehicles


def test_positions_match_the_recording_of_the_plain_code(run, golden):
    summary = summarise(run)
    assert summary["steps"] == golden["steps"]
    kept = np.array(summary["positions_every_0_5_s"])
    assert kept.shape == (golden["steps"] // KEEP_EVERY_STEPS, 4, 3)
    np.testing.assert_allclose(kept, np.array(golden["positions_every_0_5_s"]), rtol=0, atol=1e-9)
    assert summary["positions_sha256"] == golden["positions_sha256"]  # every step, every bit


def test_telemetry_frames_and_readings_are_byte_identical_to_the_recording(run, golden):
    summary = summarise(run)
    assert summary["frames_per_vehicle"] == golden["frames_per_vehicle"]
    assert summary["frames_sha256"] == golden["frames_sha256"]
    assert summary["readings"] == golden["readings"]
    assert summary["readings_sha256"] == golden["readings_sha256"]


def test_a_changed_step_is_caught(run, golden):
    """The comparison can fail: one position moved by a micrometre changes the digest."""
    moved = {**run, "positions": [list(step) for step in run["positions"]]}
    n, e, d = moved["positions"][1234][2]
    moved["positions"][1234][2] = (n + 1e-6, e, d)
    assert summarise(moved)["positions_sha256"] != golden["positions_sha256"]
