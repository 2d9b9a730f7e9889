"""Opening the plan's zenoh session from inside the event loop without blocking it.

``zenoh.open`` blocks while it binds its listeners and connects to its endpoints (0.5 s of wall
time measured in a lock-step ``swarmseek run``: ``tests/mission/sim/test_loop_debug.py``); run inside a
coroutine it stalls every other callback of the loop. :func:`open_session` runs it in the loop's
executor (a worker thread; inline, in zero simulated time, on a lock-step loop).
"""
from __future__ import annotations

import asyncio

__all__ = ["open_session"]


def _close_if_opened(fut) -> None:
    """Done callback: close a session whose opener was cancelled while it opened."""
    if not fut.cancelled() and fut.exception() is None:
        fut.result().close()


async def open_session(zplan):
    """``zenoh.open(zplan.to_config())`` off the event loop; returns the session.

    Parameters
    ----------
    zplan : mission.core.zenoh_config.ZenohPlan
        The plan's ``[zenoh]``.

    Raises
    ------
    zenoh.ZError
        The session cannot be opened. Cancelled while opening: the session, once open, is closed.
    """
    import zenoh

    config = zplan.to_config()
    fut = asyncio.get_running_loop().run_in_executor(None, zenoh.open, config)
    try:
        return await asyncio.shield(fut)
    except asyncio.CancelledError:
        fut.add_done_callback(_close_if_opened)
        raise
