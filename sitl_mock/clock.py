"""The simulated world's wall clock, scaled: :class:`SimClock`.

Every clock has the interface of ``docs/interfaces.md`` (Clock): ``time() -> float`` (Unix epoch
seconds on the *simulated* timeline), ``sleep_blocking(dt_s)``, ``async sleep(dt_s)`` and the
attribute ``speedup``.

* :class:`SimClock` maps wall time to simulated time, ``t0_s + speedup * elapsed``: real time at
  ``speedup=1``, faster than real time above.

Lock-step time is not here: a lock-step run has one clock, ``mission.sim.lockstep.VirtualClock``,
moved by the lock-step event loop, which steps the fleet itself (``MockFleet.start(thread=False)``
and ``MockFleet.step_until``).
"""
from __future__ import annotations

import asyncio
import math
import threading
import time as _time

__all__ = ["SimClock"]


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
