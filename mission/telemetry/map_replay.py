"""``swarmseek map --log mission.jsonl``: a flown mission played back on the live map.

The mission log's records are turned into the snapshots the state publication would have carried
(:class:`MissionLogReplay`): one per ``status`` record (every vehicle, each second of mission
time), with the phase, the latest estimate and its region (``iteration`` records), the formation's
slots (the ``formation ...`` event), the geofence and origin (the ``plan`` record), the events,
phases and commands, the true source of a simulated mission (``truth`` / ``embedded mock fleet``)
and the outcome (``summary``). :class:`ReplayPlayer` feeds them to the map at ``speed`` times
the mission's pace; the page's slider, speed and pause reach it through ``POST /api/replay``.
"""
from __future__ import annotations

import asyncio
import bisect
from pathlib import Path
from typing import Callable

from mission.core.tasks import spawn, stop_watched
from mission.telemetry.map_feed import MapFeed
from mission.telemetry.map_server import MapAccess, MapServer, make_app
from mission.telemetry.mission_log import RECENT_KINDS, RECENT_RECORDS, read_mission_log
from mission.telemetry.state_pub import STATE_SCHEMA

__all__ = ["ReplayError", "MissionLogReplay", "ReplayPlayer", "serve_replay"]

_MAX_GAP_S = 5.0  # wall seconds at most between two replayed snapshots (a long silence in the log)
_ESTIMATE_KEYS = ("iteration", "estimate_enu", "estimate_region95_m", "estimate_basis", "spread_m",
                  "distance_flown_m", "gradient", "estimate_map")


class ReplayError(ValueError):
    """The mission log cannot be replayed (missing, unreadable, no ``status`` record)."""


def _flight_state(v: dict) -> str:
    """A logged vehicle's map colour (``flight_state`` when the log has it; older logs: from its status)."""
    if v.get("flight_state"):
        return v["flight_state"]
    status = str(v.get("status", ""))
    for word in ("lost", "retired", "holding"):
        if word in status:
            return word
    return "flying" if v.get("armed") and (v.get("relative_alt_m") or 0) > 0.3 else "landed"


class MissionLogReplay:
    """The snapshots of one mission log, in time order (:attr:`frames`), and its true source."""

    def __init__(self, frames: list[dict], truth_enu: list | None):
        self.frames = frames
        self.times_s = [f["t_s"] for f in frames]
        self.truth_enu = truth_enu

    @classmethod
    def load(cls, path) -> "MissionLogReplay":
        """Read ``path``. Raises :class:`ReplayError` with one line saying why it cannot be replayed."""
        try:
            records = read_mission_log(Path(path))
        except OSError as exc:
            raise ReplayError(f"cannot read the mission log {path}: {exc.strerror or exc}") from None
        except ValueError as exc:
            raise ReplayError(str(exc)) from None
        frames, truth = _frames(records)
        if not frames:
            raise ReplayError(f"{path}: no status record to replay (a mission log of a mission that flew)")
        return cls(frames, truth)

    def index_at(self, t_s: float) -> int:
        """The last frame at or before mission time ``t_s``."""
        return max(0, bisect.bisect_right(self.times_s, t_s) - 1)


def _frames(records: list[dict]) -> tuple[list[dict], list | None]:
    """Snapshots rebuilt from ``records``, and the true source (ENU m) if the log has one."""
    base: dict = {"schema": STATE_SCHEMA, "phase": "idle", "events": [], "ending": None,
                  **{k: None for k in _ESTIMATE_KEYS}, "iteration": 0,
                  "geometry": {"origin": None, "fence_en_m": [], "slots_enu": {}}, "control": {}}
    t0_s, offsets, events, frames, truth, end_s = None, {}, [], [], None, None
    for rec in records:
        kind, t_s = rec.get("type"), rec.get("t_s")
        if not isinstance(t_s, (int, float)):
            continue
        t0_s = t_s if t0_s is None else t0_s
        end_s = t_s
        if kind in RECENT_KINDS:
            events.append(_short(rec, len(events) + 1))
        if kind == "plan" and isinstance(rec.get("plan"), dict):
            base["fleet"] = rec["plan"].get("fleet")
            fence = rec["plan"].get("geofence") or {}
            base["geometry"].update(origin=rec["plan"].get("origin"), fence_en_m=fence.get("polygon_en_m") or [],
                                    min_alt_m=fence.get("min_alt_m"), max_alt_m=fence.get("max_alt_m"))
        elif kind == "phase":
            base["phase"] = rec.get("phase", base["phase"])
        elif kind == "iteration":
            base.update({k: rec.get(k) for k in _ESTIMATE_KEYS if k in rec})
            base["iteration"] = rec.get("k", base["iteration"])
        elif kind == "event" and isinstance(rec.get("slots"), dict):
            offsets = rec["slots"]
        elif kind == "event" and rec.get("message") == "embedded mock fleet" and rec.get("source_enu"):
            truth = rec["source_enu"]
        elif kind == "truth" and rec.get("source_enu"):
            truth = rec["source_enu"]
        elif kind == "summary":
            base["ending"] = {"outcome": rec.get("outcome"), "message": rec.get("message")}
        elif kind == "status":
            frames.append(_frame(base, rec, t_s, t0_s, offsets, events))
    if frames:
        last = dict(frames[-1], final=True, phase="done", ending=base["ending"], events=events[-RECENT_RECORDS:],
                    t_s=max(end_s, frames[-1]["t_s"]), elapsed_s=max(end_s, frames[-1]["t_s"]) - t0_s)
        frames.append(last)
    return frames, truth


def _short(rec: dict, seq: int) -> dict:
    out = {"seq": seq, "t_s": rec["t_s"], "type": rec["type"]}
    for key in ("level", "message", "phase", "command", "sender", "accepted", "reason"):
        if key in rec:
            out[key] = rec[key]
    return out


def _frame(base: dict, rec: dict, t_s: float, t0_s: float, offsets: dict, events: list) -> dict:
    centre = rec.get("centre_enu")
    vehicles = [dict(v, flight_state=_flight_state(v)) for v in rec.get("vehicles") or () if isinstance(v, dict)]
    slots = {}
    if isinstance(centre, list) and len(centre) == 3:
        slots = {s: [c + o for c, o in zip(centre, off)] for s, off in offsets.items()
                 if isinstance(off, list) and len(off) == 3}
    return {**base, "geometry": {**base["geometry"], "slots_enu": slots}, "phase": rec.get("phase", base["phase"]),
            "t_s": t_s, "elapsed_s": t_s - t0_s, "centre_enu": centre, "vehicles": vehicles,
            "events": events[-RECENT_RECORDS:]}


class ReplayPlayer:
    """Plays a :class:`MissionLogReplay` into a feed at ``speed`` (mission s per wall s)."""

    def __init__(self, replay: MissionLogReplay, feed: MapFeed, speed: float = 1.0):
        self.replay, self.feed = replay, feed
        self.speed = float(speed)
        self.paused = False
        self.index = 0
        self._wake = asyncio.Event()

    def control(self, body: dict) -> None:
        """``{"seek_s": s}`` (mission seconds from the start), ``{"speed": x}``, ``{"paused": bool}``."""
        if isinstance(body.get("speed"), (int, float)) and 0 < body["speed"] <= 1000:
            self.speed = float(body["speed"])
        if isinstance(body.get("paused"), bool):
            self.paused = body["paused"]
        if isinstance(body.get("seek_s"), (int, float)):
            self.seek(self.replay.times_s[0] + float(body["seek_s"]))
        self._wake.set()

    def seek(self, t_s: float) -> None:
        """Jump to mission time ``t_s``: the feed is rebuilt up to there and sent to the pages."""
        self.index = self.replay.index_at(t_s)
        self.feed.reset()
        for frame in self.replay.frames[:self.index]:
            self.feed.push(frame, broadcast=False)
        self.feed.notice("history", self.feed.history())
        self.feed.push(self.replay.frames[self.index])

    async def run(self) -> None:
        """Play to the end (then stay on the last snapshot)."""
        frames = self.replay.frames
        self.feed.push(frames[0])
        while True:
            self._wake.clear()
            if self.paused or self.index >= len(frames) - 1:
                await self._wake.wait()
                continue
            gap_s = min(_MAX_GAP_S, (frames[self.index + 1]["t_s"] - frames[self.index]["t_s"]) / self.speed)
            try:
                await asyncio.wait_for(self._wake.wait(), timeout=max(0.0, gap_s))
                continue  # a seek, a new speed or a pause: go on from where the player is now
            except asyncio.TimeoutError:
                self.index += 1
                self.feed.push(frames[self.index])


async def serve_replay(replay: MissionLogReplay, host: str, port: int, *, access: MapAccess, config: dict,
                       speed: float, ready: Callable[[MapServer], None], stop: asyncio.Event) -> None:
    """Serve the replay of ``replay`` on ``host:port`` until ``stop`` is set (``OSError``: cannot bind)."""
    first = replay.frames[0]
    feed = MapFeed({**config, "fleet": first.get("fleet"), "read_only": True,
                    "read_only_reason": access.read_only_reason, "csrf_token": access.csrf_token, "login": False,
                    "truth_enu": replay.truth_enu,
                    "replay": {"t0_s": replay.times_s[0], "t1_s": replay.times_s[-1], "speed": speed}})
    player = ReplayPlayer(replay, feed, speed)
    server = MapServer(make_app(feed, access, None, player=player), host, port)
    await server.start()
    task = spawn(player.run(), "the replay")
    try:
        ready(server)
        await stop.wait()
    finally:
        await stop_watched(task)
        await server.stop()
