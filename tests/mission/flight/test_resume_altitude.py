"""``resume`` judges a vehicle "flying" on its altitude, so it waits for one.

Seen on real ArduCopter SITL (tests/sitl/test_sitl_faults_ardupilot.py): the resumed ground station got
LOCAL_POSITION_NED (a position: ``position_ok``) before the home and the first GLOBAL_POSITION_INT,
so the altitude above home was still unknown and 4 of 5 vehicles hovering 13 m up were declared
"not flying", then landed where they were. :meth:`mission.flight.phases.resume.Resume.why_not_flying` now waits
for the altitude as well as the position.
"""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

from mission.flight.phases.resume import Resume
from mission.flight.state import MissionError

_ORIGIN = (-35.363261, 149.165230, 584.0)


class _Vehicle:
    flavour = "ardupilot"

    def __init__(self):
        self.state = SimpleNamespace(position_ok=True, relative_alt_m=None, armed=True, mode="GUIDED")

    async def wait_home(self, timeout_s: float):
        return _ORIGIN


class _Waiter:
    async def wait_until(self, predicate, timeout_s: float, what: str, poll_s: float = 0.01) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not predicate():
            if loop.time() > deadline:
                raise MissionError(f"timed out waiting for {what}")
            await asyncio.sleep(poll_s)


def _why_not_flying(vehicle, sysid):
    """:meth:`Resume.why_not_flying` of a resume over just ``vehicle`` (as ``sysid``)."""
    homes = {}
    resume = Resume(SimpleNamespace(origin=_ORIGIN), SimpleNamespace(set_home=homes.__setitem__),
                    SimpleNamespace(vehicles={sysid: vehicle}), None, None, _Waiter(), None, None, None, None, None)
    return resume.why_not_flying(sysid)


def test_a_hovering_vehicle_whose_altitude_comes_after_its_position_is_flying():
    v = _Vehicle()

    async def main():
        async def altitude_later():
            await asyncio.sleep(0.2)
            v.state.relative_alt_m = 13.0
        task = asyncio.create_task(altitude_later())
        reason = await _why_not_flying(v, 7)
        await task
        return reason

    assert asyncio.run(main()) is None
    assert v.state.relative_alt_m == 13.0


def test_a_vehicle_on_the_ground_is_still_not_flying():
    v = _Vehicle()
    v.state.relative_alt_m = 0.1
    assert asyncio.run(_why_not_flying(v, 7)) == "not flying"
