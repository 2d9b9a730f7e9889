"""What the live map shows, kept for every page: the latest mission state, the tracks, the events.

:class:`MapFeed` is fed mission state snapshots (schema ``swarmseek.mission_state.v1``, the
state publication that ``swarmseek watch`` reads; or rebuilt from a mission log by
:mod:`mission.telemetry.map_replay`) on the map server's event loop. Each snapshot is encoded
once as a server-sent event and handed to every open page's queue; a page that cannot keep up
loses its oldest queued snapshots (counted), never the newest: the latest state supersedes the
older ones, as on zenoh. A page that connects later is sent the history first (tracks, centre
track, events), then the stream.
"""
from __future__ import annotations

import asyncio
import json
import math
import time
from collections import deque

__all__ = ["MAX_TRACK_POINTS", "MAX_EVENTS", "MapFeed", "sse_message"]

#: Points kept per vehicle track and for the centre's track (a point every 0.2 m moved at least)
MAX_TRACK_POINTS = 4000
#: Events kept for a page that connects later
MAX_EVENTS = 300
_TRACK_STEP_M = 0.2
_CLIENT_QUEUE = 16


def sse_message(event: str, data: dict) -> bytes:
    """One server-sent event ``event`` with ``data`` as one line of JSON."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n".encode()


def _finite_point(p) -> list | None:
    """``p`` as ``[e, n, u]`` of finite floats, or None."""
    if not isinstance(p, (list, tuple)) or len(p) != 3:
        return None
    try:
        out = [float(x) for x in p]
    except (TypeError, ValueError):
        return None
    return out if all(math.isfinite(x) for x in out) else None


class _Track:
    """A decimated track: a new point when it moved at least ``_TRACK_STEP_M`` from the last one."""

    def __init__(self):
        self.points: deque = deque(maxlen=MAX_TRACK_POINTS)

    def add(self, p) -> None:
        q = _finite_point(p)
        if q is None:
            return
        if self.points:
            last = self.points[-1]
            if sum((a - b) ** 2 for a, b in zip(q, last)) < _TRACK_STEP_M ** 2:
                return
        self.points.append([round(x, 2) for x in q])


class MapFeed:
    """The latest state, tracks and events, fanned out to the pages (on one event loop).

    Parameters
    ----------
    config : dict
        Sent to each page first (``read_only``, ``read_only_reason``, ``csrf_token``,
        ``tile_url``, ``truth_enu``, ``replay``, ``fleet``).

    Attributes
    ----------
    updates : int
        Snapshots received.
    dropped : int
        Snapshots a slow page did not get (its queue was full: the oldest went).
    """

    def __init__(self, config: dict):
        self.config = dict(config)
        self.latest: dict | None = None
        self.tracks: dict[str, _Track] = {}
        self.centre = _Track()
        self.events: deque = deque(maxlen=MAX_EVENTS)
        self._last_seq = 0
        self._clients: set[asyncio.Queue] = set()
        self.updates = 0
        self.dropped = 0
        self.first_wall_s: float | None = None

    def reset(self) -> None:
        """Forget the tracks, events and latest state (a replay seeking backwards)."""
        self.latest, self.tracks, self.centre = None, {}, _Track()
        self.events.clear()
        self._last_seq = 0
        self._broadcast(sse_message("reset", {}))

    def push(self, state: dict, broadcast: bool = True) -> None:
        """One snapshot: update the tracks and events, send it to every page (unless not ``broadcast``:
        a replay rebuilding its past)."""
        if self.first_wall_s is None:
            self.first_wall_s = time.time()
        self.updates += 1
        self.latest = state
        for v in state.get("vehicles") or ():
            if isinstance(v, dict) and "sysid" in v:
                self.tracks.setdefault(str(v["sysid"]), _Track()).add(v.get("position_enu"))
        self.centre.add(state.get("centre_enu"))
        for ev in state.get("events") or ():
            if isinstance(ev, dict) and isinstance(ev.get("seq"), int) and ev["seq"] > self._last_seq:
                self._last_seq = ev["seq"]
                self.events.append(ev)
        if broadcast:
            self._broadcast(sse_message("state", state))

    def history(self) -> dict:
        """Tracks, centre track and events so far (for a page that connects now)."""
        t0_s = None
        if self.latest is not None and isinstance(self.latest.get("t_s"), (int, float)) \
                and isinstance(self.latest.get("elapsed_s"), (int, float)):
            t0_s = self.latest["t_s"] - self.latest["elapsed_s"]
        return {"tracks": {s: list(t.points) for s, t in self.tracks.items()},
                "centre_track": list(self.centre.points), "events": list(self.events), "t0_s": t0_s}

    def hello(self) -> list[bytes]:
        """The first messages of a new page: the configuration, the history, the latest state."""
        out = [sse_message("config", self.config), sse_message("history", self.history())]
        if self.latest is not None:
            out.append(sse_message("state", self.latest))
        return out

    def subscribe(self) -> asyncio.Queue:
        """A new page's queue of encoded messages (starts with :meth:`hello`)."""
        q: asyncio.Queue = asyncio.Queue(maxsize=_CLIENT_QUEUE)
        for msg in self.hello():
            q.put_nowait(msg)
        self._clients.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue) -> None:
        """The page is gone."""
        self._clients.discard(q)

    @property
    def pages(self) -> int:
        """Pages connected now."""
        return len(self._clients)

    def close_pages(self) -> None:
        """End every open page's stream (the server is stopping): each queue gets ``None``, after
        which the page's handler returns instead of waiting for a message that will not come."""
        self._broadcast(None)

    def notice(self, event: str, data: dict) -> None:
        """Send a one-off message (``source``: the feed's source lost or back; ``replay``: position)."""
        self._broadcast(sse_message(event, data))

    def _broadcast(self, msg: bytes | None) -> None:
        for q in list(self._clients):
            while True:
                try:
                    q.put_nowait(msg)
                    break
                except asyncio.QueueFull:
                    q.get_nowait()
                    self.dropped += 1
