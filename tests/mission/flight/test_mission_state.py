"""The mission's state (:class:`mission.flight.state.MissionState`): status changes, losses, views.

Unit: a vehicle's status changes in one method, each change is a ``status_change`` record of
the mission log (unchanged statuses are not logged), unknown sysids are refused, item assignment
on the status board is the same method, the readers' views cannot be written, losses and
re-admissions keep the sets consistent, and the coordinator's state attributes are read-only.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from estimator.estimate import SourceEstimate
from mission.flight.state import MissionState, VehicleLoss
from mission.telemetry.mission_log import MissionLog, read_mission_log


class _Clock:
    def __init__(self, t_s: float = 100.0):
        self.t_s = t_s

    def time(self) -> float:
        return self.t_s


def _state(tmp_path, sysids=(1, 2, 3, 4)):
    clock = _Clock()
    log = MissionLog(tmp_path / "m.jsonl", clock)
    return MissionState(sysids, clock=clock, log=log), log, clock


def _changes(log):
    log.write("end")                                      # an empty log is not a mission log
    log.close()
    return [r for r in read_mission_log(log.path) if r["type"] == "status_change"]


def test_status_changes_are_logged_with_previous_reason_and_phase(tmp_path):
    state, log, clock = _state(tmp_path)
    state.set_phase("takeoff")
    state.set_status(2, "taking off")
    clock.t_s = 101.5
    state.set_status(2, "holding", reason="at its layer")
    state.set_status(2, "holding")                          # unchanged: not a change, not logged
    assert state.status[2] == "holding" and state.status[1] == "pending"
    got = [(r["t_s"], r["sysid"], r["previous"], r["status"], r["reason"], r["phase"]) for r in _changes(log)]
    assert got == [(100.0, 2, "pending", "taking off", None, "takeoff"),
                   (101.5, 2, "taking off", "holding", "at its layer", "takeoff")]


def test_unknown_sysids_are_refused(tmp_path):
    state, log, _ = _state(tmp_path)
    with pytest.raises(ValueError, match="vehicle 9 is not in the plan"):
        state.set_status(9, "connected")
    with pytest.raises(ValueError):
        state.declare_lost(VehicleLoss(9, "link", "silent", 1.0, 0.5))
    assert 9 not in state.status and _changes(log) == []


def test_item_assignment_on_the_board_is_set_status(tmp_path):
    state, log, _ = _state(tmp_path)
    state.status[3] = "in formation"
    with pytest.raises(ValueError):
        state.status[7] = "in formation"
    assert [(r["sysid"], r["status"]) for r in _changes(log)] == [(3, "in formation")]


def test_views_cannot_be_written(tmp_path):
    state, _, _ = _state(tmp_path)
    state.set_formation({1: [1.0, 0.0, 0.0]}, layer_alt_m={1: 8.0})
    with pytest.raises(TypeError):
        state.lost[1] = None
    with pytest.raises(TypeError):
        state.slot_offsets[1] = np.zeros(3)
    with pytest.raises(AttributeError):
        state.airborne.add(1)
    with pytest.raises(AttributeError):
        state.phase = "seek"
    with pytest.raises(ValueError, match="unknown phase"):
        state.set_phase("dancing")


def test_loss_and_readmission_keep_the_sets_consistent(tmp_path):
    state, log, clock = _state(tmp_path)
    state.set_airborne(1, "taking off")
    state.declare_lost(VehicleLoss(1, "link", "no frame for 1.2 s", 10.0, 8.8, "seek"), "lost (link)")
    assert 1 in state.lost and 1 in state.released and 1 not in state.airborne
    state.came_back(1, 12.0, readmit=True)
    assert state.lost[1].came_back_s == 12.0 and state.lost[1].readmit_pending
    clock.t_s = 13.0
    state.readmit(1, clock.time())
    assert 1 not in state.lost and 1 not in state.released and 1 in state.airborne
    assert state.readmitted == [{"sysid": 1, "lost_s": 10.0, "came_back_s": 12.0, "readmitted_s": 13.0}]
    assert [r["status"] for r in _changes(log)] == ["taking off", "lost (link)", "re-admitted"]


def test_retired_board_and_seek_progress(tmp_path):
    state, _log, _ = _state(tmp_path)
    info = SimpleNamespace(sysid=4, reason="noisy")
    state.retire(info, status="sensor retired: at the centre")
    assert state.retired[4] is info and state.status[4] == "sensor retired: at the centre"
    state.record_iteration(1, np.array([0.1, 0.0, 0.0]), 0.5, None, None)
    assert state.estimate_enu is None and state.estimate_region95_m is None and state.estimate_basis is None
    state.record_iteration(2, np.array([0.1, 0.0, 0.0]), 0.25, SourceEstimate(np.ones(3), 0.4, "b"), 0.2)
    assert state.iteration == 2 and state.distance_flown_m == pytest.approx(0.75) and state.spread_m == 0.2
    assert state.estimate_enu.tolist() == [1.0, 1.0, 1.0] and state.estimate_region95_m == 0.4
    assert state.estimate_basis == "b"
    with pytest.raises(TypeError, match="SourceEstimate or None"):
        state.record_iteration(3, np.zeros(3), 0.0, np.ones(3), 0.2)  # a bare point: never without its region


def test_the_coordinator_has_no_mirror_of_the_state_and_the_state_is_read_only():
    from mission.flight.coordinator import Coordinator
    from mission.sim.embedded import embedded_plan

    ports = {"udp_base_port": 20000, "udp_bind_base_port": 20100, "tcp_base_port": 0, "zenoh_port": 20200}
    co = Coordinator(embedded_plan(4, ports), clock=_Clock())
    assert co.state.phase == "idle" and dict(co.state.status) == {s: "pending" for s in (1, 2, 3, 4)}
    for name in ("phase", "status", "lost", "iteration", "centre_enu", "interrupts", "land_commanded",
                 "mission_checks", "final_result", "still_armed"):
        assert not hasattr(co, name), name  # one place: co.state
        with pytest.raises(AttributeError, match="no setter"):
            setattr(co.state, name, None)


def test_the_end_of_a_mission_is_mission_state(tmp_path):
    state, _log, _ = _state(tmp_path)
    state.note_interrupt("SIGINT")
    state.note_interrupt("SIGTERM")
    assert state.interrupts == ("SIGINT", "SIGTERM")
    state.add_mission_check("readings", True, "a reading from each")
    state.add_mission_check("zenoh", False, "no session", first=True)
    assert [c["name"] for c in state.mission_checks] == ["zenoh", "readings"]
    state.mission_checks[0]["ok"] = True  # a copy: the state is unchanged
    assert state.mission_checks[0] == {"name": "zenoh", "ok": False, "detail": "no session"}
    state.clear_mission_checks()
    assert state.mission_checks == ()
    state.mark_land_commanded(2)
    assert state.land_commanded == frozenset({2})
    with pytest.raises(ValueError, match="not in the plan"):
        state.mark_land_commanded(99)
    entries = [{"sysid": 3, "state": "armed on the ground"}]
    state.set_still_armed(entries)
    entries[0]["sysid"] = 4
    assert state.still_armed == ({"sysid": 3, "state": "armed on the ground"},)
    assert state.final_result is None
    result = SimpleNamespace(outcome="converged")
    state.finish(result)
    assert state.final_result is result
