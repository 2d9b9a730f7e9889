"""The coordinator's state over zenoh: ``swarmseek/<fleet>/mission/state`` at about 2 Hz.

A snapshot that cannot be taken, shown or published is counted (``errors``) and the first
failure of each kind told to ``report``: the publication goes on with the next snapshot, and the
mission never stops for its publication or its display.

Payload: UTF-8 JSON (encoding ``application/json``), the coordinator's state snapshot, schema
``swarmseek.mission_state.v1`` (fields documented in ``docs/mission.md``). Published with
``CongestionControl.DROP``: a watcher that cannot keep up misses snapshots, the mission never
waits for it (the latest snapshot supersedes every older one).
"""
from __future__ import annotations

import asyncio
import json
import time
from typing import Callable

from mission.core.tasks import spawn, stop_watched
from mission.telemetry.mission_log import to_jsonable

__all__ = ["STATE_SCHEMA", "WALL_CLOCK_RATE_HZ", "MAP_RATE_HZ", "state_key", "StatePublisher"]

STATE_SCHEMA = "swarmseek.mission_state.v1"
#: The publication's rate on the wall clock (``fly``, ``resume``, ``run --realtime``): the live map
#: wants at least 5 updates a second (a lock-step mission publishes at 2 Hz of simulated time, many
#: per wall second, and keeps that rate: more timers would move its world in other steps)
WALL_CLOCK_RATE_HZ = 5.0
#: ... and with the map served by the mission itself (``run --map``)
MAP_RATE_HZ = 10.0


def state_key(fleet: str) -> str:
    """``swarmseek/<fleet>/mission/state``."""
    return f"swarmseek/{fleet}/mission/state"


class StatePublisher:
    """Publishes snapshots from ``snapshot()`` every ``1 / rate_hz`` wall seconds while running.

    Parameters
    ----------
    session : zenoh.Session or None
        None disables publishing (snapshots are still taken for the display).
    fleet : str
    snapshot : callable
        Returns the current state dict.
    rate_hz : float
        Publication rate, wall clock (the state is for people and tools watching).
    on_snapshot : callable, optional
        Called with every snapshot (e.g. the display's ``update``).
    report : callable, optional
        Told (one line) the first time taking, showing or publishing a snapshot fails, and if the
        periodic task itself fails (:func:`mission.core.tasks.watch_task`).
    """

    def __init__(self, session, fleet: str, snapshot: Callable[[], dict], rate_hz: float = 2.0,
                 on_snapshot: Callable[[dict], None] | None = None,
                 report: Callable[[str], None] | None = None):
        self.fleet = fleet
        self.snapshot = snapshot
        self.period_s = 1.0 / float(rate_hz)
        self.on_snapshot = on_snapshot
        self.published = 0
        self.errors = 0
        self.report = report
        self._told: set[str] = set()
        self._task: asyncio.Task | None = None
        self._pub = None
        if session is not None:
            import zenoh

            self._pub = session.declare_publisher(
                state_key(fleet), encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.DROP)

    def publish_now(self, final: bool = False) -> dict:
        """Take a snapshot, hand it to ``on_snapshot`` and publish it; returns it.

        ``final``: the last one (the coordinator is stopping), marked ``"final": true`` so that a
        watcher knows the mission ended. A snapshot that cannot be taken: an empty dict (counted, told)."""
        try:
            state = dict(self.snapshot())
        except Exception as exc:  # noqa: BLE001 - a state that cannot be taken must not stop the mission
            self._failed("taking the mission's state", exc)
            return {}
        state["schema"] = STATE_SCHEMA
        state["published_wall_s"] = round(time.time(), 4)  # for a watcher's latency (same host or synced clocks)
        if final:
            state["final"] = True
        if self.on_snapshot is not None:
            try:
                self.on_snapshot(state)
            except Exception as exc:  # noqa: BLE001 - a failing display must not stop the mission
                self._failed("showing the mission's state", exc)
        if self._pub is not None:
            try:
                self._pub.put(json.dumps(to_jsonable(state), allow_nan=False).encode())
                self.published += 1
            except Exception as exc:  # noqa: BLE001 - a closed session must not stop the mission
                self._failed("publishing the mission's state", exc)
        return state

    def _failed(self, what: str, exc: Exception) -> None:
        """Count a failure; tell ``report`` the first of each kind."""
        self.errors += 1
        if what not in self._told and self.report is not None:
            self._told.add(what)
            self.report(f"{what} failed ({type(exc).__name__}: {exc}); the mission goes on "
                        "(told once; counted in the state publisher's errors)")

    async def _run(self) -> None:
        while True:
            self.publish_now()
            await asyncio.sleep(self.period_s)

    def start(self) -> None:
        """Start the periodic task on the running loop."""
        if self._task is None:
            self._task = spawn(self._run(), "the state publication", self.report)

    async def stop(self) -> None:
        """Stop the task, publish a last snapshot, undeclare the publisher."""
        await stop_watched(self._task)
        self._task = None
        self.publish_now(final=True)
        if self._pub is not None:
            try:
                self._pub.undeclare()
            except Exception:  # noqa: BLE001
                pass
            self._pub = None
