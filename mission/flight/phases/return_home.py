"""The return: back over the homes by layers (clear of lost vehicles), then land (or RTL),
staggered; an operator's ``land`` / ``rtl`` instead; or every vehicle landed where it is. Built by
:meth:`mission.flight.coordinator.Coordinator.return_phase`, run with ``await ReturnHome(...).run()``.
"""
from __future__ import annotations

import asyncio
from typing import Awaitable, Callable

from mission.core.plan_types import Plan
from mission.flight.control import MissionControl
from mission.flight.motion import retried, update_odometry
from mission.flight.services import Clock, Fleet, PhaseEvents, Waiter
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate

__all__ = ["FlyReturn", "ReturnHome"]


#: ``fly_return(sysids) -> land_here``: bring ``sysids`` above their landing spots, clear of lost
#: vehicles (:meth:`mission.flight.return_clear.ReturnClear.fly_return`); those that must LAND (not RTL)
FlyReturn = Callable[[list], Awaitable[set]]


class ReturnHome:
    """The return: back over the homes by layers, then land (or RTL), staggered by ``stagger_s``;
    an operator's ``land`` / ``rtl`` instead, also half-way; or every vehicle landed where it is.

    Parameters
    ----------
    plan : Plan
        ``return_behaviour`` and ``stagger_s``.
    state : MissionState
    fleet : Fleet
    gate : SafetyGate or None
        The vehicles under setpoints (None: the mission ended before the takeoff).
    clock : Clock
    events : PhaseEvents
    waiter : Waiter
    control : MissionControl
        The operator's LAND / RTL orders.
    fly_return : FlyReturn
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, gate: SafetyGate | None, clock: Clock,
                 events: PhaseEvents, waiter: Waiter, control: MissionControl, fly_return: FlyReturn) -> None:
        self.plan, self.state, self.fleet, self.gate, self.clock = plan, state, fleet, gate, clock
        self.events, self.waiter, self.control, self.fly_return = events, waiter, control, fly_return

    async def run(self) -> None:
        """Fly every airborne vehicle home and land it (or the operator's LAND / RTL).

        The paths, the descents included, keep ``min_separation_m + OBSTACLE_MARGIN_M`` from lost
        vehicles still flying (``fly_return``); a vehicle whose home is obstructed lands beside it.
        An operator's ``land`` / ``rtl`` (:mod:`mission.flight.control`) replaces it, also
        half-way: every airborne vehicle is commanded to LAND / RTL at once.
        """
        order = self.control.landing
        if order is None:
            order = await self.control.unless_landing_ordered(self._return_home())
        while order is not None:
            self.events.set_phase("return", behaviour=f"{order} (operator)")
            done = order
            order = await self.control.unless_landing_ordered(
                self._land_staggered(sorted(self.state.airborne), rtl=order == "rtl", stagger_s=0.0), current=done)

    async def land_all_now(self) -> None:
        """Emergency: land every airborne vehicle where it is (no stagger)."""
        await self._land_staggered(sorted(self.state.airborne), rtl=False)

    async def _return_home(self) -> None:
        """The mission's own return (:meth:`run` without an operator's order)."""
        self.events.set_phase("return", behaviour=self.plan.return_behaviour)
        gate, state = self.gate, self.state
        flying = [s for s in sorted(state.airborne) if gate is not None and s in gate.sysids]
        land_here: set[int] = set()
        if flying:
            land_here = await self.fly_return(flying)
        await self._land_staggered(sorted(state.airborne, key=lambda s: state.layer_alt_m.get(s, 0.0)),
                                   rtl=self.plan.return_behaviour == "rtl", land_only=land_here)

    async def _land_staggered(self, order, rtl: bool, land_only=frozenset(), stagger_s: float | None = None) -> None:
        """Land (or RTL) ``order`` one after the other (``stagger_s`` apart, default the plan's);
        vehicles in ``land_only`` land even with RTL."""
        waits = []
        try:
            await self._command_down(order, rtl, land_only, self.plan.stagger_s if stagger_s is None else stagger_s,
                                     waits)
            await asyncio.gather(*waits)
        finally:  # cancelled (an operator's land / rtl): no orphan waits
            for w in waits:
                w.cancel()

    async def _command_down(self, order, rtl: bool, land_only, stagger_s: float, waits: list) -> None:
        gate = self.gate
        for i, sysid in enumerate(order):
            if i and stagger_s > 0:
                await self.clock.sleep(stagger_s)
            v = self.fleet.vehicles[sysid]
            self.state.release(sysid)
            by_rtl = rtl and sysid not in land_only
            try:
                await retried(self.events, self.clock, (lambda v=v: v.rtl()) if by_rtl else (lambda v=v: v.land()),
                              f"{'RTL' if by_rtl else 'land'} of vehicle {sysid}")
            except MissionError as exc:
                self.events.event(str(exc), level="error")
                continue
            if gate is not None and sysid in gate.sysids:
                gate.remove(sysid)
            self.state.set_status(sysid, "returning" if by_rtl else "landing")
            waits.append(asyncio.ensure_future(self._wait_landed(sysid)))

    async def _wait_landed(self, sysid: int, timeout_s: float = 180.0) -> None:
        v = self.fleet.vehicles[sysid]

        def _down():
            update_odometry(self.state, self.fleet)
            return (v.state.landed is True) or not v.state.armed

        try:
            await self.waiter.wait_until(_down, timeout_s, f"vehicle {sysid} to land", poll_s=0.2)
        except MissionError as exc:
            self.events.event(str(exc), level="error")
            return
        self.state.set_landed(sysid)
        self.events.event(f"vehicle {sysid} landed", sysid=sysid)
