"""Ctrl-C and SIGTERM during a mission: told to the operator, counted, never abandoning a vehicle.

:func:`run_until_stopped` runs :meth:`~mission.flight.coordinator.Coordinator.run` with handlers
for SIGINT and SIGTERM on the running event loop (main thread only; elsewhere the signals keep
their default behaviour). Each signal cancels the mission's task once; what a cancellation does
depends on how many came before (:mod:`mission.flight.mission_end`): the first brings the
vehicles home (the plan's ``return``), the second lands them where they are, the third stops
waiting for the LAND confirmations. The mission log always gets its ``summary``; the result's
outcome is then ``interrupted`` (unless the mission had ended before the first signal) and
:func:`exit_status` gives 130 (SIGINT) or 143 (SIGTERM).
"""
from __future__ import annotations

import asyncio
import signal
import sys

__all__ = ["run_until_stopped", "exit_status", "SIGNAL_EXIT"]

#: exit status of a command stopped by a signal (128 + the signal number, as a shell reports it)
SIGNAL_EXIT = {"SIGINT": 130, "SIGTERM": 143}

_TOLD = {1: "stopping the mission: every vehicle returns (Ctrl-C again: LAND them where they are)",
         2: "LANDING every vehicle where it is now (Ctrl-C again: stop waiting for the confirmations)"}


async def run_until_stopped(co, resume_state=None):
    """``co.run(resume_state)`` under SIGINT/SIGTERM handlers; returns the MissionResult.

    A run cut short by a signal still returns its result (:attr:`Coordinator.final_result`,
    whose ``summary`` record is in the log); a cancellation from anything else propagates.
    """
    loop = asyncio.get_running_loop()
    task = loop.create_task(co.run(resume_state))

    def _on_signal(sig: signal.Signals) -> None:
        co.interrupts.append(sig.name)
        told = _TOLD.get(len(co.interrupts), "stopping now")
        print(f"\nswarmseek: {sig.name}: {told}", file=sys.stderr, flush=True)
        task.cancel()

    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, _on_signal, sig)
        except (NotImplementedError, RuntimeError, ValueError):
            continue  # not the main thread, or no signals on this platform
        installed.append(sig)
    try:
        return await task
    except asyncio.CancelledError:
        if co.interrupts and co.final_result is not None and not _self_cancelled():
            return co.final_result
        raise
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)


def _self_cancelled() -> bool:
    task = asyncio.current_task()
    return task is not None and task.cancelling() > 0


def exit_status(result, status: int) -> int:
    """The command's exit status: ``status`` unless a signal interrupted the mission (130, 143)."""
    signals = getattr(result, "interrupted_by", None)
    if signals:
        return SIGNAL_EXIT.get(signals[0], 130)
    return status
