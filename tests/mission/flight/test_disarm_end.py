"""'done' means disarmed: a mission ends once its landed vehicles have disarmed.

The autopilot's own auto-disarm after landing (PX4 ``COM_DISARM_LAND``, 2 s; ArduPilot on
touchdown) is waited for; a vehicle reported on the ground but still armed is sent a disarm
command; one that stays armed is reported (summary ``still_armed``, a ``still_armed`` record,
an error event, exit status 1). Checked against the mock fleet's own states.
"""
from __future__ import annotations

import json

import pytest

import sitl_mock.ap_flight as ap_flight
from mission.cli import cmd_run
from mission.cli import main as cli_main
from mission.telemetry.mission_log import read_mission_log


@pytest.fixture
def fleets(monkeypatch):
    """The embedded mock fleets `swarmseek run` makes in this test (kept to read their states)."""
    made = []
    real = cmd_run._make_fleet

    def _keep(*args, **kwargs):
        fleet = real(*args, **kwargs)
        made.append(fleet)
        return fleet

    monkeypatch.setattr(cmd_run, "_make_fleet", _keep)
    return made


def _run(tmp_path, capsys, *extra):
    log_dir = tmp_path / "log"
    code = cli_main(["run", "--json", "--no-tlog", "--log-dir", str(log_dir), *extra])
    summary = json.loads(capsys.readouterr().out)
    return code, summary, read_mission_log(log_dir / "mission.jsonl")


@pytest.mark.parametrize("personality,seed", [("px4", 3), ("px4", 1), ("ardupilot", 3), ("ardupilot", 2)])
def test_whole_mission_ends_with_every_vehicle_disarmed(tmp_path, capsys, fleets, personality, seed):
    # 4 vehicles (run's default is 8), for CPU: the disarm wait is per vehicle, and with it switched off
    # each of these 4-vehicle missions still ends with mock vehicles armed at 'done' (checked, as with 8)
    code, summary, records = _run(tmp_path, capsys, "--n", "4", "--seed", str(seed), "--personality", personality)
    assert summary["outcome"] == "converged" and code == 0, summary["message"]
    armed = [v.sysid for v in fleets[0].vehicles if v.autopilot.armed]
    assert armed == [], f"mock vehicles {armed} still armed at 'done'"
    assert summary["still_armed"] == [] and summary["airborne_left"] == []
    assert [r["phase"] for r in records if r["type"] == "phase"][-1] == "done"
    assert not [r for r in records if r["type"] == "still_armed"]


def test_a_vehicle_that_never_disarms_is_reported(tmp_path, capsys, fleets, monkeypatch):
    stubborn = 2
    real_disarm = ap_flight.disarm
    refused = []

    def _disarm(ap, t_s, forced=False):
        if ap.sysid == stubborn:
            refused.append(t_s)
            return ap.personality.reject_result
        return real_disarm(ap, t_s, forced)

    monkeypatch.setattr(ap_flight, "disarm", _disarm)
    real_start = cmd_run._make_fleet  # the fixture's wrapper: switch vehicle 2's auto-disarm off

    def _no_auto_disarm(*args, **kwargs):
        fleet = real_start(*args, **kwargs)
        for v in fleet.vehicles:
            if v.sysid == stubborn:
                v.autopilot.params.set("COM_DISARM_LAND", -1.0)
        return fleet

    monkeypatch.setattr(cmd_run, "_make_fleet", _no_auto_disarm)
    code, summary, records = _run(tmp_path, capsys, "--n", "4", "--seed", "3")
    still = [v.sysid for v in fleets[0].vehicles if v.autopilot.armed]
    assert still == [stubborn]
    assert refused, "the ground station never sent the landed, still armed vehicle a disarm command"
    assert [e["sysid"] for e in summary["still_armed"]] == [stubborn]
    assert code == 5 == summary["exit_status"]  # converged, but not done: a vehicle is still armed
    assert [v["sysid"] for r in records if r["type"] == "still_armed" for v in r["vehicles"]] == [stubborn]
    assert any(r["type"] == "event" and r.get("level") == "error" and "still ARMED" in r["message"]
               for r in records)


def test_summary_line_names_the_armed_vehicles():
    from mission.telemetry.display import format_summary

    lines = format_summary({"outcome": "converged", "message": "m", "still_armed": [{"sysid": 3}, {"sysid": 5}]})
    assert any("STILL ARMED" in line and "[3, 5]" in line for line in lines)


@pytest.mark.parametrize("left, armed, ok", [([], [], True), ([{"sysid": 2}], [], False),
                                             ([], [{"sysid": 3}], False)])
def test_a_converged_mission_is_ok_only_with_every_vehicle_down_and_disarmed(left, armed, ok):
    """Exit status 0 means converged AND nothing left in the air AND nothing still armed (once,
    ``fly`` exited 0 although its last line said a vehicle was left AIRBORNE)."""
    from mission.flight.result import MissionResult
    from mission.telemetry.display import report_result

    result = MissionResult(outcome="converged", message="converged after 9 iterations",
                           airborne_left=left, still_armed=armed)
    assert result.ok is ok
    assert report_result(result, None, True) == (0 if ok else 5)  # 5: go and look, a vehicle is up or armed
