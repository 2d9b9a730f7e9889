"""The embedded mock fleet's unconfigured ground-station-loss failsafe is said once, in the
mock's words, as information (``run`` once warned for each of its 8 mock vehicles that
"nothing brings it down"); real vehicles (``fly``, ``dry-run``) keep the warning naming each vehicle."""
from __future__ import annotations

import pytest

from mission.cli import main as cli_main
from mission.flight.failsafe_params import assess, report_lines
from mission.telemetry.mission_log import read_mission_log

PX4_DEFAULTS = {"COM_OBL_RC_ACT": 0, "NAV_DLL_ACT": 0, "COM_OF_LOSS_T": 1.0, "COM_DL_LOSS_T": 10}
MOCK_WORDS = "simulation: the mock autopilots keep their defaults, no ground-station-loss failsafe"


def _found(n: int, values: dict) -> dict:
    return {s: assess("px4", values) for s in range(1, n + 1)}


def test_real_vehicles_get_the_warning_naming_each_vehicle():
    ((sysids, message, level, hovers),) = report_lines(_found(8, PX4_DEFAULTS), require=False)
    assert sysids == list(range(1, 9)) and level == "warning" and hovers is True
    assert message.startswith("vehicles 1, 2, 3, 4, 5, 6, 7, 8: if the ground station dies:")
    assert "nothing brings it down: it would hover until its battery fails" in message


def test_the_mock_fleet_gets_one_informative_line():
    ((sysids, message, level, hovers),) = report_lines(_found(8, PX4_DEFAULTS), require=False, simulated=True)
    assert sysids == list(range(1, 9)) and level == "info" and hovers is True
    assert message.startswith(MOCK_WORDS)
    assert "on data-link loss (10 s): nothing (disabled)" in message
    assert "nothing brings it down" not in message and "vehicles 1, 2" not in message


def test_a_required_failsafe_is_an_error_in_simulation_too():
    ((_, message, level, _),) = report_lines(_found(4, PX4_DEFAULTS), require=True, simulated=True)
    assert level == "error" and "nothing brings it down" in message


@pytest.mark.parametrize("simulated", [False, True])
def test_configured_or_unknown_failsafes_read_the_same_in_simulation(simulated):
    found = {1: assess("px4", dict(PX4_DEFAULTS, COM_OBL_RC_ACT=4)), 2: assess("px4", {})}
    lines = report_lines(found, require=False, simulated=simulated)
    assert [(s, lvl, h) for s, _, lvl, h in lines] == [([1], "info", False), ([2], "warning", None)]
    assert lines[0][1].startswith("vehicle 1: if the ground station dies: on offboard loss (1 s): land")
    assert lines[1][1].endswith("-- failsafe unknown")


@pytest.mark.timeout(300)
def test_the_default_run_says_it_once_and_warns_nothing(tmp_path, capsys):
    log_dir = tmp_path / "run"
    status = cli_main(["run", "--n", "4", "--max-iterations", "2", "--seed", "2", "--no-tlog",
                       "--log-dir", str(log_dir)])
    out = capsys.readouterr()
    assert status in (0, 1), out.err  # 2 iterations: not converged is fine here
    printed = out.out + out.err
    assert printed.count(MOCK_WORDS) == 1
    assert "nothing brings it down" not in printed and "if the ground station dies" not in printed
    records = read_mission_log(log_dir / "mission.jsonl")
    events = [r for r in records if r.get("type") == "event" and "hovers_forever" in r]
    assert len(events) == 1 and events[0]["level"] == "info" and events[0]["sysids"] == [1, 2, 3, 4]
    ready = [r for r in records if r.get("type") == "event" and str(r.get("message", "")).endswith(": ready")]
    assert len(ready) == 4 and all(not r["warnings"] for r in ready)
