"""Run a ``swarmseek`` command with asyncio's debug mode on and time every event-loop callback.

``python tests/mission/sim/slow_callbacks.py REPORT.json run --n 8 ...`` runs ``swarmseek run ...`` in this
fresh interpreter (so first-call imports happen where the command does them) with
``PYTHONASYNCIODEBUG=1`` (set by the caller: every loop is in debug mode,
``slow_callback_duration`` 0.1 s), and writes ``REPORT.json``: the exit status, the number of
callbacks timed, and every ``Executing <callback> took X seconds`` warning of the ``asyncio``
logger.

Why not asyncio's own measure alone: it times a callback with ``loop.time()``, which in a
lock-step run (:class:`mission.sim.lockstep.LockstepEventLoop`) is *simulated* time, still during
a callback, so it would never fire; and wall time on a loaded 2-core machine also counts the time
the OS kept the thread waiting for a core. So each callback of a debug-mode loop is timed here
too (``asyncio.events.Handle._run`` wrapped) and logged in asyncio's words when it **kept the
loop's thread busy or blocked** for at least ``slow_callback_duration``:

* busy: the thread's CPU time (``time.thread_time``): the code's own work;
* blocked: wall time minus CPU time minus the time the thread was runnable but waiting for a core
  (Linux ``/proc/thread-self/schedstat``, second field): a ``time.sleep``, a DNS lookup, a
  blocking read. Without schedstat (not Linux) blocked time is not measured.

Work a lock-step loop runs inline in ``run_in_executor`` (in zero simulated time, for
determinism; a worker thread in a wall-clock mission, e.g. the CVT solves) is not the loop's: its
time is subtracted from the callback that awaited it.
"""
from __future__ import annotations

import asyncio
import json
import logging
import os
import sys
import threading
import time

__all__ = ["CallbackTimer", "main"]


def _schedstat_reader():
    """A function returning this thread's run-queue wait in seconds (None: not available)."""
    try:
        fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    except OSError:
        return None

    def runqueue_wait_s() -> float:
        return int(os.pread(fd, 128, 0).split()[1]) * 1e-9

    return runqueue_wait_s


class CallbackTimer:
    """Times every callback of every debug-mode event loop on the thread that installs it."""

    def __init__(self) -> None:
        self.timed = 0
        self.slow: list[dict] = []
        self.max_cpu_s = 0.0                    # the largest busy / blocked time of any callback
        self.max_blocked_s = 0.0
        self.limit_s: float | None = None       # the loops' slow_callback_duration
        self._thread = threading.get_ident()
        self._wait = _schedstat_reader()
        self._inline = [0.0, 0.0, 0.0]          # cpu, wall, queue spent in inline executor work
        self._orig_run = asyncio.events.Handle._run
        self._orig_executor = None

    def _now(self):
        return time.thread_time(), time.perf_counter(), self._wait() if self._wait else 0.0

    def _timed_run(self, handle) -> None:
        loop = handle._loop
        if threading.get_ident() != self._thread or loop is None or not loop.get_debug():
            return self._orig_run(handle)
        self._inline = [0.0, 0.0, 0.0]
        c0, w0, q0 = self._now()
        try:
            return self._orig_run(handle)
        finally:
            c1, w1, q1 = self._now()
            cpu = (c1 - c0) - self._inline[0]
            blocked = ((w1 - w0) - self._inline[1]) - cpu - ((q1 - q0) - self._inline[2])
            self.timed += 1
            self.max_cpu_s, self.max_blocked_s = max(self.max_cpu_s, cpu), max(self.max_blocked_s, blocked)
            limit = self.limit_s = loop.slow_callback_duration
            if cpu >= limit or (self._wait is not None and blocked >= limit):
                text = asyncio.base_events._format_handle(handle)
                self.slow.append({"callback": text, "cpu_s": round(cpu, 4), "blocked_s": round(blocked, 4)})
                logging.getLogger("asyncio").warning("Executing %s took %.3f seconds (thread CPU %.3f s, "
                                                     "blocked %.3f s)", text, max(cpu, blocked), cpu, blocked)

    def _inline_executor(self, loop, executor, func, *args):
        c0, w0, q0 = self._now()
        try:
            return self._orig_executor(loop, executor, func, *args)
        finally:
            c1, w1, q1 = self._now()
            self._inline[0] += c1 - c0
            self._inline[1] += w1 - w0
            self._inline[2] += q1 - q0

    def __enter__(self):
        from mission.sim.lockstep import LockstepEventLoop

        timer = self
        self._orig_executor = LockstepEventLoop.run_in_executor
        asyncio.events.Handle._run = lambda handle: timer._timed_run(handle)
        LockstepEventLoop.run_in_executor = lambda loop, ex, func, *a: timer._inline_executor(loop, ex, func, *a)
        return self

    def __exit__(self, *exc) -> None:
        from mission.sim.lockstep import LockstepEventLoop

        asyncio.events.Handle._run = self._orig_run
        LockstepEventLoop.run_in_executor = self._orig_executor


class _Warnings(logging.Handler):
    """Collects the asyncio logger's slow-callback warnings (its own and the timer's)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith("Executing "):
            self.lines.append(record.getMessage())


def main(argv: list[str]) -> int:
    """``REPORT.json COMMAND ARGS...``: run the command, write the report; the command's status."""
    from mission.cli import main as cli_main

    report_path, command = argv[0], argv[1:]
    warnings = _Warnings()
    logging.getLogger("asyncio").addHandler(warnings)
    with CallbackTimer() as timer:
        status = cli_main(command)
    with open(report_path, "w") as fh:
        json.dump({"status": status, "debug": os.environ.get("PYTHONASYNCIODEBUG"), "timed": timer.timed,
                   "slow": timer.slow, "warnings": warnings.lines, "schedstat": timer._wait is not None,
                   "max_cpu_s": round(timer.max_cpu_s, 4), "max_blocked_s": round(timer.max_blocked_s, 4),
                   "slow_callback_duration": timer.limit_s},
                  fh, indent=1)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
