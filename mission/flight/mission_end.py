"""The end of every mission path: return, secure, summary, in that order, whatever happens.

:func:`close` is the tail of :meth:`mission.flight.coordinator.Coordinator.run` on every path
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

__all__ = ["close", "interrupted_message"]


def _uncancel() -> None:
    """Forget a cancellation that was handled (later waits and timeouts behave normally)."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        task.uncancel()


def interrupted_message(names) -> str:
    """``interrupted (SIGINT)``, ``interrupted (SIGINT, SIGINT)``... or ``interrupted``: ``names``
    are the interrupts the mission state counted (``MissionState.interrupts``)."""
    return "interrupted" + (f" ({', '.join(names)})" if names else "")


async def _return(co, interrupts: int) -> int:
    """The controlled return, kept going through one interrupt; an emergency LAND at the next.

    Returns the interrupts counted so far (``interrupts`` on entry)."""
    while True:
        try:
            if interrupts < 2:
                await co.return_safely()
            return interrupts
        except asyncio.CancelledError:
            _uncancel()
            interrupts += 1
            if not co.return_on_interrupt:  # a ground station told to just stop
                co.event("interrupted during the return: the ground station stops; the vehicles do what "
                         "their autopilots do", level="error")
                return interrupts
            if interrupts == 1:
                co.event("interrupt during the return: the return goes on (interrupt again to LAND every "
                         "vehicle where it is)", level="warning")
                continue
            co.event("interrupted again: LANDING every airborne vehicle where it is (no return flight)",
                     level="error")
            try:
                await co.landing_guard().land_now()
            except asyncio.CancelledError:
                _uncancel()
                interrupts += 1
            return interrupts


async def close(co, outcome: str, message: str, *, interrupted: bool = False):
    """Return (unless told not to), secure, stop, summarise; returns the MissionResult.

    Parameters
    ----------
    co : Coordinator
    outcome, message : str
        How the mission ended (``interrupted`` when its task was cancelled).
    interrupted : bool
        The mission's task was cancelled: the cancellation goes on (CancelledError) after the
        summary is written.
    """
    interrupts = 0
    if interrupted:
        _uncancel()
        interrupts = 1
        co.set_phase("aborted", reason=message, returning=bool(co.return_on_interrupt))
        co.event(f"mission {message}: " + ("returning every vehicle (interrupt again to LAND them where "
                                           "they are)" if co.return_on_interrupt else
                                           "the ground station stops; the vehicles do what their autopilots do"),
                 level="error")
    if co.return_on_interrupt or not interrupted:
        interrupts = await _return(co, interrupts)
    why = f"mission {message}" if message.startswith(outcome) else f"mission {outcome}: {message}"
    left, cut_short = await co.landing_guard().secure(why, land=co.return_on_interrupt or not interrupts)
    interrupts += int(cut_short)
    co.state.set_ending(outcome, message)  # in the last snapshot (a watcher's map shows the outcome)
    try:
        await co.stop_background()
    except asyncio.CancelledError:
        _uncancel()
        await co.stop_background()
    result = co.result(outcome, message)
    result.airborne_left = left
    result.still_armed = list(co.state.still_armed)
    result.interrupted_by = list(co.state.interrupts)
    co.state.finish(result)
    co.set_phase("done")
    if co.log is not None:
        co.log.write("summary", sync=True, **result.to_json())
    if interrupted or interrupts:
        raise asyncio.CancelledError()
    return result
