"""A whole lock-step mission (the default ``swarmseek run``: model seeker, sampling while moving)
ends on the region rule of estimator.seek_confirm: its conditions hold in the logged iterations,
the window test alone would not have passed yet, and the estimate is within the tolerance."""
from __future__ import annotations

import json

import numpy as np

from estimator import ConvergenceMonitor
from estimator.seek_confirm import DEFAULT_HOLD
from mission.cli import main as cli_main
from mission.telemetry.mission_log import read_mission_log

TOL_M = 0.5  # a plan's convergence_tol_m, the run's
WINDOW = 12  # a plan's convergence_window


def test_default_mission_is_declared_by_the_region_rule_with_the_formation_on_the_source(tmp_path, capsys):
    code = cli_main(["run", "--seed", "15", "--json", "--no-tlog", "--log-dir", str(tmp_path)])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["outcome"] == "converged", out["message"]
    records = read_mission_log(tmp_path / "mission.jsonl")
    its = [r for r in records if r["type"] == "iteration"]
    assert its[-1]["converged_by"] == "region"
    assert all(r["converged_by"] is None for r in its[:-1])
    last = its[-DEFAULT_HOLD:]
    est = np.array([r["estimate_enu"] for r in last])
    for r, e in zip(last, est):  # the rule's conditions, read back from the log
        assert "log-quadratic fit" in r["estimate_basis"] and r["estimate_region95_m"] <= TOL_M
        assert np.linalg.norm(np.asarray(r["new_centre_enu"]) - e) <= TOL_M
        assert np.linalg.norm(np.asarray(r["centroid_enu"]) - e) <= TOL_M
    assert np.all(np.linalg.norm(est - est.mean(axis=0), axis=1) <= TOL_M / 2)
    # the window test alone, fed the same centres (the start, then each new centre), had not passed
    monitor = ConvergenceMonitor(window=WINDOW, tol_m=TOL_M)
    monitor.update(its[0]["centre_enu"])
    assert not any(monitor.update(r["new_centre_enu"]) for r in its)
    source = np.asarray(out["true_source_enu"])
    assert abs(np.linalg.norm(np.asarray(out["estimate_enu"]) - source) - out["error_m"]) < 1e-3  # the fit's
    assert out["error_m"] <= TOL_M
    assert out["spread_m"] <= TOL_M  # the spread of the hold's centres, not of the approach's
    assert np.linalg.norm(np.asarray(its[-1]["centroid_enu"]) - source) <= 1.0  # the formation is there
