"""Signals and a failing mission log during a mission: told, counted, never abandoning a vehicle.

:func:`run_until_stopped` runs :meth:`~mission.flight.coordinator.Coordinator.run` (the coroutine, with the
mission's state and log) with handlers
for SIGINT, SIGTERM and SIGHUP on the running event loop (main thread only; elsewhere the signals
keep their default behaviour), and for a SIGPIPE sent by another process (``kill -PIPE``; see
:mod:`mission.telemetry.terminal`: the SIGPIPE a write to a closed pipe raises is not a stop).
SIGHUP is what a closed SSH session or terminal sends: the mission's terminal may be gone, so
everything said about it is best effort (:mod:`mission.telemetry.terminal`); under ``nohup``
(SIGHUP ignored from the start) it stays ignored. A mission log
that cannot be written any more (disk full, file size limit...) stops the mission the same way,
with a loud message on whatever output still works.

Each stop cancels the mission's task once; what a cancellation does depends on how many came
before (:mod:`mission.flight.phases.mission_end`): the first brings the vehicles home (the plan's
``return``), the second lands them where they are, the third stops waiting for the LAND
confirmations. The mission log always gets its ``summary`` (when it can still be written); the
result's outcome is then ``interrupted`` (unless the mission had ended before the first stop)
and its exit status is the first stop's (:data:`mission.flight.result.SIGNAL_EXIT`).
"""
from __future__ import annotations

import asyncio
import os
import signal
import sys
import threading
from typing import Coroutine

from mission.flight.result import LOG_FAILURE
from mission.flight.state import MissionState
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import alert

__all__ = ["run_until_stopped"]

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

#: phases in which the vehicles are already on their way home: a log failure then stops nothing
_ENDING = ("finish", "aborted", "return", "done")

_TOLD = {1: "stopping the mission: every vehicle returns (Ctrl-C again: LAND them where they are)",
         2: "LANDING every vehicle where it is now (Ctrl-C again: stop waiting for the confirmations)"}


async def run_until_stopped(mission: Coroutine, state: MissionState, log: MissionLog | None = None):
    """The ``mission`` coroutine (a coordinator's ``run(resume_state)``) under the stop handlers;
    returns its MissionResult.

    Each stop is counted in ``state`` (its ``interrupts``) and cancels the mission's task once; a
    ``log`` that cannot be written any more stops it too. A run cut short by a stop still returns
    its result (:attr:`MissionState.final_result <mission.flight.state.MissionState.final_result>`,
    whose ``summary`` record is in the log); a cancellation from anything else propagates.
    """
    loop = asyncio.get_running_loop()
    task = loop.create_task(mission)
    cancels = []

    def _stop(name: str) -> None:
        state.note_interrupt(name)
        cancels.append(name)
        task.cancel()

    def _on_signal(sig: signal.Signals) -> None:
        _stop(sig.name)  # told on stderr, best effort (a hung-up terminal: the log says it)
        print(f"\nswarmseek: {sig.name}: {_TOLD.get(len(cancels), 'stopping now')}", file=sys.stderr, flush=True)

    def _on_log_failure(exc: OSError) -> None:
        ending = state.phase in _ENDING or bool(cancels)
        alert(f"swarmseek: ERROR: cannot write the mission log {log.path} ({type(exc).__name__}: {exc}); "
              + ("the vehicles are already on their way home; nothing more is logged" if ending else
                 "bringing every vehicle home (the plan's return); nothing more is logged"))
        if ending:
            state.note_interrupt(LOG_FAILURE)  # for the exit status; the return goes on as it is
        else:
            _stop(LOG_FAILURE)

    installed = _install(loop, _on_signal)
    pipe = _PipeSignals(loop, _on_signal)
    if log is not None:
        log.on_error = _on_log_failure
        if log.error is not None:  # it failed before the mission started: nothing will be armed
            _on_log_failure(log.error)
    try:
        return await task
    except asyncio.CancelledError:
        if state.interrupts and state.final_result is not None and not _self_cancelled():
            return state.final_result
        raise
    finally:
        pipe.stop()
        if log is not None:
            log.on_error = None
        for sig in installed:
            loop.remove_signal_handler(sig)


def _install(loop, on_signal) -> list:
    """``on_signal(sig)`` as the loop's handler of each stop signal it can take; those installed.

    A SIGHUP ignored when the process started (``nohup``) stays ignored: the operator asked for
    the mission to outlive the terminal."""
    installed = []
    for sig in _STOP_SIGNALS:
        if sig == signal.SIGHUP and signal.getsignal(sig) == signal.SIG_IGN:
            continue
        try:
            loop.add_signal_handler(sig, on_signal, sig)
        except (NotImplementedError, RuntimeError, ValueError):
            continue  # not the main thread, or no signals on this platform
        installed.append(sig)
    return installed


class _PipeSignals:
    """A SIGPIPE sent by another process, as a stop (``on_signal(SIGPIPE)`` on the loop).

    Only where SIGPIPE is blocked (:func:`mission.telemetry.terminal.best_effort_terminal`): a
    thread takes the pending SIGPIPEs sent to the process with ``sigwaitinfo`` and keeps those
    whose sender is another process. A write to a closed pipe or socket raises its SIGPIPE on the
    writing thread, where it stays pending, unseen (the write fails with EPIPE).
    """

    def __init__(self, loop, on_signal):
        self._thread = None
        self._done = threading.Event()
        if signal.SIGPIPE not in signal.pthread_sigmask(signal.SIG_BLOCK, []):
            return
        self._loop, self._on_signal = loop, on_signal
        self._thread = threading.Thread(target=self._wait, name="swarmseek-sigpipe", daemon=True)
        self._thread.start()

    def _wait(self) -> None:
        while True:
            info = signal.sigwaitinfo([signal.SIGPIPE])
            if self._done.is_set():
                return
            if info.si_pid != os.getpid():
                self._loop.call_soon_threadsafe(self._on_signal, signal.SIGPIPE)

    def stop(self) -> None:
        """Stop the thread (a SIGPIPE to itself wakes it)."""
        if self._thread is None:
            return
        self._done.set()
        signal.pthread_kill(self._thread.ident, signal.SIGPIPE)
        self._thread.join(timeout=5.0)
        self._thread = None


def _self_cancelled() -> bool:
    task = asyncio.current_task()
    return task is not None and task.cancelling() > 0
