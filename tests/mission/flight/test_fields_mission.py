"""Whole missions in lock-step on the plumes (``swarmseek run --field plume`` / ``intermittent``):
they finish (converged or, honestly, not), every vehicle lands, the sensors answer with the
configured lag and floor, and the error is measured against the release point."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mission.cli import main as cli_main
from mission.telemetry.mission_log import read_mission_log

from tests.support.fly_helpers import summary_exit_status

N = 4
FLOOR = 0.002


@pytest.mark.parametrize("field", ["plume", "intermittent"])
def test_run_on_a_plume_finishes_with_every_vehicle_landed(field, tmp_path, capsys):
    argv = ["run", "--field", field, "--n", str(N), "--seed", "2", "--max-iterations", "12", "--json",
            "--no-tlog", "--wind-from", "240", "--sensor-tau", "0.3", "--detection-floor", str(FLOOR),
            "--log-dir", str(tmp_path)]
    code = cli_main(argv)
    out = json.loads(capsys.readouterr().out)
    assert out["outcome"] in ("converged", "max_iterations"), out["message"]
    assert code == summary_exit_status(out)
    records = read_mission_log(tmp_path / "mission.jsonl")
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    assert phases[-3:] == ["finish", "return", "done"]
    landed = {r["message"] for r in records if r["type"] == "event" and r["message"].endswith("landed")}
    assert len(landed) == N
    setup = next(r for r in records if r["type"] == "event" and r["message"] == "embedded mock fleet")
    assert setup["field"] == field and ("FilamentPlume" if field == "intermittent" else "GaussianPlume") in \
        setup["field_model"] and "wind_from_deg=240" in setup["field_model"]
    assert setup["sensor_response"] == {"time_constant_s": 0.3, "detection_floor": FLOOR}
    # the start is downwind of the release: within 10 degrees of the wind's axis (blowing toward 60 deg)
    source, start = np.asarray(setup["source_enu"]), np.asarray(setup["start_enu"])
    bearing = np.degrees(np.arctan2(start[0] - source[0], start[1] - source[1]))  # clockwise from north
    assert abs((bearing - 60.0 + 180.0) % 360.0 - 180.0) <= 10.0 + 1e-6
    truth = next(r for r in records if r["type"] == "truth")
    assert np.allclose(truth["source_enu"], source, atol=1e-6)
    values = np.array([x["value"] for r in records if r["type"] == "iteration" for x in r["readings"]])
    assert len(values) >= 4 * out["iterations"]
    assert np.all((values == 0.0) | (values >= FLOOR))  # below the floor reads 0
    if out["estimate_enu"] is not None:
        assert out["error_m"] == pytest.approx(np.linalg.norm(np.asarray(out["estimate_enu"]) - source), abs=1e-3)
