"""``swarmseek simulate``: ``--seeds`` sweeps (a row per trial, the single trial's numbers), and what
its report says: the convergence test's window and where it comes from, why a test never passed,
no gradient error for a seeker that has none."""
from __future__ import annotations

import csv
import json

import pytest

from experiments.cmd_simulate import MISSION_TOL_M, MISSION_WINDOW
from experiments.sweep import SIMULATE_COLUMNS
from mission.cli import main as cli_main
from mission.core.plan_types import SeekingPlan

#: short noisy model-seeker trials (about 0.2 s each)
_TRIAL = ["simulate", "--seeker", "model", "--gamma", "20", "--noise", "0.01", "--iterations", "60"]


def exit_status(argv: list[str]) -> int:
    """The exit status of ``swarmseek ARGV`` run in this process (argparse's errors exit)."""
    try:
        return cli_main(argv)
    except SystemExit as exc:
        return exc.code


def test_a_sweep_row_is_the_single_trials_result(tmp_path, capsys):
    rows_path = tmp_path / "rows.csv"
    assert cli_main([*_TRIAL, "--seeds", "0-2", "--sweep-out", str(rows_path)]) == 0
    out = capsys.readouterr().out
    with open(rows_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(SIMULATE_COLUMNS)
    assert [r["seed"] for r in rows] == ["0", "1", "2"]
    assert len({r["error_m"] for r in rows}) == 3  # the seed sets the noise: three different trials
    for row in rows:
        assert cli_main([*_TRIAL, "--seed", row["seed"], "--json"]) == 0
        single = json.loads(capsys.readouterr().out)
        assert row["outcome"] == "converged" and single["converged"]
        assert float(row["error_m"]) == single["estimate_error_m"]
        assert int(row["iterations"]) == single["converged_at_iteration"]
        assert float(row["final_distance_m"]) == pytest.approx(single["final_distance_m"], abs=1e-6)
        assert float(row["distance_flown_m"]) == pytest.approx(single["distance_flown_m"], abs=1e-6)
        assert single["distance_flown_m"] >= 28.7 - 0.5 - 1e-9  # from 28.7 m away to within 0.5 m
    assert "swarmseek simulate: sweep of 3 seeds (0-2)" in out and "converged 3" in out


def test_two_jobs_give_the_same_rows(tmp_path, capsys):
    serial, parallel = tmp_path / "serial.jsonl", tmp_path / "parallel.jsonl"
    assert cli_main([*_TRIAL, "--seeds", "0,2", "--sweep-out", str(serial)]) == 0
    assert cli_main([*_TRIAL, "--seeds", "0,2", "--jobs", "2", "--sweep-out", str(parallel)]) == 0
    strip = lambda path: sorted(({k: v for k, v in json.loads(line).items() if k != "wall_s"}  # noqa: E731
                                 for line in path.read_text().splitlines()), key=lambda r: r["seed"])
    assert strip(serial) == strip(parallel) and [r["seed"] for r in strip(serial)] == [0, 2]


@pytest.mark.parametrize("argv, message", [
    (["--seeds", "3-1"], "argument --seeds: the range '3-1' ends below its start"),
    (["--seeds", "0-1", "--sweep-out", "{tmp}/rows.txt"], "the rows file must end in .csv or .jsonl"),
    (["--jobs", "2"], "--jobs applies to a sweep only"),
    (["--seeds", "0-1", "--seek-wind-from", "90", "--sweep-out", "{tmp}/rows.csv"],
     "--seek-wind-from applies to the plume and ste seekers only"),
    (["--seeds", "0-1", "--window", "4", "--sweep-out", "{tmp}/rows.csv"], "--window must be at least 8"),
])
def test_bad_sweep_options_exit_2_before_any_trial(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert exit_status(["simulate", *argv]) == 2
    err = capsys.readouterr().err
    assert "error: " in err.strip().splitlines()[-1] and message in err.strip().splitlines()[-1]
    assert "Traceback" not in err and not (tmp_path / "rows.csv").exists()


def test_the_mission_window_is_the_plans_default():
    assert (MISSION_WINDOW, MISSION_TOL_M) == (SeekingPlan.convergence_window, SeekingPlan.convergence_tol_m)


def test_the_gradient_run_names_the_papers_window_and_the_missions(capsys):
    assert cli_main(["simulate", "--iterations", "100"]) == 0
    text = capsys.readouterr().out
    assert ("convergence test (a mission's test, here window 400 iterations, tolerance 1 m: the paper's gradient "
            "run's; a mission plan's default is window 12, tolerance 0.5 m) never passed") in text
    assert "the run's 100 iterations are fewer than the test's window of 400" in text
    assert "gradient error 0.000" in text  # the gradient seeker has one


def test_a_seeker_without_a_gradient_reports_none(capsys):
    assert cli_main(["simulate", "--seeker", "model", "--gamma", "20", "--iterations", "40"]) == 0
    text = capsys.readouterr().out
    assert "gradient error" not in text and "nan" not in text
    assert "here window 12 iterations, tolerance 0.5 m: a mission plan's defaults) passed at iteration" in text
    assert cli_main(["simulate", "--seeker", "model", "--gamma", "20", "--iterations", "40", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["final_gradient_error"] is None


def test_the_plume_seeker_at_the_source_converges_with_the_missions_test(capsys):
    """It sits on the source of sigma_2 between casts: the mission's window of 12 sees it settle."""
    assert cli_main(["simulate", "--seeker", "plume", "--gamma", "20", "--iterations", "100", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["converged"] and out["window"] == 12 and out["tol_m"] == 0.5 and out["test_from"] == "plan"
    assert out["estimate_error_m"] < 0.01 and out["last_window"] is None


def test_a_test_that_never_passes_says_why(capsys):
    """With the paper's window of 400 the plume seeker's casts (out and back, up to 20 m) keep the
    spread over the tolerance, though the run ends on the source: the report says so."""
    argv = ["simulate", "--seeker", "plume", "--gamma", "20", "--iterations", "600", "--window", "400", "--tol", "1"]
    assert cli_main(argv) == 0
    text = capsys.readouterr().out
    assert "here window 400 iterations, tolerance 1 m: --window, --tol) never passed: not converged" in text
    assert "  over the last 400 iterations the centres spread " in text
    assert "(over the tolerance; up to 20.000 m from the source)" in text
    assert "after 600 iterations: centre [0.0, -0.0, -0.0], 0.000 m from the true source\n" in text + "\n"
