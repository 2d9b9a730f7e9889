"""Preflight's wait for MAV_STATE_STANDBY (``mission.flight.phases.connect.wait_standby``): a booting
autopilot is waited for until the deadline; one that says why it will not arm (a ``Preflight
Fail`` / ``PreArm:`` STATUSTEXT, or the SYS_STATUS pre-arm bit unhealthy) for
``REFUSAL_SETTLE_S`` in a row is judged then, with its reason, not at the deadline (PX4 SIH
whose pre-arm checks fail stays in MAV_STATE_UNINIT for good: 30 s were waited for nothing)."""
from __future__ import annotations

import asyncio

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.flight.phases.connect import REFUSAL_SETTLE_S, standby_refusal, wait_standby
from mission.vehicle.prearm import PrearmStatus

_UNINIT, _STANDBY = 0, 3
_PREARM = mav.MAV_SYS_STATUS_PREARM_CHECK
_MAG = mav.MAV_SYS_STATUS_SENSOR_3D_MAG


class _Clock:
    def __init__(self):
        self.t = 0.0
        self.at: list = []  # (time, callback) run once the clock reaches the time

    def time(self):
        return self.t

    async def sleep(self, dt):
        self.t += dt
        for when, fn in [a for a in self.at if a[0] <= self.t]:
            self.at.remove((when, fn))
            fn()
        await asyncio.sleep(0)


class _Vehicle:
    def __init__(self, status: int | None):
        self.state = type("S", (), {"armed": False, "system_status": status})()
        self.prearm = PrearmStatus("px4")


def _sys_status(enabled: int, health: int):
    return mav.MAVLink_sys_status_message(enabled, enabled, health, 0, 12000, -1, 80, 0, 0, 0, 0, 0, 0)


def _text(s: str):
    return mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, s.encode())


def _run(v, clock, deadline_s=30.0):
    return asyncio.run(wait_standby(v, clock, deadline_s))


def test_a_refusal_text_ends_the_wait_with_the_autopilots_words():
    clock, v = _Clock(), _Vehicle(_UNINIT)
    clock.at.append((1.0, lambda: v.prearm.on_statustext(
        _text("Preflight Fail: Found 1 compass (required: 2)"), clock.t)))
    reason = _run(v, clock)
    assert reason == "autopilot says: 'Preflight Fail: Found 1 compass (required: 2)'"
    assert 1.0 + REFUSAL_SETTLE_S <= clock.t <= 1.0 + REFUSAL_SETTLE_S + 0.5  # not the 30 s deadline


def test_the_prearm_bit_unhealthy_ends_the_wait_too():
    clock, v = _Clock(), _Vehicle(_UNINIT)
    v.prearm.on_sys_status(_sys_status(_PREARM | _MAG, 0))
    reason = _run(v, clock)
    assert "PREARM_CHECK unhealthy" in reason
    assert REFUSAL_SETTLE_S <= clock.t <= REFUSAL_SETTLE_S + 0.5


def test_a_booting_autopilot_is_waited_for_even_if_it_says_why_for_a_moment():
    clock, v = _Clock(), _Vehicle(_UNINIT)
    v.prearm.on_sys_status(_sys_status(_PREARM, 0))                       # pre-arm failing at boot...
    clock.at.append((1.0, lambda: v.prearm.on_sys_status(_sys_status(_PREARM, _PREARM))))  # ...for 1 s
    clock.at.append((6.0, lambda: setattr(v.state, "system_status", _STANDBY)))
    assert _run(v, clock) is None
    assert 6.0 <= clock.t <= 6.5


def test_an_autopilot_that_says_nothing_is_waited_for_to_the_deadline():
    clock, v = _Clock(), _Vehicle(_UNINIT)
    v.prearm.on_sys_status(_sys_status(_PREARM, _PREARM))
    assert _run(v, clock, deadline_s=12.0) is None
    assert 12.0 <= clock.t <= 12.5


@pytest.mark.parametrize("status, armed", [(_STANDBY, False), (None, False), (_UNINIT, True)])
def test_standby_armed_or_unknown_is_not_waited_for(status, armed):
    clock, v = _Clock(), _Vehicle(status)
    v.state.armed = armed
    v.prearm.on_statustext(_text("Preflight Fail: Found 1 compass (required: 2)"), 0.0)
    assert _run(v, clock) is None and clock.t == 0.0


def test_an_old_text_is_not_a_reason():
    v = _Vehicle(_UNINIT)
    v.prearm.on_statustext(_text("Preflight Fail: ekf2 missing data"), 0.0)
    assert standby_refusal(v, 1.0) is not None and standby_refusal(v, 1000.0) is None
