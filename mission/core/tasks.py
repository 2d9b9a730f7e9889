"""Background tasks whose failure is always told, never "Task exception was never retrieved".

:func:`watch_task` gives an asyncio task a done-callback: when it ends with an exception (not a
cancellation) the exception is retrieved and told to ``report`` (the coordinator's ``event`` at
level ``error``, so it is in the mission log and above the live display), or when there is no
``report`` to the ``swarmseek`` logger (standard error).
"""
from __future__ import annotations

import asyncio
import logging
from typing import Callable

from mission.core.clock import cancel_and_wait

__all__ = ["watch_task", "spawn", "stop_watched"]

_LOGGER = "swarmseek"


def watch_task(task: asyncio.Future, what: str, report: Callable[[str], None] | None = None) -> asyncio.Future:
    """Tell ``report(message)`` when ``task`` fails; returns ``task``.

    Parameters
    ----------
    task : asyncio.Task or asyncio.Future
    what : str
        What the task does, in the message (``the state publication``).
    report : callable, optional
        Called with one line; default: a warning of the ``swarmseek`` logger.
    """
    def _done(t: asyncio.Future) -> None:
        if t.cancelled():
            return
        exc = t.exception()  # retrieved: never "Task exception was never retrieved"
        if exc is None:
            return
        message = f"background task {what} failed: {type(exc).__name__}: {exc}"
        if report is None:
            logging.getLogger(_LOGGER).warning("swarmseek: %s", message)
            return
        try:
            report(message)
        except Exception:  # noqa: BLE001 - the report itself failed: the logger still says it
            logging.getLogger(_LOGGER).exception("swarmseek: %s (and reporting it failed)", message)

    task.add_done_callback(_done)
    return task


def spawn(coro, what: str, report: Callable[[str], None] | None = None) -> asyncio.Task:
    """``create_task(coro)`` on the running loop, watched by :func:`watch_task`."""
    return watch_task(asyncio.get_running_loop().create_task(coro), what, report)


async def stop_watched(task: asyncio.Future | None) -> None:
    """Cancel a task watched by :func:`watch_task` and wait until it has finished.

    Its cancellation is absorbed; an exception it ended with was told by :func:`watch_task`
    and is not raised again (stopping the mission's background must go on).
    """
    try:
        await cancel_and_wait(task)
    except Exception:  # noqa: BLE001 - already told by the task's watch_task callback
        return
