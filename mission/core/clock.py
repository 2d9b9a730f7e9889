"""Clocks for the ground station, and waiting on a clock.

The coordinator runs on a clock object (see ``docs/interfaces.md``, section Clock):
``time() -> float`` (Unix-epoch seconds), ``async sleep(dt_s)``, ``sleep_blocking(dt_s)`` and
``speedup``. Against real vehicles that is :class:`WallClock`; with an embedded mock fleet it is
the fleet's ``sitl_mock.clock.SimClock``, which has the same interface.
"""
from __future__ import annotations

import asyncio
import time
from typing import Awaitable, TypeVar

__all__ = ["WallClock", "wait_on_clock", "cancel_and_wait"]

_T = TypeVar("_T")


class WallClock:
    """The real time: ``time.time()``, ``asyncio.sleep`` and ``time.sleep``; ``speedup`` is 1.

    Attributes
    ----------
    speedup : float
        Always 1.0 (simulated seconds per wall second).
    """

    speedup: float = 1.0

    def time(self) -> float:
        """Return the Unix-epoch time in seconds."""
        return time.time()

    async def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` seconds without blocking the event loop (negative means zero)."""
        await asyncio.sleep(max(0.0, float(dt_s)))

    def sleep_blocking(self, dt_s: float) -> None:
        """Block the calling thread for ``dt_s`` seconds (negative means zero)."""
        time.sleep(max(0.0, float(dt_s)))

    def __repr__(self) -> str:
        return "WallClock()"


async def wait_on_clock(awaitable: Awaitable[_T], timeout_s: float, clock) -> _T:
    """Await ``awaitable`` for at most ``timeout_s`` seconds of ``clock`` time.

    Works with any clock of the interface (wall, scaled or lock-step): the timeout is a
    ``clock.sleep`` racing the awaitable, so a lock-step clock times out only when advanced.

    Parameters
    ----------
    awaitable : Awaitable
        A coroutine, task or future.
    timeout_s : float
        Timeout in clock seconds.
    clock : object
        A clock with ``async sleep(dt_s)``.

    Returns
    -------
    object
        The awaitable's result.

    Raises
    ------
    TimeoutError
        When the clock timeout passes first (the awaitable is cancelled).
    """
    target = asyncio.ensure_future(awaitable)
    if target.done():
        return target.result()
    timer = asyncio.ensure_future(clock.sleep(timeout_s))
    try:
        await asyncio.wait({target, timer}, return_when=asyncio.FIRST_COMPLETED)
    except asyncio.CancelledError:
        target.cancel()
        timer.cancel()
        raise
    if target.done():
        timer.cancel()
        return target.result()
    target.cancel()
    raise TimeoutError(f"timed out after {timeout_s:g} s")


async def cancel_and_wait(task) -> None:
    """Cancel ``task`` (an asyncio task or None) and wait until it has finished.

    Its own cancellation is absorbed; any other exception it ends with propagates.
    """
    if task is None:
        return
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        pass
