"""The exit status tells the truth (``run``, ``fly``, ``resume``, ``watch``): one code per kind of
ending, the same in ``--json`` (``exit_status``) and in the state publication's ``ending``."""
from __future__ import annotations

import pytest

from mission.flight.result import (EXIT_AIRBORNE, EXIT_NOT_REACHED, EXIT_OK, EXIT_VEHICLE_LOST, MissionResult,
                                   mission_exit_status)

LOST = [{"sysid": 3, "reason": "link"}]
LEFT = [{"sysid": 2}]
ARMED = [{"sysid": 4}]


@pytest.mark.parametrize("outcome, kwargs, status", [
    ("converged", {}, EXIT_OK),
    ("ready", {}, EXIT_OK),
    ("recovered", {}, EXIT_OK),
    ("max_iterations", {}, EXIT_NOT_REACHED),
    ("stopped_at_fence", {}, EXIT_NOT_REACHED),
    ("aborted", {}, EXIT_NOT_REACHED),
    ("not_ready", {}, EXIT_NOT_REACHED),
    ("converged", {"lost": LOST}, EXIT_VEHICLE_LOST),
    ("aborted", {"lost": LOST}, EXIT_VEHICLE_LOST),
    ("converged", {"airborne_left": LEFT}, EXIT_AIRBORNE),
    ("converged", {"still_armed": ARMED}, EXIT_AIRBORNE),
    ("aborted", {"lost": LOST, "airborne_left": LEFT}, EXIT_AIRBORNE),
    ("interrupted", {"interrupted_by": ["SIGTERM"]}, 143),
    ("interrupted", {"interrupted_by": ["SIGHUP", "SIGINT"]}, 129),
    ("interrupted", {"interrupted_by": ["LOG_WRITE_FAILED"]}, 74),
    ("interrupted", {"interrupted_by": ["SIGINT"], "lost": LOST}, 130),
    ("interrupted", {"interrupted_by": ["SIGINT"], "airborne_left": LEFT}, EXIT_AIRBORNE),
], ids=lambda v: v if isinstance(v, str) else None)
def test_one_status_per_kind_of_ending(outcome, kwargs, status):
    assert mission_exit_status(outcome, **kwargs) == status
    result = MissionResult(outcome=outcome, **kwargs)
    assert result.exit_status == status
    assert result.to_json()["exit_status"] == status
    assert result.ok is (status == EXIT_OK)


def test_the_codes_are_distinct_and_clear_of_usage_and_signals():
    codes = {EXIT_OK, EXIT_NOT_REACHED, EXIT_VEHICLE_LOST, EXIT_AIRBORNE}
    assert len(codes) == 4 and not codes & {2, 3, 74, 129, 130, 141, 143}


@pytest.mark.parametrize("ending, status, said", [
    ({"outcome": "converged", "message": "m", "exit_status": 0}, 0, "converged, exit status 0"),
    ({"outcome": "converged", "message": "m", "exit_status": 4}, 4, "converged, exit status 4"),
    ({"outcome": "aborted", "message": "m", "exit_status": 5}, 5, "aborted, exit status 5"),
    ({"outcome": "converged", "message": "m"}, 0, "converged, exit status 0"),  # an older ground station
    ({"outcome": "converged", "exit_status": "4"}, 0, "exit status 0"),  # not a number: not trusted
    ({"outcome": "converged", "exit_status": 999}, 0, "exit status 0"),
    (None, 0, "ended"),
])
def test_watch_exits_with_the_missions_status(capsys, ending, status, said):
    from mission.cli.cmd_watch import _ended

    assert _ended("alpha", {"phase": "done", "ending": ending}, as_json=False) == status
    assert said in capsys.readouterr().out
    assert _ended("alpha", {"phase": "done", "ending": ending}, as_json=True) == status
    assert capsys.readouterr().out == ""  # --json prints snapshots only


def test_a_vehicle_resume_found_on_the_ground_is_accounted_for():
    """``resume`` keeps a vehicle of the stopped mission that is already down out of the formation (a
    ``lost`` entry with ``on_ground``): recovering a mission whose vehicles had all landed exits 0."""
    down = [{"sysid": s, "reason": "left", "detail": "on the ground (disarmed)", "phase": "resume",
             "on_ground": True} for s in (1, 2)]
    assert MissionResult(outcome="recovered", lost=down).exit_status == EXIT_OK
    in_rtl = {"sysid": 3, "reason": "left", "detail": "in RTL", "phase": "resume", "on_ground": False}
    assert MissionResult(outcome="recovered", lost=[*down, in_rtl]).exit_status == EXIT_VEHICLE_LOST
