"""``swarmseek run --seeds``: one lock-step mission per seed, a row each (the single run's own
numbers), serial or ``--jobs 2``, a failed mission a row of its own; bad sweep options exit 2."""
from __future__ import annotations

import csv
import json

import pytest

from experiments.sweep import RUN_COLUMNS, run_sweep, seed_list
from mission.cli import main as cli_main

#: short missions: 4 vehicles (about 2.5 s of wall time each on this machine), no .tlog files
_SHORT = ["--n", "4", "--no-tlog"]


def exit_status(argv: list[str]) -> int:
    """The exit status of ``swarmseek ARGV`` run in this process (argparse's errors exit)."""
    try:
        return cli_main(argv)
    except SystemExit as exc:
        return exc.code


def _csv_rows(path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def serial_sweep(tmp_path_factory):
    """Seeds 0-1 one after another, rows to a CSV file; (exit status, rows, log root)."""
    tmp = tmp_path_factory.mktemp("sweep")
    rows_path = tmp / "rows.csv"
    status = cli_main(["run", *_SHORT, "--seeds", "0-1", "--log-dir", str(tmp / "logs"),
                       "--sweep-out", str(rows_path)])
    return status, _csv_rows(rows_path), tmp / "logs"


def test_a_sweep_writes_one_row_per_seed_with_every_column(serial_sweep):
    status, rows, logs = serial_sweep
    assert status == 0
    assert list(rows[0]) == list(RUN_COLUMNS)
    assert [r["seed"] for r in rows] == ["0", "1"]
    for r in rows:
        assert r["n"] == "4" and r["field"] == "sigma2" and r["seeker"] == "model"
        assert r["outcome"] == "converged" and r["landed"] == "True" and r["reason"] == ""
        assert 0.0 < float(r["error_m"]) < 1.0 and float(r["estimate_region95_m"]) > 0.0
        assert int(r["iterations"]) > 0 and float(r["seek_s"]) > 0.0 and float(r["wall_s"]) > 0.0
        assert 1.0 <= float(r["straight_line_ratio"]) < 4.0  # never faster than the straight line
        assert float(r["distance_flown_m"]) > 20.0  # the formation starts 25 m from the source
        assert r["log_path"] == str(logs / f"seed-{r['seed']}" / "mission.jsonl")


def test_a_sweep_row_is_the_single_runs_json_summary(serial_sweep, tmp_path, capsys):
    """Seed 1's row holds the numbers `swarmseek run --seed 1 --json` prints (lock-step: the same mission)."""
    _, rows, _ = serial_sweep
    capsys.readouterr()
    assert cli_main(["run", *_SHORT, "--seed", "1", "--json", "--log-dir", str(tmp_path / "one")]) == 0
    single = json.loads(capsys.readouterr().out)
    row = rows[1]
    assert float(row["error_m"]) == single["error_m"]
    assert float(row["estimate_region95_m"]) == single["estimate_region95_m"]
    assert int(row["iterations"]) == single["iterations"]
    assert float(row["seek_s"]) == single["seek_time_s"]
    assert float(row["distance_flown_m"]) == single["distance_flown_m"]


def test_two_jobs_give_the_same_rows_as_one_after_another(serial_sweep, tmp_path, capsys):
    _, serial_rows, _ = serial_sweep
    rows_path = tmp_path / "rows.jsonl"
    assert cli_main(["run", *_SHORT, "--seeds", "0-1", "--jobs", "2", "--log-dir", str(tmp_path / "logs"),
                     "--sweep-out", str(rows_path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    rows = sorted((json.loads(line) for line in rows_path.read_text().splitlines()), key=lambda r: r["seed"])
    assert [r["seed"] for r in rows] == [0, 1]
    for row, serial in zip(rows, serial_rows):
        for col in ("error_m", "iterations", "seek_s", "straight_line_ratio", "distance_flown_m"):
            assert row[col] == pytest.approx(float(serial[col]), abs=0), col
    assert summary["runs"] == 2 and summary["outcomes"] == {"converged": 2} and summary["jobs"] == 2
    errors = sorted(r["error_m"] for r in rows)
    assert summary["stats"]["error_m"]["median"] == pytest.approx(sum(errors) / 2)
    assert summary["stats"]["error_m"]["max"] == errors[-1]


def test_a_mission_that_fails_is_a_row_and_the_sweep_goes_on(tmp_path, monkeypatch, capsys):
    """A mission raising: its row says error and why, the next seed still flies, exit status 1."""
    from mission.cli import run_sweep as sweep_module

    real = sweep_module.sweep_mission

    def flaky(fly, options, log_root, seed):
        if seed == 0:
            raise RuntimeError("the fleet caught fire")
        return real(fly, options, log_root, seed)

    monkeypatch.setattr(sweep_module, "sweep_mission", flaky)
    rows_path = tmp_path / "rows.csv"
    assert cli_main(["run", *_SHORT, "--seeds", "0-1", "--log-dir", str(tmp_path / "logs"),
                     "--sweep-out", str(rows_path)]) == 1
    rows = _csv_rows(rows_path)
    assert [(r["seed"], r["outcome"]) for r in rows] == [("0", "error"), ("1", "converged")]
    assert rows[0]["reason"] == "RuntimeError: the fleet caught fire" and rows[0]["error_m"] == ""
    assert rows[0]["n"] == "4" and rows[0]["seeker"] == "model"
    captured = capsys.readouterr()
    assert "seed 0 failed: RuntimeError: the fleet caught fire" in captured.out
    assert "converged 1, error 1" in captured.out
    assert "swarmseek run: 1/2 done (1 failed)" in captured.err  # plain progress lines: not a terminal


def _raise_on_seed_one(seed: int) -> dict:
    if seed == 1:
        raise ValueError("no source here")
    return {"seed": seed, "outcome": "converged", "error_m": 0.1 * seed}


@pytest.mark.parametrize("jobs", [1, 2])
def test_run_sweep_keeps_going_after_an_exception(jobs):
    seen = []
    rows = run_sweep([0, 1, 2], _raise_on_seed_one, jobs=jobs, on_row=seen.append, base={"n": 4})
    assert [r["seed"] for r in rows] == [0, 1, 2] and len(seen) == 3
    assert rows[1]["outcome"] == "error" and rows[1]["reason"] == "ValueError: no source here"
    assert rows[1]["n"] == 4 and rows[1]["wall_s"] >= 0.0
    assert rows[2] == {"seed": 2, "outcome": "converged", "error_m": 0.2}


def test_seed_lists():
    assert seed_list("0-3,7") == [0, 1, 2, 3, 7]
    assert seed_list("5") == [5]
    assert seed_list(" 2 - 4 ".replace(" ", "")) == [2, 3, 4]


@pytest.mark.parametrize("argv, message", [
    (["--seeds", "5-2"], "argument --seeds: the range '5-2' ends below its start"),
    (["--seeds", "a"], "argument --seeds: expected seeds as N, A-B or a comma-separated list"),
    (["--seeds", "-1"], "argument --seeds: expected"),
    (["--seeds", "0,1,0"], "argument --seeds: seed 0 is given twice"),
    (["--seeds", "0-1", "--sweep-out", "{tmp}/rows.txt"], "the rows file must end in .csv or .jsonl"),
    (["--seeds", "0-1", "--sweep-out", "{tmp}/no-such-dir/rows.csv"],
     "cannot write the rows file (--sweep-out) '{tmp}/no-such-dir/rows.csv': No such file or directory"),
    (["--seeds", "0-1", "--sweep-out", "{tmp}/a-dir.csv"], "'{tmp}/a-dir.csv': Is a directory"),
    (["--sweep-out", "{tmp}/rows.csv"], "--sweep-out applies to a sweep only (give --seeds"),
    (["--jobs", "2"], "--jobs applies to a sweep only (give --seeds"),
    (["--seeds", "0-1", "--jobs", "0"], "argument --jobs: --jobs must be 1..64, got 0"),
    (["--seed", "1", "--seeds", "0-1"], "argument --seeds: not allowed with argument --seed"),
    (["--seeds", "0-1", "--out", "udp:127.0.0.1:14550"], "--out forwards one mission's MAVLink; a sweep"),
    (["--seeds", "0-1", "--n", "3"], "--n must be at least 4"),
])
def test_bad_sweep_options_exit_2_with_one_line(tmp_path, capsys, argv, message):
    (tmp_path / "a-dir.csv").mkdir()
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    status = exit_status(["run", *argv, "--log-dir", str(tmp_path / "logs")])
    err = capsys.readouterr().err
    assert status == 2
    last = err.strip().splitlines()[-1]
    assert last.startswith("swarmseek run: error: ") and message.replace("{tmp}", str(tmp_path)) in last
    assert "Traceback" not in err
    assert not (tmp_path / "logs").exists()  # refused before any mission or log directory
    assert not (tmp_path / "rows.csv").exists()


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_ctrl_c_stops_the_sweep_with_its_rows_kept(tmp_path, jobs):
    """SIGINT once the first mission's row is out: the mission under way ends as a single run's
    does (its vehicles brought down), no further seed flies, exit 130 naming the seeds not flown."""
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    rows_path = tmp_path / "rows.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "mission", "run", *_SHORT, "--seeds", "0-5", "--jobs", jobs,
                             "--log-dir", str(tmp_path / "logs"), "--sweep-out", str(rows_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            env=dict(os.environ, PYTHONPATH=str(root)))
    err_lines = []
    try:
        for line in proc.stderr:  # the progress lines: wait for the first finished mission
            err_lines.append(line)
            if " done, " in line:
                break
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(err_lines) + err
    assert proc.returncode == 130, err
    assert "swarmseek run: stopped by SIGINT: seeds " in err and " not flown" in err
    assert "Traceback" not in err
    rows = [json.loads(line) for line in rows_path.read_text().splitlines()]
    assert 1 <= len(rows) < 6
    assert all(r["landed"] is True for r in rows)  # the interrupted mission's vehicles too


@pytest.mark.parametrize("tty", [False, True])
def test_progress_is_a_bar_on_a_terminal_and_plain_lines_elsewhere(tty):
    import io

    from experiments.sweep import Progress

    class Stream(io.StringIO):
        def isatty(self):
            return tty

    stream = Stream()
    progress = Progress("swarmseek run", 4, stream)
    progress.update({"seed": 7, "outcome": "converged", "error_m": 0.0514})
    progress.update({"seed": 8, "outcome": "error", "error_m": None})
    text = stream.getvalue()
    if tty:  # redrawn in place: carriage returns, a bar, no newline before the last run
        assert text.startswith("\r[#####...............] swarmseek run: 1/4 done")
        assert "\x1b[K\r[##########..........] swarmseek run: 2/4 done (1 failed)" in text and "\n" not in text
    else:
        lines = text.splitlines()
        assert lines[0].startswith("swarmseek run: 1/4 done, ") and lines[0].endswith("seed 7 converged, error 0.051 m")
        assert lines[1].startswith("swarmseek run: 2/4 done (1 failed), ") and lines[1].endswith("seed 8 error")
        assert "\r" not in text
