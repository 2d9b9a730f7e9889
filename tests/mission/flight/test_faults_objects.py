"""The fault responses of :mod:`mission.flight.faults` built from fake services, without a
Coordinator: each object is constructed with the narrow services its class docstring names
(``tests/faults_fakes.py``), and what it does shows in the mission state, the events and the
commands the fake vehicles received."""
from __future__ import annotations

import asyncio

import numpy as np
from tests.support.wait_helpers import wait_until_async
from tests.mission.flight.faults_fakes import (
    FakeClock,
    FakeGate,
    FakeMotion,
    FakeVehicle,
    FakeWaiter,
    Recorder,
    fleet_of,
    flying_state,
    ring,
)

from mission.core.plan_types import FaultsPlan, FormationPlan
from mission.flight.faults.loss import LossMonitor, Reformation
from mission.flight.faults.rejoin import Rejoin, pending_readmissions
from mission.flight.faults.retire import PARKED_STATUS, RetiredSensor, Retirement
from mission.flight.faults.watchdog import Watchdog
from mission.flight.state import VehicleLoss


class _Status:
    """The vehicles' status and the links' refusals (:class:`mission.flight.faults.watchdog.MissionStatus`)."""

    def __init__(self) -> None:
        self.odometry = 0

    def update_odometry(self) -> None:
        self.odometry += 1

    def vehicle_status(self) -> list[dict]:
        return []

    def link_rejections(self) -> dict[str, int]:
        return {"bad_crc": 2}

    def unknown_sysids(self) -> list[int]:
        return []


def test_the_watchdog_reengages_a_vehicle_in_hold_and_leaves_a_failsafe_alone():
    clock = FakeClock()
    state = flying_state(4, clock)
    vehicles = [FakeVehicle(s, ring(4)[s]) for s in range(1, 5)]
    vehicles[0].state.mode = "AUTO.LOITER"   # offboard lost: re-engaged
    vehicles[1].state.mode = "AUTO.RTL"      # a failsafe: the loss detection decides, never re-engaged
    vehicles[2].age_s = 5.0                  # silent: never re-engaged
    vehicles[2].state.mode = "AUTO.LOITER"
    gate = FakeGate({s: ring(4)[s] for s in range(1, 5)})
    rec, status = Recorder(), _Status()
    dog = Watchdog(state, fleet_of(vehicles), lambda: gate, clock, FaultsPlan(), status, None, 1.0, rec, rec.report)

    async def main():
        task = asyncio.create_task(dog.run(period_s=0.01))
        try:
            await wait_until_async(lambda: state.reengaged.get(1), 10.0, "vehicle 1 re-engaged", poll_s=0.01)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())
    assert vehicles[0].commands == ["mode OFFBOARD"] and state.reengaged[1] == 1
    assert vehicles[1].commands == [] and vehicles[2].commands == [] and vehicles[3].commands == []
    assert status.odometry > 0
    assert any("MAVLink frames rejected: " in m for m in rec.messages("warning"))
    assert any("vehicle 1 left OFFBOARD" in m for m in rec.messages("warning"))


def _monitor(n: int, readmit: bool = False):
    clock = FakeClock(100.0)
    state = flying_state(n, clock)
    vehicles = [FakeVehicle(s, ring(n)[s]) for s in range(1, n + 1)]
    gate = FakeGate({s: ring(n)[s] for s in range(1, n + 1)})
    rec, motion = Recorder(), FakeMotion(state, gate)
    monitor = LossMonitor(state, fleet_of(vehicles), lambda: gate, clock, FaultsPlan(readmit=readmit), "land",
                          motion, rec, rec.report)
    return clock, state, vehicles, gate, rec, motion, monitor


def _watch(monitor, predicate, what: str) -> None:
    async def main():
        task = asyncio.create_task(monitor.run(period_s=0.1))
        try:
            await wait_until_async(predicate, 10.0, what, poll_s=0.01)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())


def test_the_loss_monitor_declares_a_silent_vehicle_and_a_failsafe_lost():
    clock, state, vehicles, gate, rec, motion, monitor = _monitor(5)
    vehicles[1].age_s = 3.0                # silent for 3 s > link_timeout_s
    vehicles[3].state.mode = "AUTO.RTL"    # a failsafe, reported by 2 heartbeats
    _watch(monitor, lambda: {2, 4} <= set(state.lost), "vehicles 2 and 4 lost")
    assert state.lost[2].reason == "link" and state.lost[4].reason == "left"
    assert state.lost[2].latency_s == 3.0
    np.testing.assert_allclose(state.lost[2].last_setpoint_enu, ring(5)[2])
    assert gate.sysids == [1, 3, 5] and set(state.lost) == {2, 4}
    assert sum("lost:" in m for m in rec.messages("warning")) == 2


def test_the_loss_monitor_keeps_out_a_vehicle_heard_again_without_readmit():
    clock, state, vehicles, gate, rec, motion, monitor = _monitor(4)
    vehicles[0].age_s = 3.0
    _watch(monitor, lambda: 1 in state.lost, "vehicle 1 lost")
    vehicles[0].age_s = 0.0                # heard again, with a heartbeat since the loss
    vehicles[0].state.last_heartbeat_s = clock.time()
    _watch(monitor, lambda: motion.calls, "vehicle 1 kept out")
    assert motion.calls == [("keep_out", 1, "faults.readmit = false")]
    assert state.lost[1].came_back_s is not None and not state.lost[1].readmit_pending


def test_a_reformation_flies_the_survivors_to_new_slots_and_switches_an_odd_symmetric_formation():
    clock = FakeClock()
    state = flying_state(6, clock, kind="symmetric")
    vehicles = [FakeVehicle(s, ring(6)[s]) for s in range(1, 7)]
    gate = FakeGate({s: ring(6)[s] for s in range(1, 7) if s != 3})
    state.declare_lost(VehicleLoss(3, "left", "switched to AUTO.RTL", 0.0, 0.0, "seek"))
    rec, motion = Recorder(), FakeMotion(state, gate)
    reform = Reformation(state, fleet_of(vehicles), gate, clock, FormationPlan(radius_m=5.0), 1.5, motion, rec)
    survivors = asyncio.run(reform.reform(np.zeros(3), [1, 2, 3, 4, 5, 6]))
    assert survivors == [1, 2, 4, 5, 6]
    assert [c[:2] for c in motion.calls] == [("transfer_to", [1, 2, 4, 5, 6])]
    assert state.formation_kind == "cvt"
    assert any("switching to the CVT formation" in m for m in rec.messages("warning"))
    slots = np.array([state.slot_offsets[s] for s in survivors])
    np.testing.assert_allclose(np.linalg.norm(slots, axis=1), 5.0, atol=1e-6)
    gaps = [np.linalg.norm(a - b) for i, a in enumerate(slots) for b in slots[i + 1:]]
    assert min(gaps) > 1.5


def test_a_reformation_below_four_flies_nothing():
    clock = FakeClock()
    state = flying_state(4, clock)
    gate = FakeGate({s: ring(4)[s] for s in (1, 2, 3)})
    state.declare_lost(VehicleLoss(4, "link", "silent", 0.0, 0.0, "seek"))
    motion = FakeMotion(state, gate)
    reform = Reformation(state, fleet_of([]), gate, clock, FormationPlan(), 1.5, motion, Recorder())
    assert asyncio.run(reform.reform(np.zeros(3), [1, 2, 3, 4])) == [1, 2, 3] and motion.calls == []


def _returning(n: int, back: FakeVehicle):
    """``n`` flying vehicles and ``back`` (sysid n + 1) lost by its link and heard again, re-admissible."""
    clock = FakeClock(50.0)
    state = flying_state(n + 1, clock)
    vehicles = [FakeVehicle(s, ring(n + 1)[s]) for s in range(1, n + 1)] + [back]
    gate = FakeGate({s: ring(n + 1)[s] for s in range(1, n + 1)})
    state.declare_lost(VehicleLoss(n + 1, "link", "silent", 40.0, 39.0, "seek"))
    state.came_back(n + 1, 45.0, readmit=True)
    rec, motion, waiter = Recorder(), FakeMotion(state, gate), FakeWaiter()
    rejoin = Rejoin(state, fleet_of(vehicles), gate, clock, FaultsPlan(readmit=True), FormationPlan(radius_m=5.0),
                    1.5, motion, waiter, rec)
    return state, gate, rec, motion, waiter, rejoin


def test_a_returning_vehicle_is_reengaged_and_readmitted_into_a_grown_formation():
    back = FakeVehicle(5, [0.0, 0.0, 12.0], mode="AUTO.LOITER")
    state, gate, rec, motion, waiter, rejoin = _returning(4, back)
    assert pending_readmissions(state, FaultsPlan(readmit=True)) == [5]
    assert pending_readmissions(state, FaultsPlan(readmit=False)) == []
    members = asyncio.run(rejoin.readmit(np.zeros(3), [1, 2, 3, 4], [5]))
    assert members == [1, 2, 3, 4, 5]
    assert back.commands == ["mode OFFBOARD"] and waiter.waited == ["vehicle 5 in OFFBOARD"]
    assert 5 not in state.lost and 5 in gate.sysids and 5 not in state.reengaging
    assert [c[:2] for c in motion.calls] == [("transfer_to", [1, 2, 3, 4, 5])]
    assert state.readmitted[-1]["sysid"] == 5
    assert any("vehicle 5 re-admitted" in m for m in rec.messages())


def test_a_returning_vehicle_on_the_ground_is_kept_out():
    back = FakeVehicle(5, [0.0, 0.0, 0.0], armed=False, alt_m=0.0)
    state, gate, rec, motion, waiter, rejoin = _returning(4, back)
    assert asyncio.run(rejoin.readmit(np.zeros(3), [1, 2, 3, 4], [5])) == [1, 2, 3, 4]
    assert [c[:2] for c in motion.calls] == [("keep_out", 5)] and back.commands == []
    assert 5 not in gate.sysids


def test_a_goal_near_a_lost_vehicle_still_flying_rotates_the_slots():
    clock = FakeClock(10.0)
    state = flying_state(5, clock)
    centre = np.array([0.0, -6.0, 0.0])  # the next iteration's centre: slot 1's goal is next to the lost vehicle
    near = centre + ring(5)[1] * 1.05
    hovering = FakeVehicle(5, near, mode="AUTO.LOITER")  # lost by its link, hovering
    vehicles = [FakeVehicle(s, ring(5)[s]) for s in range(1, 5)] + [hovering]
    gate = FakeGate({s: ring(5)[s] for s in range(1, 5)})
    state.declare_lost(VehicleLoss(5, "link", "silent", 9.0, 8.0, "seek", last_setpoint_enu=near))
    rec, motion = Recorder(), FakeMotion(state, gate)
    rejoin = Rejoin(state, fleet_of(vehicles), gate, clock, FaultsPlan(), FormationPlan(radius_m=5.0), 1.5,
                    motion, FakeWaiter(), rec)
    before = {s: state.slot_offsets[s].copy() for s in range(1, 5)}
    ok = rejoin.clear_goals(centre, [1, 2, 3, 4])
    clearance = min(np.linalg.norm(centre + state.slot_offsets[s] - near) for s in range(1, 5))
    assert ok and clearance >= 1.5 + 0.5, clearance
    asyncio.run(rejoin.fly_rotation(centre, [1, 2, 3, 4], before))
    assert [c[:2] for c in motion.calls] == [("transfer_to", [1, 2, 3, 4])]
    assert any("formation rotated" in m for m in rec.messages())


def test_a_retired_sensor_parks_its_vehicle_at_the_centre_and_a_returning_retired_vehicle_is_kept_out():
    clock = FakeClock(30.0)
    state = flying_state(6, clock)
    vehicles = [FakeVehicle(s, ring(6)[s]) for s in range(1, 7)]
    fleet, gate = fleet_of(vehicles), FakeGate({s: ring(6)[s] for s in range(1, 7)})
    rec, motion = Recorder(), FakeMotion(state, gate)
    reformation = Reformation(state, fleet, gate, clock, FormationPlan(radius_m=5.0), 1.5, motion, rec)
    retirement = Retirement(state, fleet, gate, FaultsPlan(), reformation, motion, rec)
    assert retirement.make_watch(object(), [1, 2, 3, 4, 5, 6]) is not None
    info = RetiredSensor(3, "stuck", 0.05, 0.01, 12, 20, 30.0)
    sensing = asyncio.run(retirement.retire_sensor(np.zeros(3), [1, 2, 3, 4, 5, 6], info))
    assert sensing == [1, 2, 4, 5, 6] and state.retired[3] == info and state.status[3] == PARKED_STATUS
    assert [c[:2] for c in motion.calls] == [("transfer_to", [1, 2, 4, 5, 6, 3])]
    np.testing.assert_allclose(state.slot_offsets[3], 0.0)
    assert any("vehicle 3's sensor retired (stuck" in m for m in rec.messages("warning"))
    centre = np.array([1.0, 2.0, 12.0])
    goals = retirement.formation_goals(centre, sensing)
    assert sorted(goals) == [1, 2, 3, 4, 5, 6] and np.allclose(goals[3], centre)
    assert retirement.make_watch(object(), sensing) is None  # one parking place: the centre
    assert asyncio.run(retirement.keep_out_retired([3, 4])) == [4]
    assert motion.calls[-1] == ("keep_out", 3, "its sensor was retired")


def test_the_loss_monitor_marks_a_vehicle_heard_again_for_readmission():
    clock, state, vehicles, gate, rec, motion, monitor = _monitor(4, readmit=True)
    vehicles[2].age_s = 3.0
    _watch(monitor, lambda: 3 in state.lost, "vehicle 3 lost")
    vehicles[2].age_s = 0.0                # heard again, armed, in the air, not returning: re-admissible
    vehicles[2].state.last_heartbeat_s = clock.time()   # with a heartbeat since the loss
    _watch(monitor, lambda: state.lost[3].came_back_s is not None, "vehicle 3 heard again")
    assert state.lost[3].readmit_pending and motion.calls == []
    assert pending_readmissions(state, FaultsPlan(readmit=True)) == [3]


class _Log:
    def __init__(self) -> None:
        self.records: list[tuple[str, dict]] = []

    def write(self, kind: str, **fields) -> None:
        self.records.append((kind, fields))


class _Refusing(FakeVehicle):
    async def set_mode(self, mode: str) -> None:
        self.commands.append(f"mode {mode}")
        raise RuntimeError("MAV_RESULT_DENIED")


def test_the_watchdog_writes_status_records_and_reports_a_refused_reengagement():
    clock = FakeClock()
    state = flying_state(4, clock)
    vehicles = [_Refusing(1, ring(4)[1], mode="AUTO.LOITER")] + [FakeVehicle(s, ring(4)[s]) for s in (2, 3, 4)]
    gate = FakeGate({s: ring(4)[s] for s in range(1, 5)})
    rec, log = Recorder(), _Log()
    dog = Watchdog(state, fleet_of(vehicles), lambda: gate, clock, FaultsPlan(), _Status(), log, 1.0, rec,
                   rec.report)

    async def main():
        task = asyncio.create_task(dog.run(period_s=0.01))
        try:
            await wait_until_async(lambda: len(vehicles[0].commands) >= 2, 10.0, "a second attempt", poll_s=0.01)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())
    assert any("vehicle 1: could not re-engage OFFBOARD: MAV_RESULT_DENIED" in m for m in rec.messages("error"))
    assert state.reengaged.get(1, 0) == 0          # refused: not counted, retried (two attempts seen)
    assert log.records and log.records[0][0] == "status" and log.records[0][1]["phase"] == "seek"
