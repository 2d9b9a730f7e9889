"""A source the centre cannot reach (the fence shrunk by a large formation's radius) but the
formation surrounds: the seek converges on it; ``stopped_at_fence`` only for a source out of reach.

``swarmseek run --n 254 --seed 0`` (radius 10.8 m, the centre's floor 12.8 m, the source at
12.25 m up) ended ``stopped_at_fence`` with the model seeker's estimate 0.02 m from the source. The
same geometry at N = 6: ``--radius 10.5`` puts the centre's floor at 12.5 m, 0.25 m above seed 0's source.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.flight.fence_reach import source_in_reach
from mission.safety.audit import audit_mission
from mission.safety.fence import Geofence
from mission.sim.embedded import default_source_and_start
from mission.telemetry.mission_log import read_mission_log

FENCE = Geofence(((-15.0, -15.0), (15.0, -15.0), (15.0, 15.0), (-15.0, 15.0)), 2.0, 40.0)
HELD = np.array([4.0, 0.0, 12.5])  # on the fence shrunk by an 11 m radius (east 15 - 11)


def test_a_source_inside_the_formation_is_in_reach():
    """The seeker's own estimate and request 0.3 m beyond the held centre, inside the fence."""
    near = HELD + [0.0, 0.0, -0.3]
    assert source_in_reach(HELD, near, near, radius_m=11.0, tol_m=0.3, fence=FENCE)


def test_a_source_outside_the_fence_is_out_of_reach():
    """The request (or the estimate) outside the geofence itself: out of reach, however close."""
    outside = np.array([15.5, 0.0, 12.5])
    assert not source_in_reach(HELD, outside, outside, radius_m=11.0, tol_m=0.3, fence=FENCE)
    assert not source_in_reach(HELD, HELD + [0.2, 0, 0], outside, radius_m=11.0, tol_m=0.3, fence=FENCE)


def test_a_source_farther_than_the_radius_is_out_of_reach():
    """Inside the fence but beyond the formation (the vehicles do not surround it)."""
    held = np.array([0.0, 0.0, 13.0])
    below = np.array([0.0, 0.0, 2.5])
    assert not source_in_reach(held, below, below, radius_m=10.0, tol_m=0.3, fence=FENCE)
    assert source_in_reach(held, below, below, radius_m=11.0, tol_m=0.3, fence=FENCE)


def test_without_an_own_estimate_the_request_must_be_within_the_tolerance():
    """The mission reports the held centres then: the request must be within ``tol_m`` of them."""
    assert source_in_reach(HELD, HELD + [0.0, 0.0, -0.25], None, radius_m=11.0, tol_m=0.3, fence=FENCE)
    assert not source_in_reach(HELD, HELD + [0.0, 0.0, -0.5], None, radius_m=11.0, tol_m=0.3, fence=FENCE)


@pytest.mark.slow
def test_a_large_formation_over_a_low_source_converges(tmp_path, capsys):
    """N = 6, radius 10.5 m, seed 0: the centre's floor (2 + 10.5 m) is 0.25 m above the source;
    the mission converges (not ``stopped_at_fence``) within 0.3 m, the centre never below the
    floor, and the audit of its .tlogs is clean (no setpoint left the fence)."""
    source, _ = default_source_and_start(0)
    floor_m = 2.0 + 10.5
    assert source[2] < floor_m  # the geometry of the bug: the centre cannot reach the source
    code = cli_main(["run", "--n", "6", "--seed", "0", "--radius", "10.5", "--json", "--max-iterations", "60",
                     "--log-dir", str(tmp_path)])
    out = json.loads(capsys.readouterr().out)
    assert code == 0, out["message"]
    assert out["outcome"] == "converged", out["message"]
    assert "held at the fence" in out["message"]
    assert out["error_m"] < 0.3
    centres = np.array([r["new_centre_enu"] for r in read_mission_log(tmp_path / "mission.jsonl")
                        if r["type"] == "iteration"])
    assert centres[:, 2].min() >= floor_m - 1e-6
    assert audit_mission(tmp_path).ok
