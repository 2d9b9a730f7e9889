"""Waiting on a condition, with a timeout, instead of sleeping for a guessed time.

:func:`wait_until` (threads, blocking) and :func:`wait_until_async` (inside an event loop) poll
``predicate`` every ``poll_s`` seconds of wall time and return its first truthy value; they fail
the test with ``timed out waiting for <what>`` after ``timeout_s`` seconds.
"""
from __future__ import annotations

import asyncio
import time
from typing import Any, Callable

__all__ = ["wait_until", "wait_until_async"]


def wait_until(predicate: Callable[[], Any], timeout_s: float = 20.0, what: str = "condition",
               poll_s: float = 0.02) -> Any:
    """Block until ``predicate()`` is truthy (returned); AssertionError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


async def wait_until_async(predicate: Callable[[], Any], timeout_s: float = 20.0,
                           what: str = "condition", poll_s: float = 0.02) -> Any:
    """:func:`wait_until` for coroutines: yields to the event loop between polls."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if loop.time() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(poll_s)
