"""What ``swarmseek resume`` does with every way a mission log can end (docs/faults.md, "What
resume does with each ending"; mission.flight.phases.resume_endings).

The logs are a real lock-step mission's (``swarmseek run --n 4``) cut at each phase, or that log
with the closing records each ending writes (the formats of mission.flight.coordinator and
mission_end). The last test resumes, against a live mock fleet, a log that ends ``aborted`` by an
internal error while the vehicles hover: it must bring them home, not fly on into the seek.
"""
from __future__ import annotations

import json

import pytest

from mission.cli import main as cli_main
from mission.flight.phases.resume import ResumeError, load_resume_state
from mission.flight.phases.resume_endings import ENDINGS, classify_ending


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    """The records of a whole lock-step mission (4 vehicles, 6 iterations)."""
    log_dir = tmp_path_factory.mktemp("real") / "run"
    code = cli_main(["run", "--n", "4", "--seed", "1", "--max-iterations", "6", "--json", "--no-tlog",
                     "--log-dir", str(log_dir)])
    assert code in (0, 1)
    lines = (log_dir / "mission.jsonl").read_text().splitlines()
    return lines


def _index(lines, pred) -> int:
    return next(i for i, line in enumerate(lines) if pred(json.loads(line)))


def _phase_at(lines, phase) -> int:
    return _index(lines, lambda r: r["type"] == "phase" and r.get("phase") == phase)


def _cut_in(lines, phase, extra=1) -> list[str]:
    """The log cut ``extra`` records after the ``phase`` record."""
    return lines[:_phase_at(lines, phase) + 1 + extra]


def _in_seek(lines, iterations=3) -> list[str]:
    its = [i for i, line in enumerate(lines) if json.loads(line)["type"] == "iteration"]
    return lines[:its[iterations - 1] + 1]


def _rec(**fields) -> str:
    return json.dumps({"t_s": 999.0, **fields})


def _closing(*records) -> list[str]:
    return [_rec(**r) for r in records]


_DONE = ({"type": "phase", "phase": "done"}, {"type": "summary", "outcome": "x", "message": "x"})
_RETURN = ({"type": "phase", "phase": "return", "behaviour": "land"},)


def _write(tmp_path, lines, name="m.jsonl"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _ending(tmp_path, lines):
    state = load_resume_state(_write(tmp_path, lines))
    assert classify_ending([json.loads(x) for x in lines if x.strip().startswith("{") and x.strip().endswith("}")]).go_on \
        == state.go_on
    return state


@pytest.mark.parametrize("phase", ["takeoff", "assemble"])
def test_cut_in_takeoff_or_assembly_seeks_on(tmp_path, real_log, phase):
    state = _ending(tmp_path, _cut_in(real_log, phase))
    assert (state.ending, state.go_on, state.iteration) == ("cut", True, 0)


def test_cut_in_the_seek_seeks_on_from_the_last_iteration(tmp_path, real_log):
    state = _ending(tmp_path, _in_seek(real_log, 3))
    assert (state.ending, state.go_on, state.iteration) == ("cut", True, 3)


def test_a_record_cut_in_the_middle_is_skipped(tmp_path, real_log):
    lines = _in_seek(real_log, 3)
    half = real_log[len(lines)][: len(real_log[len(lines)]) // 2]  # the 4th iteration, half written
    path = tmp_path / "m.jsonl"
    path.write_text("\n".join(lines) + "\n" + half)
    state = load_resume_state(path)
    assert (state.ending, state.go_on, state.iteration) == ("cut", True, 3)


@pytest.mark.parametrize("outcome", ["converged", "max_iterations", "stopped_at_fence", "too_few_vehicles"])
@pytest.mark.parametrize("after", ["nothing", "return", "done"])
def test_a_finished_seek_brings_home_whatever_followed(tmp_path, real_log, outcome, after):
    lines = _in_seek(real_log, 3) + _closing({"type": "phase", "phase": "finish", "outcome": outcome})
    lines += {"nothing": [], "return": _closing(*_RETURN), "done": _closing(*_RETURN, *_DONE)}[after]
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on) == ("finished", False)


def test_the_real_complete_log_brings_home(tmp_path, real_log):
    state = _ending(tmp_path, real_log)
    assert (state.ending, state.go_on, state.last_phase) == ("finished", False, "done")


def test_cut_in_the_real_return_brings_home(tmp_path, real_log):
    state = _ending(tmp_path, _cut_in(real_log, "return", 0))
    assert (state.ending, state.go_on, state.last_phase) == ("finished", False, "return")


def test_an_operators_landing_order_cut_in_its_return_brings_home(tmp_path, real_log):
    lines = _in_seek(real_log, 2) + _closing({"type": "phase", "phase": "return", "behaviour": "land (operator)"})
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on) == ("returning", False)


@pytest.mark.parametrize("reason", [
    "unexpected error in phase seek: RuntimeError: boom",
    "no usable readings for 20 iterations (rejections: 0)",
    "operator ctl aborted (abort)",
    "seek needs at least 4 vehicles in formation, have 3",
])
@pytest.mark.parametrize("after", ["nothing", "return", "done"])
def test_an_aborted_mission_brings_home(tmp_path, real_log, reason, after):
    lines = _in_seek(real_log, 3) + _closing({"type": "phase", "phase": "aborted", "reason": reason})
    lines += {"nothing": [], "return": _closing(*_RETURN), "done": _closing(*_RETURN, *_DONE)}[after]
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on) == ("aborted", False)


@pytest.mark.parametrize("phase", ["takeoff", "assemble"])
def test_an_abort_in_the_takeoff_or_assembly_brings_home(tmp_path, real_log, phase):
    lines = _cut_in(real_log, phase) + _closing(
        {"type": "phase", "phase": "aborted", "reason": f"unexpected error in phase {phase}: BrokenPipeError: x"})
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on) == ("aborted", False)


def test_an_interrupt_with_the_return_brings_home(tmp_path, real_log):
    lines = _in_seek(real_log, 3) + _closing(
        {"type": "phase", "phase": "aborted", "reason": "interrupted (SIGINT)", "returning": True}, *_RETURN, *_DONE)
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on) == ("interrupted", False)


@pytest.mark.parametrize("new_format", [True, False])
def test_a_ground_station_told_to_just_stop_seeks_on(tmp_path, real_log, new_format):
    aborted = {"type": "phase", "phase": "aborted", "reason": "interrupted"}
    if new_format:
        aborted["returning"] = False
    event = {"type": "event", "level": "error",
             "message": "mission interrupted: the ground station stops; the vehicles do what their autopilots do"}
    lines = _in_seek(real_log, 3) + _closing(aborted, event, *_DONE)
    state = _ending(tmp_path, lines)
    assert (state.ending, state.go_on, state.iteration) == ("stopped", True, 3)


def test_a_resumed_session_cut_while_reconnecting_keeps_the_decision_before(tmp_path, real_log):
    plan = json.loads(real_log[_index(real_log, lambda r: r["type"] == "plan")])
    stopped = _in_seek(real_log, 3) + _closing(
        {"type": "phase", "phase": "aborted", "reason": "interrupted", "returning": False}, *_DONE)
    resumed = _closing({**plan, "resumed": True}, {"type": "phase", "phase": "connect"})
    assert _ending(tmp_path, stopped + resumed).ending == "stopped"
    # the resumed session seeks, then is cut: seek on; it finishes: bring home
    seeking = resumed + _closing({"type": "phase", "phase": "seek"})
    assert _ending(tmp_path, stopped + seeking).ending == "cut"
    finished = seeking + _closing({"type": "phase", "phase": "finish", "outcome": "converged"})
    assert _ending(tmp_path, stopped + finished).ending == "finished"
    # an aborted first session, resumed to bring home and cut while reconnecting: still home
    aborted = _in_seek(real_log, 3) + _closing({"type": "phase", "phase": "aborted", "reason": "boom"})
    assert _ending(tmp_path, aborted + resumed).go_on is False


@pytest.mark.parametrize("phase", ["connect", "preflight"])
def test_a_log_stopped_before_the_takeoff_is_refused(tmp_path, real_log, phase):
    with pytest.raises(ResumeError, match="stopped before the takeoff"):
        load_resume_state(_write(tmp_path, _cut_in(real_log, phase, 0)))


def test_no_plan_or_no_log_is_refused(tmp_path, real_log):
    no_plan = [x for x in real_log if json.loads(x)["type"] != "plan"]
    with pytest.raises(ResumeError, match="no plan record"):
        load_resume_state(_write(tmp_path, no_plan))
    with pytest.raises(ResumeError, match="not a swarmseek mission log"):
        load_resume_state(_write(tmp_path, [""], "empty.jsonl"))


def test_every_ending_of_the_table_is_tested():
    assert set(ENDINGS) == {"finished", "returning", "aborted", "interrupted", "stopped", "cut", "before_takeoff"}
    assert [k for k, go_on in ENDINGS.items() if go_on] == ["stopped", "cut"]


@pytest.mark.timeout(400)
def test_resume_of_a_log_aborted_by_an_internal_error_brings_the_hovering_vehicles_home(tmp_path):
    """The case seen: the ground station died of an internal error in the seek (its log ends
    ``aborted: unexpected error ...``, nothing after) while the vehicles hover in GUIDED."""
    from mission.cli.cmd_resume import resume
    from mission.telemetry.mission_log import read_mission_log

    from tests.support.fly_helpers import run_fleet
    from tests.support.invariants import abandoned
    from tests.mission.flight.test_abandon import _fly_with, _settle, _setup
    from tests.mission.flight.test_resume_any_phase import _stop_in

    plan, fleet = _setup("ardupilot", return_behaviour="land", max_iterations=6)
    log_path = tmp_path / "m.jsonl"
    try:
        run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, _stop_in("seek", 1.0), world))
        flying = [v.sysid for v in fleet.vehicles if v.armed and not v.autopilot.mc.landed]
        assert len(flying) == 4, "the stop left nothing flying: the test proves nothing"
        lines = log_path.read_text().splitlines()
        last_seek = max(i for i, x in enumerate(lines) if json.loads(x)["type"] in ("iteration", "phase")
                        and json.loads(x).get("phase") in (None, "seek"))
        lines = lines[:last_seek + 1] + _closing(
            {"type": "phase", "phase": "aborted", "reason": "unexpected error in phase seek: RuntimeError: boom"})
        log_path.write_text("\n".join(lines) + "\n")
        state = load_resume_state(log_path)
        assert (state.ending, state.go_on) == ("aborted", False)
        iterations_before = sum(1 for r in read_mission_log(log_path) if r["type"] == "iteration")
        result = run_fleet(fleet, lambda world: resume(log_path, clock=fleet.clock, tlog=False, world=world))
        run_fleet(fleet, lambda _world: _settle(fleet, 60.0))
        assert not abandoned(fleet)
        assert not any(v.armed for v in fleet.vehicles), [v.mode_name for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert result.outcome == "recovered" and "bringing them home" in result.message, result.message
    records = read_mission_log(log_path)
    assert sum(1 for r in records if r["type"] == "iteration") == iterations_before  # no seek flown
    assert not result.airborne_left and not result.still_armed
