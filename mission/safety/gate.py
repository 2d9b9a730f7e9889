"""The safety gate: the one place where setpoints are made, limited, checked and sent.

Between what the mission wants (a goal per vehicle, set by the phases) and the datagrams on the
wire stands :class:`SafetyGate`. One task on the mission clock, on an absolute schedule at the
streaming rate, does everything per tick: it moves each vehicle's setpoint towards its goal by at
most ``max_speed_m_s`` (and ``max_vertical_speed_m_s`` vertically) times the time since the
previous burst was sent, passes the whole batch through the safety envelope (:mod:`mission.safety.envelope`:
geofence, altitude band, speed, separation) and has the
:class:`~mission.vehicle.streamer.SetpointStreamer` send it at once (``tick()``). It is the only
speed limiter: every datagram carries the batch computed in its own tick, so two consecutive
setpoints sent to a vehicle are at most ``max_speed_m_s`` times the time between the two sends
apart (``docs/safety.md``), whatever the goals do and however late the loop wakes (a late tick only
makes a longer step allowed, never a longer step than the time passed). Holding (no goal moving)
costs nothing: a settled batch is re-sent without being moved or checked again.
"""
from __future__ import annotations

import asyncio
import logging
from typing import Callable

import numpy as np

from mission.core.tasks import spawn
from mission.core.clock import cancel_and_wait
from mission.safety.separation import describe_conflicts
from mission.vehicle.streamer import SetpointStreamer

__all__ = ["SafetyGate"]

_log = logging.getLogger(__name__)


class SafetyGate:
    """Speed-limited setpoints of every vehicle, safety-checked per batch and sent in the same tick.

    Parameters
    ----------
    streamer : mission.vehicle.streamer.SetpointStreamer
        Receives ``set_target(sysid, position_enu_m)`` and ``remove(sysid)``; its ``tick()`` sends
        every tick's batch (the gate's task is the stream: do not start the streamer's own); its
        ``longest_gap_s(sysid, since_s)`` answers :meth:`stream_gap_s`.
    clock
        Mission clock.
    max_speed_m_s : float
        Largest setpoint speed.
    max_vertical_speed_m_s : float
        Largest vertical setpoint speed (multicopters descend slowly; equal vertical speeds
        keep the layered transfer's ordering argument valid).
    rate_hz : float, optional
        Ticks per clock second (setpoints moved, checked and sent); default the streamer's
        ``rate_hz``.
    envelope : object, optional
        ``mission.safety.envelope.SafetyEnvelope``; its ``clamp_setpoints(prev, new, dt_s)`` is applied to
        every batch.
    on_violation : callable, optional
        Called with a message when the envelope had to change a batch; for separation, once
        when vehicles start being held and once when the holding has been over for
        ``SEPARATION_QUIET_S`` (with the counts), not at every tick.

    Attributes
    ----------
    separation_interventions : int
        Vehicle-batches held at their previous setpoints, or moved aside, by the envelope to keep
        separation.
    separation_held_by_vehicle : dict
        The same, per sysid.

    Notes
    -----
    What the envelope returns is what is streamed and what the gate keeps as each vehicle's
    current setpoint: a held vehicle's next step starts from where it was held.
    """

    #: a separation episode is over (and reported) after this long without a hold
    SEPARATION_QUIET_S = 1.0

    def __init__(self, streamer: SetpointStreamer, clock, max_speed_m_s: float, rate_hz: float | None = None, envelope=None,
                 on_violation: Callable[[str], None] | None = None, max_vertical_speed_m_s: float = 1.0):
        self.streamer = streamer
        self.clock = clock
        self.max_speed_m_s = float(max_speed_m_s)
        self.max_vertical_speed_m_s = min(float(max_vertical_speed_m_s), self.max_speed_m_s)
        self.period_s = 1.0 / float(streamer.rate_hz if rate_hz is None else rate_hz)
        self.envelope = envelope
        self.on_violation = on_violation
        self._cmd: dict[int, np.ndarray] = {}
        self._goal: dict[int, np.ndarray] = {}
        self._task: asyncio.Task | None = None
        self._last_t: float | None = None
        self.batches = 0
        self.clamped_batches = 0
        self.reported_batches = 0
        self.safety_errors = 0
        self.separation_interventions = 0
        self.separation_held_by_vehicle: dict[int, int] = {}
        self._episode: dict | None = None
        self._settled = False
        self.idle_steps = 0
        self.late_ticks = 0

    @property
    def sysids(self) -> list[int]:
        """Vehicles with a setpoint."""
        return sorted(self._cmd)

    def add(self, sysid: int, position_enu_m) -> None:
        """Start commanding a vehicle, holding at ``position_enu_m``."""
        p = np.asarray(position_enu_m, dtype=float).copy()
        self._settled = False
        self._cmd[sysid] = p
        self._goal[sysid] = p.copy()
        self.streamer.set_target(sysid, p)

    def remove(self, sysid: int) -> None:
        """Stop commanding a vehicle (and streaming to it)."""
        self._settled = False
        self._cmd.pop(sysid, None)
        self._goal.pop(sysid, None)
        self.streamer.remove(sysid)

    def stream_gap_s(self, sysid: int, since_s: float) -> float | None:
        """The longest pause of the setpoints sent to ``sysid`` since ``since_s`` (mission clock),
        the current one included; None when the streamer cannot tell (or nothing was sent)."""
        return None if sysid not in self._cmd else self.streamer.longest_gap_s(sysid, since_s)

    def set_goal(self, sysid: int, goal_enu_m) -> None:
        """New goal of one vehicle (reached at ``max_speed_m_s``)."""
        if sysid not in self._cmd:
            raise KeyError(f"vehicle {sysid} has no setpoint yet (add it first)")
        goal = np.asarray(goal_enu_m, dtype=float).copy()
        if self._settled and not np.array_equal(goal, self._goal[sysid]):
            self._settled = False
        self._goal[sysid] = goal

    def set_goals(self, goals: dict[int, np.ndarray]) -> None:
        """New goals of several vehicles."""
        for sysid, g in goals.items():
            self.set_goal(sysid, g)

    def setpoint(self, sysid: int) -> np.ndarray:
        """The current (ramped) setpoint of a vehicle."""
        return self._cmd[sysid].copy()

    def goal(self, sysid: int) -> np.ndarray:
        """The goal of a vehicle."""
        return self._goal[sysid].copy()

    def at_goal(self, sysid: int, tol_m: float = 1e-6) -> bool:
        """Whether the setpoint has reached the goal."""
        return float(np.linalg.norm(self._cmd[sysid] - self._goal[sysid])) <= tol_m

    def step(self, dt_s: float) -> None:
        """Advance every setpoint by ``dt_s`` (also called by the task)."""
        if not self._cmd:
            return
        if self._settled:
            # every setpoint is at its goal and that batch passed the envelope unchanged: the
            # streamer repeats it; nothing to move or check until a goal or the vehicles change
            self.idle_steps += 1
            return
        sysids = list(self._cmd)
        prev = np.array([self._cmd[s] for s in sysids])
        goal = np.array([self._goal[s] for s in sysids])
        delta = goal - prev
        dist = np.linalg.norm(delta, axis=1, keepdims=True)
        max_step = self.max_speed_m_s * max(dt_s, 0.0)
        max_vstep = self.max_vertical_speed_m_s * max(dt_s, 0.0)
        scale = np.minimum(1.0, max_step / np.maximum(dist, 1e-12))
        scale = np.minimum(scale, max_vstep / np.maximum(np.abs(delta[:, 2:3]), 1e-12))
        new = prev + delta * scale
        if self.envelope is not None and max_step > 0:
            new = self._apply_envelope(prev, new, dt_s, sysids)
        for s, p in zip(sysids, new):
            self._cmd[s] = p
            self.streamer.set_target(s, p)
        self.batches += 1
        # settled when this batch moved nothing and nothing is left to move: the envelope has
        # passed these very setpoints (it is a function of the two batches only)
        self._settled = (not np.any(delta)) and bool(np.array_equal(new, prev)) and self._episode is None

    def _apply_envelope(self, prev, new, dt_s, sysids):
        try:
            res = self.envelope.clamp_setpoints(prev, new, dt_s)
        except Exception as exc:  # noqa: BLE001 - SafetyViolation etc.: hold position instead
            self.safety_errors += 1
            if self.on_violation is not None and self.safety_errors in (1, 10, 100, 1000):
                self.on_violation(f"safety envelope refused a setpoint batch ({exc}); holding")
            # hold, but never at a point outside the fence prism (e.g. below min_alt_m
            # just after takeoff): the nearest inside point
            return self.envelope.fence.clamp(prev)
        safe = np.asarray(res.positions_enu, dtype=float)
        if safe.shape != new.shape:
            return prev
        held = np.asarray(res.separation_held, dtype=bool)
        held = held if held.shape == (len(sysids),) else np.zeros(len(sysids), dtype=bool)
        aside = np.asarray(res.separation_aside, dtype=bool)
        aside = aside if aside.shape == (len(sysids),) else np.zeros(len(sysids), dtype=bool)
        self._separation(sysids, held, res.separation_conflicts, aside)
        held = held | aside
        report = res.report
        if not report.ok:
            self.reported_batches += 1
            if self.on_violation is not None and self.reported_batches in (1, 10, 100, 1000):
                self.on_violation(f"safety check: {report} ({self.reported_batches} batches so far)")
        # fence and speed changes (a separation hold is reported by _separation)
        if not np.allclose(safe[~held], new[~held], atol=1e-6):
            self.clamped_batches += 1
            if self.on_violation is not None and self.clamped_batches in (1, 10, 100, 1000):
                worst = float(np.max(np.linalg.norm(safe[~held] - new[~held], axis=1)))
                self.on_violation(f"safety envelope changed setpoints by up to {worst:.2f} m "
                                  f"({self.clamped_batches} batches so far)")
        return safe

    def _separation(self, sysids, held, conflicts, aside) -> None:
        """Count the vehicles held or moved aside for separation; one event when an episode starts,
        one when it ends."""
        now = self.clock.time()
        if held.any() or aside.any():
            who = [sysids[k] for k in np.flatnonzero(held | aside)]
            for s in who:
                self.separation_held_by_vehicle[s] = self.separation_held_by_vehicle.get(s, 0) + 1
            self.separation_interventions += len(who)
            if self._episode is None:
                self._episode = {"t0": now, "counts": {}}
                if self.on_violation is not None:
                    note = describe_conflicts(conflicts, held, self.envelope.min_separation_m, sysids, aside=aside)
                    self.on_violation(f"separation enforced: {note}")
            counts = self._episode["counts"]
            for s in who:
                counts[s] = counts.get(s, 0) + 1
            self._episode["t_last"] = now
        elif self._episode is not None and now - self._episode["t_last"] >= self.SEPARATION_QUIET_S:
            self._end_separation_episode()

    def _end_separation_episode(self) -> None:
        ep, self._episode = self._episode, None
        if ep is None or self.on_violation is None:
            return
        counts = ", ".join(f"{s}: {c}" for s, c in sorted(ep["counts"].items()))
        self.on_violation(f"separation enforcement over: {sum(ep['counts'].values())} intervention(s) in "
                          f"{ep['t_last'] - ep['t0']:.1f} s (by vehicle {counts}); "
                          f"{self.separation_interventions} in the mission so far")

    async def _run(self) -> None:
        clock, period_s = self.clock, self.period_s
        next_s = self._last_t = clock.time()
        while True:
            self._tick()
            next_s += period_s
            delay_s = next_s - clock.time()
            if delay_s < -period_s:  # more than a period behind: skip ahead, do not burst
                self.late_ticks += 1
                next_s = clock.time() + period_s
                delay_s = period_s
            await clock.sleep(max(0.0, delay_s))

    def _tick(self) -> None:
        """One tick: the setpoints moved by the time since the last burst was sent, checked, sent.

        The time base runs from just *after* the previous burst to just *before* this step, so it
        is never longer than the time between two datagrams to one vehicle as stamped on the way
        out (e.g. in a ``.tlog``), however long the envelope or the sends take on the wall clock.
        """
        # a step never covers more than five periods (after a stall the vehicles catch up gradually)
        dt = min(max(self.clock.time() - self._last_t, 0.0), 5 * self.period_s)
        if dt > 0:
            try:
                self.step(dt)
            except Exception:  # noqa: BLE001 - the setpoint task must survive anything
                _log.exception("safety gate step failed")
        self.streamer.tick()
        self._last_t = self.clock.time()

    def start(self) -> None:
        """Start the periodic task on the running loop."""
        if self._task is None:
            self._task = spawn(self._run(), "the safety gate")

    async def stop(self) -> None:
        """Stop the task: nothing more is moved or sent (the setpoints stay where they are)."""
        await cancel_and_wait(self._task)
        self._task = None
        self._end_separation_episode()
