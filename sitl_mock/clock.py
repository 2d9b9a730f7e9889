"""Clocks of the simulated world: scaled wall time and lock-step time.

Every clock has the interface of ``docs/interfaces.md`` (Clock): ``time() -> float`` (Unix epoch
seconds on the *simulated* timeline), ``sleep_blocking(dt_s)``, ``async sleep(dt_s)`` and the
attribute ``speedup``.

* :class:`SimClock` maps wall time to simulated time, ``t0_s + speedup * elapsed``: real time at
  ``speedup=1``, faster than real time above.
* :class:`LockstepClock` only moves when :meth:`LockstepClock.advance` is called, which wakes
  every sleeper (threads and asyncio tasks, on any event loop) whose deadline has passed. Tests
  use it to run the world deterministically.
"""
from __future__ import annotations

import asyncio
import math
import threading
import time as _time

__all__ = ["SimClock", "LockstepClock"]


def _check_duration(dt_s: float) -> float:
    dt = float(dt_s)
    if not math.isfinite(dt):
        raise ValueError(f"sleep duration must be finite, got {dt_s!r}")
    return max(dt, 0.0)


class SimClock:
    """Simulated time running ``speedup`` times faster than the wall clock.

    ``time() = t0_s + speedup * (monotonic wall seconds elapsed since creation)``.

    Parameters
    ----------
    speedup : float
        Simulated seconds per wall second (> 0, finite). 1.0 is real time.
    t0_s : float or None
        Simulated Unix time at creation; default ``time.time()``.

    Raises
    ------
    ValueError
        If ``speedup`` is not a positive finite number.
    """

    def __init__(self, speedup: float = 1.0, t0_s: float | None = None):
        speedup = float(speedup)
        if not (math.isfinite(speedup) and speedup > 0.0):
            raise ValueError(f"speedup must be a positive finite number, got {speedup!r}")
        self.speedup = speedup
        self.t0_s = float(_time.time() if t0_s is None else t0_s)
        self._wall0_s = _time.monotonic()

    def time(self) -> float:
        """Simulated Unix-epoch seconds now."""
        return self.t0_s + self.speedup * (_time.monotonic() - self._wall0_s)

    def wall_delay_s(self, dt_s: float) -> float:
        """Wall seconds that ``dt_s`` simulated seconds take."""
        return _check_duration(dt_s) / self.speedup

    def sleep_blocking(self, dt_s: float) -> None:
        """Block the calling thread for ``dt_s`` seconds of simulated time."""
        _time.sleep(self.wall_delay_s(dt_s))

    async def sleep(self, dt_s: float) -> None:
        """Suspend the calling task for ``dt_s`` seconds of simulated time."""
        await asyncio.sleep(self.wall_delay_s(dt_s))

    def __repr__(self) -> str:
        return f"SimClock(speedup={self.speedup}, t0_s={self.t0_s})"


class LockstepClock:
    """Simulated time that moves only through :meth:`advance`.

    Sleepers wait until the clock has been advanced past their deadline: threads on a
    ``threading.Condition``, asyncio tasks on a future of their own event loop (woken thread-
    safely, so ``advance`` may be called from any thread or from inside a loop).

    Parameters
    ----------
    t0_s : float
        Simulated Unix time at creation.

    Attributes
    ----------
    speedup : float
        ``math.inf``: simulated time is not tied to the wall clock.
    """

    speedup = math.inf

    def __init__(self, t0_s: float = 1.7e9):
        t0 = float(t0_s)
        if not math.isfinite(t0):
            raise ValueError(f"t0_s must be finite, got {t0_s!r}")
        self._now_s = t0
        self._cond = threading.Condition()
        # (deadline_s, loop, future) of suspended asyncio sleepers
        self._async_sleepers: list[tuple[float, asyncio.AbstractEventLoop, asyncio.Future]] = []

    def time(self) -> float:
        """Simulated Unix-epoch seconds now."""
        with self._cond:
            return self._now_s

    def advance(self, dt_s: float) -> None:
        """Move time forward by ``dt_s`` (>= 0) and wake sleepers whose deadline has passed.

        Raises
        ------
        ValueError
            If ``dt_s`` is negative or not finite.
        """
        dt = float(dt_s)
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"advance needs a finite dt_s >= 0, got {dt_s!r}")
        with self._cond:
            self._now_s += dt
            now = self._now_s
            due = [s for s in self._async_sleepers if s[0] <= now]
            self._async_sleepers = [s for s in self._async_sleepers if s[0] > now]
            self._cond.notify_all()
        for _deadline, loop, fut in due:
            try:
                loop.call_soon_threadsafe(_wake, fut)
            except RuntimeError:  # the sleeper's loop is closed: nobody to wake
                pass

    def pending_sleepers(self) -> int:
        """Number of asyncio tasks currently suspended in :meth:`sleep`."""
        with self._cond:
            return len(self._async_sleepers)

    def next_deadline_s(self) -> float | None:
        """Earliest deadline among suspended asyncio sleepers, or None."""
        with self._cond:
            return min((s[0] for s in self._async_sleepers), default=None)

    def sleep_blocking(self, dt_s: float) -> None:
        """Block the calling thread until the clock has advanced by ``dt_s``."""
        dt = _check_duration(dt_s)
        with self._cond:
            deadline = self._now_s + dt
            while self._now_s < deadline:
                self._cond.wait()

    async def sleep(self, dt_s: float) -> None:
        """Suspend the calling task until the clock has advanced by ``dt_s``.

        Always yields to the event loop at least once, like ``asyncio.sleep(0)``.
        """
        dt = _check_duration(dt_s)
        loop = asyncio.get_running_loop()
        with self._cond:
            deadline = self._now_s + dt
            if dt <= 0.0:
                entry = None
            else:
                fut = loop.create_future()
                entry = (deadline, loop, fut)
                self._async_sleepers.append(entry)
        if entry is None:
            await asyncio.sleep(0)
            return
        try:
            await entry[2]
        finally:
            with self._cond:
                if entry in self._async_sleepers:
                    self._async_sleepers.remove(entry)

    def __repr__(self) -> str:
        return f"LockstepClock(t={self._now_s})"


def _wake(fut: asyncio.Future) -> None:
    if not fut.done():
        fut.set_result(None)
