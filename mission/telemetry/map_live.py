"""The live map fed by zenoh: the state publication into a :class:`~mission.telemetry.map_feed.MapFeed`,
the page's commands out as ``swarmseek ctl``'s, and the map server on its own thread (``--map`` of
``run``, ``fly`` and ``resume``).

:func:`pump_states` reads the state publication through the same subscriber as ``swarmseek watch``
(:class:`mission.telemetry.watch.StateWatcher`), in the executor so that the server's loop never
blocks. :class:`MapThread` runs the server on a thread of its own, reading the state through
the mission's own zenoh session once the mission hands it over (:meth:`MapThread.attach`): no
endpoint is added to the plan and no credential is read; a mission on the lock-step loop is not
touched (the map schedules nothing on the mission's loop).
"""
from __future__ import annotations

import asyncio
import threading
import time
from typing import Callable

from mission.telemetry.map_feed import MapFeed
from mission.telemetry.map_server import DESTRUCTIVE, FEED, MapAccess, MapServer, make_app
from mission.telemetry.watch import CommandTimeout, StateWatcher, send_command

__all__ = ["pump_states", "zenoh_commander", "live_feed", "serve_live", "SessionHandoff", "MapThread"]

_SOURCE_SILENT_S = 3.0


async def pump_states(watcher: StateWatcher, feed: MapFeed, stop: asyncio.Event) -> None:
    """Push every snapshot ``watcher`` receives into ``feed`` until ``stop`` is set.

    A silence of 3 s after snapshots arrived is told to the pages (``source`` notice), as is
    the end of the silence."""
    loop = asyncio.get_running_loop()
    silent = False
    last_s = time.monotonic()
    while not stop.is_set():
        state = await loop.run_in_executor(None, watcher.get, 0.25)
        now = time.monotonic()
        if state is None:
            if not silent and feed.latest is not None and now - last_s > _SOURCE_SILENT_S \
                    and not feed.latest.get("final"):
                silent = True
                feed.notice("source", {"ok": False, "message": f"no mission state for {_SOURCE_SILENT_S:g} s"})
            continue
        if silent:
            silent = False
            feed.notice("source", {"ok": True, "message": "mission state received again"})
        last_s = now
        feed.push(state)


def zenoh_commander(session_of: Callable[[], object], fleet: str, sender: str,
                    timeout_s: float = 5.0) -> Callable[[str], dict]:
    """``send(command) -> acknowledgement``: one ``swarmseek ctl`` query (blocking) through the
    session ``session_of()`` returns (None: not open yet); a timeout is a rejection the page shows."""
    def send(command: str) -> dict:
        session = session_of()
        if session is None:
            return {"command": command, "sender": sender, "accepted": False,
                    "reason": "the map has not reached the mission's zenoh network yet"}
        try:
            return send_command(session, fleet, command, sender, timeout_s)
        except CommandTimeout as exc:
            return {"command": command, "sender": sender, "accepted": False, "reason": str(exc)}
    return send


def live_feed(fleet: str, access: MapAccess, config: dict) -> MapFeed:
    """A feed whose configuration tells the page the fleet and its access (read-only, CSRF token, login)."""
    return MapFeed({**config, "fleet": fleet, "read_only": access.read_only, "confirm": list(DESTRUCTIVE),
                    "read_only_reason": access.read_only_reason, "csrf_token": access.csrf_token,
                    "login": access.password is not None and not access.read_only})


async def serve_live(open_session: Callable[[], object], fleet: str, host: str, port: int, *,
                     access: MapAccess, sender: str, config: dict,
                     ready: Callable[[MapServer], None], stop: asyncio.Event,
                     close_session: bool = True) -> None:
    """Serve the map of ``fleet`` on ``host:port`` until ``stop`` is set.

    Binds first (``ready(server)`` is then called: :attr:`MapServer.url`, ``server.app[FEED]``),
    then opens the zenoh session (``open_session()``, in the executor: it may wait for the
    mission's endpoint, or for the mission to hand its own session over) and streams the state;
    the session is closed at the end if ``close_session`` (not the mission's own). Raises
    ``OSError`` when the address cannot be bound.
    """
    holder: list = []
    feed = live_feed(fleet, access, config)
    send = None if access.read_only else zenoh_commander(lambda: holder[0] if holder else None, fleet, sender)
    server = MapServer(make_app(feed, access, send), host, port)
    await server.start()
    watcher = None
    try:
        ready(server)
        session = await asyncio.get_running_loop().run_in_executor(None, open_session)
        if session is None:
            return
        holder.append(session)
        watcher = StateWatcher(session, fleet)
        await pump_states(watcher, feed, stop)
    finally:
        if watcher is not None:
            watcher.close()
        await server.stop()
        if holder and close_session:
            holder[0].close()


class SessionHandoff:
    """The mission's own zenoh session, handed to the map's thread once the mission opened it.

    :meth:`open` (the map's thread) waits until :meth:`offer` (the mission) or until its
    ``stopped()`` is true (then None: the mission never opened its session)."""

    def __init__(self):
        self._ready = threading.Event()
        self._session = None

    @property
    def offered(self) -> bool:
        """Whether the mission's session was handed over."""
        return self._ready.is_set()

    def offer(self, session) -> None:
        """The mission's session is open: the map may subscribe and query through it."""
        self._session = session
        self._ready.set()

    def open(self, stopped: Callable[[], bool]):
        """The offered session, or None once ``stopped()`` (checked every 0.2 s)."""
        while not self._ready.wait(0.2):
            if stopped():
                return None
        return self._session


class MapThread:
    """The live map of ``--map`` (``run``, ``fly``, ``resume``): its server and loop on a thread,
    reading and commanding through the mission's own zenoh session.

    Parameters
    ----------
    fleet, host, port, access, sender, config
        As :func:`serve_live`.

    The server binds at :meth:`start` (before the mission opens anything); the mission hands
    its zenoh session over with :meth:`attach` and takes it back with :meth:`stop` (before it
    closes it): the map only subscribes to the state publication and queries the control key
    on that session, and never closes it.
    """

    def __init__(self, fleet: str, host: str, port: int, *, access: MapAccess, sender: str, config: dict):
        self._handoff = SessionHandoff()
        self._args = (fleet, host, port)
        self._kw = {"access": access, "sender": sender, "config": config}
        self._bound = threading.Event()
        self._stopping = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self.error: BaseException | None = None
        self.url: str | None = None
        self.feed: MapFeed | None = None
        self._thread = threading.Thread(target=self._main, name="swarmseek-map", daemon=True)

    def start(self, timeout_s: float = 30.0) -> str:
        """Start; returns the page's URL once bound. Raises ``OSError`` (port in use, ...)."""
        self._thread.start()
        if not self._bound.wait(timeout_s):
            raise OSError(f"the map server did not start within {timeout_s:g} s")
        if self.error is not None:
            raise self.error
        return self.url

    def _main(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        try:
            await serve_live(lambda: self._handoff.open(self._stopping.is_set), *self._args, **self._kw,
                             ready=self._ready, stop=self._stop, close_session=False)
        except OSError as exc:
            self.error = exc
        finally:
            self._bound.set()

    def _ready(self, server: MapServer) -> None:
        self.url, self.feed = server.url, server.app[FEED]
        self._bound.set()

    def attach(self, session) -> None:
        """The mission's zenoh session is open: read its state publication and command through it."""
        self._handoff.offer(session)

    def stop(self, final_wait_s: float = 3.0) -> None:
        """Stop serving (and let go of the mission's session), once the mission's last snapshot
        reached the map (at most ``final_wait_s``; none when the session was never attached).
        Idempotent; blocking (on an event loop: :meth:`detach`)."""
        deadline = time.monotonic() + (final_wait_s if self._handoff.offered else 0.0)
        while time.monotonic() < deadline and self.error is None and not self.got_final():
            time.sleep(0.05)
        self._stopping.set()
        if self._loop is not None and self._stop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:
                pass  # the loop already ended
        self._thread.join(timeout=10.0)

    async def detach(self) -> None:
        """:meth:`stop` in the executor: the mission calls it before it closes its session, so
        that the map shows the mission's last snapshot (its outcome) and lets go of the session."""
        await asyncio.get_running_loop().run_in_executor(None, self.stop)

    def set_truth(self, truth_enu) -> None:
        """The simulated source (ENU m), drawn on every page from now on."""
        truth = [float(x) for x in truth_enu]

        def tell() -> None:
            if self.feed is not None:
                self.feed.config["truth_enu"] = truth
                self.feed.notice("config", self.feed.config)
        if self._loop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(tell)
            except RuntimeError:
                pass  # the map already stopped

    def got_final(self) -> bool:
        """Whether the mission's last snapshot (``final``) has been received."""
        feed = self.feed
        return feed is not None and feed.latest is not None and bool(feed.latest.get("final"))

