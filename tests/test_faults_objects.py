"""The fault responses of :mod:`mission.flight.faults` built from fake services, without a
Coordinator: each object is constructed with the narrow services its class docstring names
(``tests/faults_fakes.py``), and what it does shows in the mission state, the events and the
commands the fake vehicles received."""
from __future__ import annotations

import asyncio

import numpy as np
from faults_fakes import FakeClock, FakeGate, FakeMotion, FakeVehicle, Recorder, fleet_of, flying_state, ring

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.watchdog import Watchdog


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


async def _until(predicate, what: str, timeout_s: float = 10.0) -> None:
    """Yield to the loop until ``predicate()``; AssertionError after ``timeout_s`` (wall)."""
    async def _poll():
        while not predicate():
            await asyncio.sleep(0.01)
    try:
        await asyncio.wait_for(_poll(), timeout_s)
    except asyncio.TimeoutError:
        raise AssertionError(f"timed out waiting for {what}") from None


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
            await _until(lambda: state.reengaged.get(1), "vehicle 1 re-engaged")
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())
    assert vehicles[0].commands == ["mode OFFBOARD"] and state.reengaged[1] == 1
    assert vehicles[1].commands == [] and vehicles[2].commands == [] and vehicles[3].commands == []
    assert status.odometry > 0
    assert any("MAVLink frames rejected: " in m for m in rec.messages("warning"))
    assert any("vehicle 1 left OFFBOARD" in m for m in rec.messages("warning"))
