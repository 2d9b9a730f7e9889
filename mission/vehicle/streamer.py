"""Stream every vehicle's latest position setpoint at a steady rate from one asyncio task.

One task wakes at ``rate_hz`` on the mission clock (absolute schedule: no drift) and sends the
latest target of every vehicle, one non-blocking datagram each, so no vehicle waits for another.
The order rotates every tick so that the same vehicle is not always the last one of the burst.
If the loop falls more than a period behind, it skips ahead rather than bursting to catch up.

The streamer sends targets as they are: it limits nothing. In a mission its own task is not
started; the safety gate (:class:`mission.safety.gate.SafetyGate`, the one speed limiter) calls
:meth:`SetpointStreamer.tick` right after each batch it made, so that what is sent is what the
gate checked, tick for tick.
"""
from __future__ import annotations

import asyncio
import math
import collections

import numpy as np

from mission.core.tasks import spawn
from mission.core.clock import WallClock, cancel_and_wait

__all__ = ["SetpointStreamer"]

_HISTORY = 1200


class _Track:
    __slots__ = ("target", "yaw", "sent", "errors", "last_s", "intervals", "first_s", "last_error")

    def __init__(self) -> None:
        self.target = None
        self.yaw = None
        self.sent = 0
        self.errors = 0
        self.last_s = None
        self.first_s = None
        self.last_error = None
        self.intervals: collections.deque = collections.deque(maxlen=_HISTORY)


class SetpointStreamer:
    """Send each vehicle's latest setpoint at ``rate_hz``.

    Parameters
    ----------
    vehicles : list of VehicleLink
        Vehicles that may be streamed to (a vehicle is streamed once it has a target).
    rate_hz : float
        Setpoints per clock second per vehicle.
    clock : object, optional
        Mission clock; default :class:`~mission.core.clock.WallClock`.

    Attributes
    ----------
    ticks : int
        Bursts sent so far.
    late_ticks : int
        Ticks that started more than one period late (the schedule was reset).
    """

    def __init__(self, vehicles, rate_hz: float = 10.0, clock=None) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.clock = clock if clock is not None else WallClock()
        self._vehicles = {v.sysid: v for v in vehicles}
        self._tracks = {sysid: _Track() for sysid in self._vehicles}
        self._task: asyncio.Task | None = None
        self._offset = 0
        self.ticks = 0
        self.late_ticks = 0

    def add(self, vehicle) -> None:
        """Add a vehicle (not streamed until it gets a target)."""
        self._vehicles[vehicle.sysid] = vehicle
        self._tracks.setdefault(vehicle.sysid, _Track())

    def set_target(self, sysid: int, position_enu_m, yaw_rad: float | None = None) -> None:
        """Set the mission-frame ENU target of ``sysid``; streamed from the next tick on.

        Raises
        ------
        KeyError
            Unknown system id.
        ValueError
            Not three finite numbers.
        """
        track = self._tracks.get(sysid)
        if track is None:
            raise KeyError(f"vehicle {sysid} is not in this streamer (known: {sorted(self._tracks)})")
        if type(position_enu_m) is np.ndarray and position_enu_m.shape == (3,):
            position_enu_m = position_enu_m.tolist()  # the ramp's rows: one call, not three numpy scalars
        e, n, u = position_enu_m
        e, n, u = float(e), float(n), float(u)
        if not (math.isfinite(e) and math.isfinite(n) and math.isfinite(u)):
            raise ValueError(f"vehicle {sysid}: setpoint must be finite, got {(e, n, u)}")
        track.target = (e, n, u)
        track.yaw = None if yaw_rad is None else float(yaw_rad)

    def target(self, sysid: int):
        """The current target of ``sysid`` as ``(east_m, north_m, up_m)``, or None."""
        return self._tracks[sysid].target

    def remove(self, sysid: int) -> None:
        """Stop streaming to ``sysid`` (its target is dropped; statistics are kept)."""
        track = self._tracks.get(sysid)
        if track is not None:
            track.target = None
            track.last_s = None

    async def start(self) -> None:
        """Start the streaming task (idempotent)."""
        if self._task is None or self._task.done():
            self._task = spawn(self._run(), "the setpoint stream")

    async def stop(self) -> None:
        """Stop the streaming task and wait for it."""
        task, self._task = self._task, None
        await cancel_and_wait(task)

    @property
    def running(self) -> bool:
        """True while the task runs."""
        return self._task is not None and not self._task.done()

    def tick(self) -> int:
        """Send one burst now (the task calls this; usable directly). Returns datagrams sent."""
        now = self.clock.time()
        items = list(self._tracks.items())
        if not items:
            return 0
        k = self._offset % len(items)
        self._offset += 1
        sent = 0
        for sysid, track in items[k:] + items[:k]:
            if track.target is None:
                continue
            try:
                self._vehicles[sysid].send_position_enu(track.target, track.yaw)
            except Exception as exc:  # one vehicle's problem must not starve the others
                track.errors += 1
                track.last_error = str(exc)
                continue
            if track.last_s is not None:
                track.intervals.append(now - track.last_s)
            else:
                track.first_s = now
            track.last_s = now
            track.sent += 1
            sent += 1
        self.ticks += 1
        return sent

    async def _run(self) -> None:
        clock = self.clock
        period_s = 1.0 / self.rate_hz
        next_s = clock.time()
        while True:
            self.tick()
            next_s += period_s
            delay_s = next_s - clock.time()
            if delay_s < -period_s:
                self.late_ticks += 1
                next_s = clock.time() + period_s
                delay_s = period_s
            await clock.sleep(max(0.0, delay_s))

    def longest_gap_s(self, sysid: int, since_s: float) -> float | None:
        """The longest time without a setpoint sent to ``sysid`` from ``since_s`` (clock time) to
        now, the time since the last send included (None: never sent to, or not streamed).

        A gap this long in the stream could have made the autopilot leave its offboard/guided
        mode by itself (PX4's offboard loss after ``COM_OF_LOSS_T``). A stream that began after
        ``since_s`` (e.g. a resume taking over vehicles its predecessor left) was a pause until
        then: ``inf``.
        """
        track = self._tracks.get(sysid)
        if track is None or track.last_s is None:
            return None
        if track.first_s is None or track.first_s > since_s:
            return float("inf")
        gap = max(self.clock.time() - track.last_s, 0.0)
        t = track.last_s
        for interval in reversed(track.intervals):
            if t <= since_s:
                break
            gap = max(gap, interval)
            t -= interval
        return gap

    def measured_rate_hz(self, sysid: int) -> float | None:
        """Setpoints per second to ``sysid`` over the recent history (None before two sends)."""
        intervals = self._tracks[sysid].intervals
        total = sum(intervals)
        return len(intervals) / total if intervals and total > 0 else None

    def stats(self, sysid: int) -> dict:
        """Sending statistics of ``sysid`` (sender side, clock seconds).

        Returns
        -------
        dict
            ``sent``, ``errors``, ``last_error``, ``rate_hz`` (over the recent history),
            ``p50_interval_s``, ``p99_interval_s`` (None before two sends).
        """
        track = self._tracks[sysid]
        out = {"sent": track.sent, "errors": track.errors, "last_error": track.last_error,
               "rate_hz": None, "p50_interval_s": None, "p99_interval_s": None}
        if track.intervals:
            intervals = np.fromiter(track.intervals, dtype=float)
            total = float(intervals.sum())
            out["rate_hz"] = len(intervals) / total if total > 0 else None
            out["p50_interval_s"] = float(np.percentile(intervals, 50))
            out["p99_interval_s"] = float(np.percentile(intervals, 99))
        return out
