"""A vehicle lost by its link and heard again is judged on its first heartbeat since the loss, not on
the mode it had before the cut (``mission.flight.faults.loss.LossMonitor``). On ArduCopter SITL the
link came back 0.08 s after the vehicle had switched to LAND by itself: a position frame arrived
first, the last heartbeat still said GUIDED, and the ground station logged it re-admissible
(tests/sitl/test_sitl_faults_ardupilot_link.py, docs/faults.md)."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

from mission.core.plan_types import FaultsPlan
from mission.flight.faults.loss import LossMonitor
from mission.flight.state import VehicleLoss


class _Co:
    """The mission state and the events, as a LossMonitor is handed them (no coordinator)."""

    def __init__(self):
        self.phase = "seek"
        self.came_back, self.events = [], []

    def event(self, message, level="info", **fields):
        self.events.append(message)

    def monitor(self) -> LossMonitor:
        state = SimpleNamespace(phase="seek", came_back=self._came_back, readiness={})
        return LossMonitor(state, None, lambda: None, None, FaultsPlan(readmit=True), "land", None, self,
                           self.events.append)

    def _came_back(self, sysid, now, readmit):
        self.came_back.append((sysid, now, readmit))


def _vehicle(last_heartbeat_s: float):
    state = SimpleNamespace(armed=True, mode="GUIDED", relative_alt_m=12.0, last_heartbeat_s=last_heartbeat_s)
    return SimpleNamespace(sysid=3, flavour="ardupilot", state=state, link_age_s=lambda: 0.05,
                           status_since_s=None, statustexts=[])


def _loss():
    return VehicleLoss(3, "link", "no MAVLink frame for 1.02 s", 100.0, 99.0, "seek")


def test_heard_again_before_a_fresh_heartbeat_is_not_judged_yet():
    co, loss = _Co(), _loss()
    asyncio.run(co.monitor()._maybe_came_back(_vehicle(last_heartbeat_s=98.9), loss, 110.0))
    assert co.came_back == [] and co.events == [] and loss.came_back_s is None


def test_heard_again_with_a_fresh_heartbeat_is_judged():
    co, loss = _Co(), _loss()
    asyncio.run(co.monitor()._maybe_came_back(_vehicle(last_heartbeat_s=109.8), loss, 110.0))
    assert co.came_back == [(3, 110.0, True)]
    assert "re-admitted at the next iteration" in co.events[0]
