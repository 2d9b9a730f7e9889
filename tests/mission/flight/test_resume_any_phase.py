"""``swarmseek resume`` takes over a mission whose log ends in any phase while vehicles are
airborne, and brings them home: a ground station stopped during the return or after
the finish, vehicles hovering in GUIDED with nobody flying them."""
from __future__ import annotations

import asyncio

import pytest

from mission.cli.cmd_resume import resume
from mission.flight.phases.resume import ResumeError, load_resume_state
from mission.telemetry.mission_log import read_mission_log

from tests.support.fly_helpers import run_fleet
from tests.support.invariants import abandoned
from tests.mission.flight.test_abandon import _fly_with, _settle, _setup, _wait_phase

pytestmark = pytest.mark.timeout(400)


def _stop_in(phase, extra_s):
    """An action that stops the ground station (no return) ``extra_s`` into ``phase``."""
    async def action(co, task):
        co.return_on_interrupt = False
        if phase == "finish":  # the return starts right after the finish: hold it there a moment
            original = co.return_safely

            async def later():
                await co.clock.sleep(2.0)
                await original()
            co.return_safely = later
        await _wait_phase(co, phase, extra_s)
        task.cancel()
    return action


@pytest.mark.parametrize("phase, extra_s", [("return", 3.0), ("finish", 0.0), ("seek", 1.0)])
def test_resume_brings_home_what_a_stopped_mission_left_flying(tmp_path, phase, extra_s):
    plan, fleet = _setup("ardupilot", return_behaviour="rtl", max_iterations=4)
    log_path = tmp_path / "m.jsonl"
    try:
        run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, _stop_in(phase, extra_s), world))
        flying = [v.sysid for v in fleet.vehicles if v.armed and not v.autopilot.mc.landed]
        assert flying, "the stop left nothing flying: the test proves nothing"
        state = load_resume_state(log_path)
        assert state.go_on == (phase == "seek")
        result = run_fleet(fleet, lambda world: resume(log_path, clock=fleet.clock, tlog=False, world=world))
        run_fleet(fleet, lambda _world: _settle(fleet, 120.0))
        assert not abandoned(fleet)
        assert not any(v.armed for v in fleet.vehicles), [v.mode_name for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert not result.airborne_left
    if phase == "seek":
        assert result.outcome in ("converged", "max_iterations"), result.message
    else:
        assert result.outcome == "recovered" and "bringing them home" in result.message
    summaries = [r for r in read_mission_log(log_path) if r["type"] == "summary"]
    assert len(summaries) == 2 and summaries[-1]["outcome"] == result.outcome


def test_resume_of_a_mission_whose_vehicles_are_all_down_does_nothing(tmp_path):
    plan, fleet = _setup("ardupilot", return_behaviour="land", max_iterations=2)
    log_path = tmp_path / "m.jsonl"

    async def nothing(co, task):
        await asyncio.sleep(0)

    try:
        run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, nothing, world))
        run_fleet(fleet, lambda _world: _settle(fleet, 30.0))
        result = run_fleet(fleet, lambda world: resume(log_path, clock=fleet.clock, tlog=False, world=world))
    finally:
        fleet.stop()
    assert result.outcome == "recovered" and "nothing to bring home" in result.message


def test_resume_refuses_a_log_stopped_before_the_takeoff(tmp_path):
    import json

    from mission.flight.coordinator import _plan_json

    plan, fleet = _setup("ardupilot")
    fleet.stop()
    log = tmp_path / "m.jsonl"
    log.write_text("\n".join(json.dumps(r) for r in (
        {"t_s": 0, "type": "plan", "plan": _plan_json(plan)},
        {"t_s": 1, "type": "phase", "phase": "preflight"},
        {"t_s": 2, "type": "phase", "phase": "aborted"},
        {"t_s": 3, "type": "phase", "phase": "done"})) + "\n")
    with pytest.raises(ResumeError, match="stopped before the takeoff"):
        load_resume_state(log)
