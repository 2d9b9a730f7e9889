"""A vehicle lost by its link and heard again is judged on fresh state (``mission.flight.faults.loss.LossMonitor``).

Found on real PX4 SIH (tests/sitl/test_sitl_faults_px4.py): the cut vehicle came down by itself and
disarmed; when its link was restored the first frames back were positions, while its mode and
armed flag were still those from before the cut, so the ground station said "mode OFFBOARD" and
commanded a disarmed vehicle to land. The judgement now waits for a HEARTBEAT heard after the
loss, and a disarmed vehicle is kept out without a command.
"""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.loss import LossMonitor
from mission.flight.motion import GateMotion
from mission.flight.state import MissionState, VehicleLoss


class _Clock:
    def __init__(self):
        self.now = 100.0

    def time(self) -> float:
        return self.now


class _Vehicle:
    """What the judgement reads of a vehicle link; ``land`` counted."""

    def __init__(self, *, mode: str, armed: bool, alt_m: float, heartbeat_s: float | None):
        self.flavour = "px4"
        self.state = SimpleNamespace(mode=mode, armed=armed, relative_alt_m=alt_m, last_heartbeat_s=heartbeat_s)
        self.status_since_s, self.statustexts = None, []  # no mode change seen, no STATUSTEXT heard
        self.lands = 0

    def link_age_s(self) -> float:
        return 0.05

    async def land(self) -> None:
        self.lands += 1


def _co(readmit: bool = True):
    clock = _Clock()
    state = MissionState([1, 2, 3, 4, 5], clock=clock)
    state.set_phase("seek")
    loss = VehicleLoss(sysid=5, reason="link", detail="silent", detected_s=90.0, since_s=89.0, phase="seek")
    state.declare_lost(loss, status="lost")
    events: list[str] = []
    co = SimpleNamespace(plan=SimpleNamespace(faults=SimpleNamespace(readmit=readmit), return_behaviour="land"),
                         state=state, clock=clock,
                         event=lambda message, **kw: events.append(message))
    return co, loss, events


async def _maybe_came_back(co, v, loss, now):
    """The loss monitor's judgement, built from the test's services (no coordinator), with the
    mission's own ``keep_out`` as its motion."""
    events = SimpleNamespace(event=co.event)
    motion = GateMotion(co.state, None, lambda: None, lambda: None, co.clock, events, None,
                        return_behaviour=co.plan.return_behaviour, min_separation_m=1.5, max_speed_m_s=3.0,
                        arrival_tol_m=0.35)
    monitor = LossMonitor(co.state, None, lambda: None, co.clock, FaultsPlan(readmit=co.plan.faults.readmit),
                          co.plan.return_behaviour, motion, events, lambda line: None)
    await monitor._maybe_came_back(v, loss, now)


def test_no_judgement_before_a_heartbeat_after_the_loss():
    """Positions back, no HEARTBEAT since the loss (mode and armed flag from before it): no decision."""
    co, loss, events = _co()
    v = _Vehicle(mode="OFFBOARD", armed=True, alt_m=0.0, heartbeat_s=88.5)
    asyncio.run(_maybe_came_back(co, v, loss, 100.0))
    assert loss.came_back_s is None and events == [] and v.lands == 0


def test_disarmed_on_the_ground_is_kept_out_without_a_command():
    co, loss, events = _co()
    v = _Vehicle(mode="OFFBOARD", armed=False, alt_m=0.0, heartbeat_s=99.9)
    asyncio.run(_maybe_came_back(co, v, loss, 100.0))
    assert loss.came_back_s == 100.0 and not loss.readmit_pending
    assert v.lands == 0
    assert len(events) == 1 and "kept out" in events[0] and "disarmed" in events[0], events
    assert "commanded" not in events[0].replace("not commanded", ""), events
    assert co.state.status[5] == "lost (back, on the ground)"


@pytest.mark.parametrize("readmit", [True, False])
def test_armed_in_the_air_is_readmitted_or_landed(readmit):
    co, loss, events = _co(readmit)
    v = _Vehicle(mode="POSCTL", armed=True, alt_m=9.0, heartbeat_s=99.9)
    asyncio.run(_maybe_came_back(co, v, loss, 100.0))
    assert loss.came_back_s == 100.0
    assert loss.readmit_pending is readmit
    assert v.lands == (0 if readmit else 1)
    assert ("re-admitted at the next iteration" in events[0]) is readmit, events
