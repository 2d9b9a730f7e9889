"""``swarmseek audit`` can fail: on a real mission directory (one lock-step ``swarmseek run`` per
module, copied and then damaged per test) it exits 3, "incomplete", when it checked no setpoint
(``--gcs-sysid 1``), when a planned vehicle's tlog is missing or empty, or when the log's plan
and the tlogs disagree (two missions' plan records in one mission.jsonl, setpoints sent to a
vehicle the plan does not have); bad options are exit 2 with one line; ``--json | head`` (a
closed stdout) ends quietly. Before, each of these printed "OK" and exited 0."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mission.cli import main as cli_main

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[3]
N = 4


@pytest.fixture(scope="module")
def flown(tmp_path_factory) -> Path:
    """A real mission directory: ``swarmseek run`` (lock-step, 4 vehicles, a few iterations)."""
    log_dir = tmp_path_factory.mktemp("audit-mission") / "run"
    status = cli_main(["run", "--n", str(N), "--max-iterations", "4", "--seed", "2", "--json",
                       "--log-dir", str(log_dir)])
    assert status in (0, 1) and (log_dir / "mission.jsonl").is_file()
    assert sorted(p.name for p in (log_dir / "tlogs").glob("vehicle-*.tlog")) == [
        f"vehicle-{s}.tlog" for s in range(1, N + 1)]
    return log_dir


@pytest.fixture
def mission_dir(flown, tmp_path) -> Path:
    """A copy of the flown mission, to damage."""
    return Path(shutil.copytree(flown, tmp_path / "mission"))


def _audit(capsys, log_dir, *options) -> tuple[int, dict]:
    status = cli_main(["audit", str(log_dir), "--json", *options])
    return status, json.loads(capsys.readouterr().out)


def test_the_whole_mission_audits_clean(capsys, mission_dir):
    status, report = _audit(capsys, mission_dir)
    assert status == 0 and report["ok"] and report["incomplete"] == []
    assert report["setpoints_checked"] > 100 and sorted(report["per_vehicle"]) == [str(s) for s in range(1, N + 1)]


def test_no_setpoint_checked_is_not_ok(capsys, mission_dir):
    status, report = _audit(capsys, mission_dir, "--gcs-sysid", "1")
    assert status == 3 and report["setpoints_checked"] == 0 and not report["ok"]
    assert any("nothing was checked" in why for why in report["incomplete"])
    assert cli_main(["audit", str(mission_dir), "--gcs-sysid", "1"]) == 3
    text = capsys.readouterr().out
    assert "INCOMPLETE: no position setpoint sent by system id 1" in text and "OK: no violation" not in text


@pytest.mark.parametrize("damage, why", [("delete", "vehicle 3 of the plan has no tlog"),
                                         ("empty", "vehicle 3 of the plan has an empty tlog")])
def test_a_missing_or_empty_tlog_of_a_planned_vehicle_is_not_ok(capsys, mission_dir, damage, why):
    tlog = mission_dir / "tlogs" / "vehicle-3.tlog"
    if damage == "delete":
        tlog.unlink()
    else:
        tlog.write_bytes(b"")
    status, report = _audit(capsys, mission_dir)
    assert status == 3 and report["incomplete"] == [why] and report["setpoints_checked"] > 0


def test_two_missions_in_one_log_are_not_ok(capsys, mission_dir):
    log = mission_dir / "mission.jsonl"
    log.write_bytes(log.read_bytes() * 2)              # a second run wrote into the same directory
    status, report = _audit(capsys, mission_dir)
    assert status == 3 and "holds 2 missions' plan records" in report["incomplete"][0]


def test_a_resumed_missions_own_plan_record_is_not_another_mission(capsys, mission_dir):
    log = mission_dir / "mission.jsonl"
    plan = next(r for r in map(json.loads, log.read_text().splitlines()) if r.get("type") == "plan")
    with open(log, "a") as fh:
        fh.write(json.dumps(dict(plan, resumed=True)) + "\n")
    status, report = _audit(capsys, mission_dir)
    assert status == 0 and report["incomplete"] == []


def test_setpoints_to_a_vehicle_not_in_the_plan_are_not_ok(capsys, mission_dir):
    log = mission_dir / "mission.jsonl"
    records = [json.loads(line) for line in log.read_text().splitlines()]
    for r in records:                                  # the plan forgets vehicle 4, its tlog is there
        if r.get("type") == "plan":
            r["plan"]["vehicles"] = [v for v in r["plan"]["vehicles"] if v["sysid"] != 4]
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    status, report = _audit(capsys, mission_dir)
    assert status == 3 and report["ignored_tlogs"][0].endswith("vehicle-4.tlog")
    assert any("sent to system id 4, which is not in the plan" in why for why in report["incomplete"])


@pytest.mark.parametrize("value", ["0", "256", "-1", "ten"])
def test_bad_gcs_sysid_is_a_clear_error(capsys, mission_dir, value):
    with pytest.raises(SystemExit) as exc:
        cli_main(["audit", str(mission_dir), "--gcs-sysid", value])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--gcs-sysid" in err and "Traceback" not in err


def test_json_into_a_closed_pipe_ends_quietly(mission_dir):
    read_end, write_end = os.pipe()
    os.close(read_end)                                 # the reader (`| head`) is gone before a byte is written
    try:
        p = subprocess.run([sys.executable, "-m", "mission", "audit", str(mission_dir), "--json"], cwd=ROOT,
                           env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=write_end,
                           stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(write_end)
    assert p.returncode == 0 and p.stderr == "", p.stderr
