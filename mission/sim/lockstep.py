"""Lock-step simulation: the ground station and a simulated world on one simulated clock.

With real vehicles the coordinator runs on the wall clock. Against a simulated world it can run
in lock-step instead (as crazyswarm2's simulation backend and ArduPilot's lock-step SITL do):
simulated time advances only when every party is waiting, and then jumps straight to the next
thing anybody waits for, as fast as the CPU allows. A busy host then slows a mission down but can
never make a vehicle look lost, and the same seed gives the same mission.

The parts:

* :class:`VirtualClock`: the mission clock of the interface in :mod:`mission.core.clock`
  (``time()``, ``async sleep(dt_s)``, ``speedup``), read from the lock-step event loop.
* :class:`LockstepEventLoop`: an asyncio event loop whose ``time()`` is simulated. When no
  callback is ready and no socket has data (the ground station is waiting), it asks the world to
  settle (deliver what is in flight), then advances the clock to the earlier of the loop's next
  timer and the world's next event, and lets the world run up to it. Every asyncio timeout
  (``asyncio.sleep``, ``wait_for``, the coordinator's watchdogs) is therefore in simulated time.
  ``run_in_executor`` runs the function at once, in zero simulated time: work handed to a
  thread cannot race the clock.
* A *world* (see :class:`LockstepWorld`), the small backend interface the loop drives:
  ``settle()``, ``next_event_s()`` and ``advance_to(t_s)``. The embedded mock fleet is one
  (:class:`mission.sim.embedded_world.EmbeddedWorld`).

All I/O stays real: MAVLink over loopback sockets, readings over zenoh. What makes it
deterministic is the order: the loop and the world run on one thread, and the world's
``settle`` waits until every frame and reading sent so far has been received.
"""
from __future__ import annotations

import asyncio
import math
import selectors
import threading
import time as _time
from typing import Awaitable, Callable, Protocol, TypeVar

__all__ = ["LOCKSTEP_T0_S", "LockstepWorld", "VirtualClock", "LockstepEventLoop", "run_lockstep"]

_T = TypeVar("_T")

#: simulated Unix time at which every lock-step run starts (2026-01-01 00:00:00 UTC), so that two
#: runs of the same seed write the same mission log
LOCKSTEP_T0_S = 1_767_225_600.0


class LockstepWorld(Protocol):
    """What a lock-step event loop needs from the simulated world it drives."""

    def settle(self) -> None:
        """Deliver everything in flight now (frames, readings); return when nothing is."""

    def next_event_s(self) -> float:
        """Simulated time (clock seconds, Unix epoch) of the world's next scheduled event."""

    def advance_to(self, t_s: float) -> None:
        """Run the world up to simulated time ``t_s`` (the clock is already there)."""


class VirtualClock:
    """Simulated Unix-epoch time that only a :class:`LockstepEventLoop` moves.

    Parameters
    ----------
    t0_s : float
        Simulated Unix time at the start (default :data:`LOCKSTEP_T0_S`).

    Attributes
    ----------
    speedup : float
        ``math.inf``: simulated time is not tied to the wall clock.
    """

    speedup = math.inf

    def __init__(self, t0_s: float = LOCKSTEP_T0_S) -> None:
        t0 = float(t0_s)
        if not math.isfinite(t0):
            raise ValueError(f"t0_s must be finite, got {t0_s!r}")
        self.t0_s = t0
        self._elapsed_s = 0.0
        self._moved = threading.Condition()
        self._loop_thread: int | None = None

    @property
    def elapsed_s(self) -> float:
        """Simulated seconds since the start."""
        return self._elapsed_s

    def time(self) -> float:
        """Simulated Unix-epoch seconds now."""
        return self.t0_s + self._elapsed_s

    def advance_to(self, elapsed_s: float) -> None:
        """Move to ``elapsed_s`` seconds after the start (never backwards); wake blocked threads."""
        if elapsed_s > self._elapsed_s:
            with self._moved:
                self._elapsed_s = float(elapsed_s)
                self._moved.notify_all()

    def bind_loop_thread(self, thread_id: int | None) -> None:
        """Record the thread that moves this clock (None: no lock-step run is going on).

        Unbinding wakes every thread blocked in :meth:`sleep_blocking`: with no run, nothing
        would ever move the clock for them.
        """
        with self._moved:
            self._loop_thread = thread_id
            self._moved.notify_all()

    async def sleep(self, dt_s: float) -> None:
        """Suspend the calling task for ``dt_s`` simulated seconds (the loop's own timers)."""
        await asyncio.sleep(max(0.0, float(dt_s)))

    def sleep_blocking(self, dt_s: float) -> None:
        """Block the calling thread until the clock has moved ``dt_s`` simulated seconds.

        For threads beside a lock-step run (a test's fault injector, say). While no run is going
        on (before it starts, after it ends) nothing moves the clock: the call then returns after
        one wall millisecond. The thread that moves the clock cannot wait for itself: it gets a
        :class:`RuntimeError`.
        """
        if threading.get_ident() == self._loop_thread:
            raise RuntimeError("VirtualClock.sleep_blocking on the lock-step loop's own thread would "
                               "never return; use await clock.sleep(dt_s)")
        with self._moved:
            deadline = self._elapsed_s + max(0.0, float(dt_s))
            while self._elapsed_s < deadline and self._loop_thread is not None:
                self._moved.wait()
            running = self._loop_thread is not None
        if not running:
            _time.sleep(1e-3)

    def __repr__(self) -> str:
        return f"VirtualClock(t={self.time():.3f})"


class _IdleSelector(selectors.BaseSelector):
    """A selector that, instead of blocking, lets the event loop's simulated time move."""

    def __init__(self, inner: selectors.BaseSelector, on_idle: Callable[[float | None], list]):
        self._inner = inner
        self._on_idle = on_idle

    def register(self, fileobj, events, data=None):
        return self._inner.register(fileobj, events, data)

    def unregister(self, fileobj):
        return self._inner.unregister(fileobj)

    def modify(self, fileobj, events, data=None):
        return self._inner.modify(fileobj, events, data)

    def get_key(self, fileobj):
        return self._inner.get_key(fileobj)

    def get_map(self):
        return self._inner.get_map()

    def close(self) -> None:
        self._inner.close()

    def poll(self) -> list:
        """Events ready now, without waiting."""
        return self._inner.select(0)

    def select(self, timeout=None):
        events = self._inner.select(0)
        if events or timeout == 0:
            return events
        return self._on_idle(timeout)


class LockstepEventLoop(asyncio.SelectorEventLoop):
    """An asyncio event loop on simulated time that drives a world in lock-step.

    Parameters
    ----------
    clock : VirtualClock
        The clock this loop moves; ``loop.time()`` is ``clock.elapsed_s``.
    world : LockstepWorld or None
        The world to drive; None: time just jumps to the next timer (useful in tests).

    Attributes
    ----------
    advances : int
        Times simulated time moved.
    """

    def __init__(self, clock: VirtualClock, world: LockstepWorld | None = None) -> None:
        self._sim_clock = clock
        self._world = world
        self._idle_selector = _IdleSelector(selectors.DefaultSelector(), self._on_idle)
        super().__init__(self._idle_selector)
        self.advances = 0

    def time(self) -> float:
        return self._sim_clock.elapsed_s

    def run_in_executor(self, executor, func, *args):
        """Run ``func(*args)`` now, on the loop's thread, in zero simulated time."""
        fut = self.create_future()
        try:
            fut.set_result(func(*args))
        except (SystemExit, KeyboardInterrupt):
            raise
        except BaseException as exc:  # noqa: BLE001 - handed to the awaiting task, like an executor would
            fut.set_exception(exc)
        return fut

    def _on_idle(self, timeout: float | None) -> list:
        """The loop has nothing to do for ``timeout`` s: move simulated time, return events."""
        clock = self._sim_clock
        deadline = math.inf if timeout is None else clock.elapsed_s + timeout
        while True:
            if self._world is not None:
                self._world.settle()
                events = self._idle_selector.poll()
                if events:
                    return events
                next_s = min(deadline, self._world.next_event_s() - clock.t0_s)
            else:
                next_s = deadline
            if not math.isfinite(next_s):
                raise RuntimeError("lock-step deadlock: nothing is scheduled and nothing is in flight")
            clock.advance_to(next_s)
            self.advances += 1
            if self._world is not None:
                self._world.advance_to(clock.time())
                self._world.settle()  # what the world sent is received before anyone looks
            events = self._idle_selector.poll()
            if events or clock.elapsed_s >= deadline:
                return events


def run_lockstep(main: Callable[[], Awaitable[_T]], clock: VirtualClock,
                 world: LockstepWorld | None = None) -> _T:
    """Run ``main()`` to completion on a :class:`LockstepEventLoop` (like ``asyncio.run``).

    Parameters
    ----------
    main : callable
        Returns the coroutine to run (called on the new loop).
    clock : VirtualClock
    world : LockstepWorld, optional

    Returns
    -------
    object
        What the coroutine returned.
    """
    clock.bind_loop_thread(threading.get_ident())
    try:
        with asyncio.Runner(loop_factory=lambda: LockstepEventLoop(clock, world)) as runner:
            return runner.run(main())
    finally:
        clock.bind_loop_thread(None)
