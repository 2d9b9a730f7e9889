"""The end of every mission path: return, secure, summary, in that order, whatever happens.

:meth:`MissionEnd.run` is the tail of :meth:`mission.flight.coordinator.Coordinator.run` on every path
(converged, aborted, exception, interrupted). Interrupts are cancellations of the mission's task
(Ctrl-C and SIGTERM through :func:`mission.flight.operator_stop.run_until_stopped`; a test
cancelling the task is the same thing) and are counted:

1. the first stops the mission: the vehicles fly the controlled return (the plan's ``return``);
   one that arrives while the return is already flying lets it go on;
2. the next one during the return lands every airborne vehicle where it is, now
   (:meth:`mission.flight.faults.landing_guard.LandingGuard.land_now`);
3. the next one stops waiting for the LAND confirmations.

Then :meth:`mission.flight.faults.landing_guard.LandingGuard.secure` checks the never-abandon invariant (and reports
any vehicle still airborne), the background tasks and links stop, the phase becomes ``done`` and
the ``summary`` record is written: also when interrupted (then the cancellation goes on after it).
"""
from __future__ import annotations

import asyncio
from typing import Awaitable, Callable

from mission.flight.faults.landing_guard import LandingGuard
from mission.flight.result import MissionResult, mission_exit_status
from mission.flight.services import PhaseEvents
from mission.flight.state import MissionState
from mission.telemetry.mission_log import MissionLog

__all__ = ["MissionEnd", "interrupted_message"]


def _uncancel() -> None:
    """Forget a cancellation that was handled (later waits and timeouts behave normally)."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        task.uncancel()


def interrupted_message(names) -> str:
    """``interrupted (SIGINT)``, ``interrupted (SIGINT, SIGINT)``... or ``interrupted``: ``names``
    are the interrupts the mission state counted (``MissionState.interrupts``)."""
    return "interrupted" + (f" ({', '.join(names)})" if names else "")


class MissionEnd:
    """The end of the mission on every path: return, secure, stop, summarise.

    Parameters
    ----------
    state : MissionState
        The interrupts, the ending, the result.
    events : PhaseEvents
    return_home : callable
        ``await return_home()``: fly every airborne vehicle home (or land it where it is if that
        fails: :meth:`mission.flight.coordinator.Coordinator.return_safely`).
    landing_guard : callable
        ``landing_guard() -> LandingGuard``: the never-abandon check over the vehicles now.
    stop_background : callable
        ``await stop_background()``: stop what runs beside the phases, close the links.
    result : callable
        ``result(outcome, message) -> MissionResult``: the mission's result so far.
    log : MissionLog or None
        The ``summary`` record goes there.
    return_on_interrupt : bool
        False: a ground station told to just stop (an interrupt brings nobody home).
    """

    def __init__(self, state: MissionState, events: PhaseEvents, return_home: Callable[[], Awaitable[None]],
                 landing_guard: Callable[[], LandingGuard], stop_background: Callable[[], Awaitable[None]],
                 result: Callable[[str, str], MissionResult], log: MissionLog | None = None,
                 return_on_interrupt: bool = True) -> None:
        self.state, self.events, self.return_home, self.landing_guard = state, events, return_home, landing_guard
        self.stop_background, self.result, self.log = stop_background, result, log
        self.return_on_interrupt = bool(return_on_interrupt)

    async def run(self, outcome: str, message: str, *, interrupted: bool = False) -> MissionResult:
        """Return (unless told not to), secure, stop, summarise; returns the MissionResult.

        Parameters
        ----------
        outcome, message : str
            How the mission ended (``interrupted`` when its task was cancelled).
        interrupted : bool
            The mission's task was cancelled: the cancellation goes on (CancelledError) after the
            summary is written.
        """
        events, back = self.events, self.return_on_interrupt
        interrupts = 0
        if interrupted:
            _uncancel()
            interrupts = 1
            events.set_phase("aborted", reason=message, returning=back)
            events.event(f"mission {message}: " + ("returning every vehicle (interrupt again to LAND them where "
                                                   "they are)" if back else
                                                   "the ground station stops; the vehicles do what their autopilots do"),
                         level="error")
        if back or not interrupted:
            interrupts = await self._return(interrupts)
        why = f"mission {message}" if message.startswith(outcome) else f"mission {outcome}: {message}"
        left, cut_short = await self.landing_guard().secure(why, land=back or not interrupts)
        interrupts += int(cut_short)
        # in the last snapshot (a watcher's map shows the outcome; ``watch`` exits with the status)
        self.state.set_ending(outcome, message, mission_exit_status(
            outcome, lost=[x for x in self.state.lost.values() if not x.on_ground], airborne_left=left, still_armed=self.state.still_armed,
            interrupted_by=self.state.interrupts))
        try:
            await self.stop_background()
        except asyncio.CancelledError:
            _uncancel()
            await self.stop_background()
        result = self.result(outcome, message)
        result.airborne_left = left
        result.still_armed = list(self.state.still_armed)
        result.interrupted_by = list(self.state.interrupts)
        self.state.finish(result)
        events.set_phase("done")
        if self.log is not None:
            self.log.write("summary", sync=True, **result.to_json())
        if interrupted or interrupts:
            raise asyncio.CancelledError()
        return result

    async def _return(self, interrupts: int) -> int:
        """The controlled return, kept going through one interrupt; an emergency LAND at the next.

        Returns the interrupts counted so far (``interrupts`` on entry)."""
        events = self.events
        while True:
            try:
                if interrupts < 2:
                    await self.return_home()
                return interrupts
            except asyncio.CancelledError:
                _uncancel()
                interrupts += 1
                if not self.return_on_interrupt:  # a ground station told to just stop
                    events.event("interrupted during the return: the ground station stops; the vehicles do what "
                                 "their autopilots do", level="error")
                    return interrupts
                if interrupts == 1:
                    events.event("interrupt during the return: the return goes on (interrupt again to LAND every "
                                 "vehicle where it is)", level="warning")
                    continue
                events.event("interrupted again: LANDING every airborne vehicle where it is (no return flight)",
                             level="error")
                try:
                    await self.landing_guard().land_now()
                except asyncio.CancelledError:
                    _uncancel()
                    interrupts += 1
                return interrupts
