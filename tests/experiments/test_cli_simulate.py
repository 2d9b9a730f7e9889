"""``swarmseek simulate``: "converged" means what a mission means by it, every distance named."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimator import ConvergenceMonitor
from mission.cli import main as cli_main


def _run(capsys, *argv) -> dict:
    assert cli_main(["simulate", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_stop_agrees_with_the_missions_convergence_monitor(capsys):
    """The iteration and the estimate simulate reports are those the mission's monitor gives."""
    out = _run(capsys, "--window", "400", "--tol", "1.0")
    from experiments.offline import simulate
    import formation
    from sitl_mock.fields_config import make_field

    res = simulate(formation.cvt_sphere(8, 1.0, seed=0), make_field("sigma2"), np.array([20.0, -20.0, 5.0]),
                   eps=1.0, gamma=0.1, iterations=3000)
    monitor = ConvergenceMonitor(window=400, tol_m=1.0)
    stop = next(k for k, c in enumerate(res.centres[:, 0]) if monitor.update(c))
    assert out["converged"] and out["converged_at_iteration"] == stop
    assert np.allclose(out["estimated_source_enu"], monitor.estimate_enu, atol=1e-9)
    assert np.allclose(out["centre_at_convergence_enu"], res.centres[stop, 0])


def test_both_distances_reported_and_the_tests_promise_holds(capsys):
    """The reported run: the estimate where a mission stops (0.835 m) and the run's end (0.033 m)
    are two named distances, and the estimate is within the tolerance of the source (noise-free:
    the limit point is the source), as the test promises."""
    out = _run(capsys)
    assert out["converged"] and out["converged_at_iteration"] < out["final_iteration"] == 3000
    assert out["estimate_error_m"] <= out["tol_m"]
    src = np.asarray(out["source_enu"])
    assert out["estimate_error_m"] == pytest.approx(np.linalg.norm(np.asarray(out["estimated_source_enu"]) - src))
    assert out["final_distance_m"] == pytest.approx(np.linalg.norm(np.asarray(out["final_centre_enu"]) - src))
    assert out["final_distance_m"] < out["estimate_error_m"]  # the run went on and got closer
    assert out["converged_at_end"] is True and out["final_window_error_m"] < out["estimate_error_m"]


def test_stop_at_convergence_ends_where_a_mission_would(capsys):
    out = _run(capsys, "--stop-at-convergence")
    assert out["stopped_at_convergence"]
    assert out["final_iteration"] == out["converged_at_iteration"]
    assert out["final_centre_enu"] == out["centre_at_convergence_enu"]


def test_text_names_each_distance(capsys):
    assert cli_main(["simulate"]) == 0
    text = capsys.readouterr().out
    assert "passed at iteration 1700: a mission would stop there" in text
    assert "(mean of the window's centres, spread" in text and "m from the true source" in text
    assert "after 3000 iterations (the run goes on past convergence)" in text
    assert "the test over the last 400 iterations passes" in text


def test_never_converged_reports_no_estimate(capsys):
    out = _run(capsys, "--iterations", "100")
    assert not out["converged"] and out["estimated_source_enu"] is None and out["estimate_error_m"] is None
    assert out["converged_at_end"] is None  # the run is shorter than the window
    assert cli_main(["simulate", "--iterations", "100"]) == 0
    assert "never passed: not converged, no estimated source" in capsys.readouterr().out
