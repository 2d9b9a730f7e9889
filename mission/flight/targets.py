"""Speed-limited setpoint targets, the safety check on every batch, and layered transfers.

:class:`TargetRamp` owns the position setpoint of every vehicle in flight. A task on the mission
clock moves each vehicle's setpoint towards its goal by at most ``max_speed_m_s * dt`` per tick
(so consecutive setpoints never exceed the speed limit), passes the whole batch through the
safety envelope (``mission.safety.envelope``: geofence, altitude band, speed, separation) and hands it to
the :class:`~mission.vehicle.streamer.SetpointStreamer`, which streams the latest setpoint of every
vehicle at its own steady rate.

:func:`layered_transfer` plans a formation change that keeps separation: vehicles first move
vertically to their altitude layers, then horizontally at them, then vertically to their goals
(proved in ``docs/mission.md``). The layers come from
:func:`mission.flight.layers.shared_layers` (shared by vehicles whose paths keep apart);
:func:`layered_altitudes` (one layer per vehicle) is kept for small fleets and tests.
"""
from __future__ import annotations

import asyncio
import logging
from typing import Callable

import numpy as np

from mission.core.tasks import spawn
from mission.core.clock import cancel_and_wait
from mission.safety.separation import describe_conflicts

__all__ = ["TargetRamp", "layered_altitudes", "layered_transfer", "assign_slots"]

_log = logging.getLogger(__name__)


def assign_slots(current_positions, slots) -> np.ndarray:
    """Minimum total squared travel assignment: ``perm[i]`` is the slot of vehicle ``i``.

    Uses ``formation.assign_slots`` when available, else ``scipy.optimize.linear_sum_assignment``.
    """
    cur = np.asarray(current_positions, dtype=float)
    sl = np.asarray(slots, dtype=float)
    try:
        from formation import assign_slots as _fa  # type: ignore[attr-defined]
    except ImportError:
        _fa = None
    if _fa is not None:
        perm, _ = _fa(cur, sl, allow_rotation=False)
        return np.asarray(perm, dtype=int)
    from scipy.optimize import linear_sum_assignment

    cost = np.sum((cur[:, None, :] - sl[None, :, :]) ** 2, axis=-1)
    rows, cols = linear_sum_assignment(cost)
    perm = np.empty(len(cur), dtype=int)
    perm[rows] = cols
    return perm


def layered_altitudes(n: int, low_m: float, high_m: float, min_separation_m: float) -> np.ndarray:
    """``n`` distinct altitudes from ``low_m`` upwards, ``1.25 * min_separation_m`` apart.

    Raises
    ------
    ValueError
        They do not fit below ``high_m``.
    """
    spacing = 1.25 * float(min_separation_m)
    alts = low_m + spacing * np.arange(n)
    if n and alts[-1] > high_m:
        raise ValueError(f"{n} altitude layers {spacing:.2f} m apart from {low_m:.1f} m need up to "
                         f"{alts[-1]:.1f} m, above the allowed {high_m:.1f} m: widen the geofence "
                         f"altitude band or lower takeoff_alt_m")
    return alts


def layered_transfer(start, goal, layer_alt_m) -> list[np.ndarray]:
    """Waypoint batches ``[(N,3), ...]`` from ``start`` to ``goal`` keeping the layers' separation.

    Step 1: each vehicle to its layer altitude above its start; step 2: horizontally to above its
    goal at its layer; step 3: vertically to its goal. Every vehicle finishes a step before any
    begins the next (the caller waits for arrival between batches). Separation holds when the
    layers are ordered like the goals' altitudes where goals are horizontally close: the caller
    orders layers by goal altitude.
    """
    s = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    lay = np.asarray(layer_alt_m, dtype=float)
    up = s.copy()
    up[:, 2] = lay
    across = g.copy()
    across[:, 2] = lay
    return [up, across, g.copy()]


class TargetRamp:
    """Speed-limited setpoints of every vehicle, safety-checked per batch, fed to a streamer.

    Parameters
    ----------
    streamer : mission.vehicle.streamer.SetpointStreamer
        Receives ``set_target(sysid, position_enu_m)``.
    clock
        Mission clock.
    max_speed_m_s : float
        Largest setpoint speed.
    max_vertical_speed_m_s : float
        Largest vertical setpoint speed (multicopters descend slowly; equal vertical speeds
        keep the layered transfer's ordering argument valid).
    rate_hz : float
        Update rate of the setpoints (mission clock).
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
        Vehicle-batches held at their previous setpoints by the envelope to keep separation.
    separation_held_by_vehicle : dict
        The same, per sysid.

    Notes
    -----
    What the envelope returns is what is streamed and what the ramp keeps as each vehicle's
    current setpoint: a held vehicle's next step starts from where it was held.
    """

    #: a separation episode is over (and reported) after this long without a hold
    SEPARATION_QUIET_S = 1.0

    def __init__(self, streamer, clock, max_speed_m_s: float, rate_hz: float = 10.0, envelope=None,
                 on_violation: Callable[[str], None] | None = None, max_vertical_speed_m_s: float = 1.0):
        self.streamer = streamer
        self.clock = clock
        self.max_speed_m_s = float(max_speed_m_s)
        self.max_vertical_speed_m_s = min(float(max_vertical_speed_m_s), self.max_speed_m_s)
        self.period_s = 1.0 / float(rate_hz)
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
        safe = np.asarray(getattr(res, "positions_enu", res), dtype=float)
        if safe.shape != new.shape:
            return prev
        held = np.asarray(getattr(res, "separation_held", ()), dtype=bool)
        held = held if held.shape == (len(sysids),) else np.zeros(len(sysids), dtype=bool)
        self._separation(sysids, held, getattr(res, "separation_conflicts", ()))
        report = getattr(res, "report", None)
        if report is not None and not report.ok:
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

    def _separation(self, sysids, held, conflicts) -> None:
        """Count the vehicles held for separation; one event when an episode starts, one when it ends."""
        now = self.clock.time()
        if held.any():
            who = [sysids[k] for k in np.flatnonzero(held)]
            for s in who:
                self.separation_held_by_vehicle[s] = self.separation_held_by_vehicle.get(s, 0) + 1
            self.separation_interventions += len(who)
            if self._episode is None:
                self._episode = {"t0": now, "counts": {}}
                if self.on_violation is not None:
                    note = describe_conflicts(conflicts, held, self.envelope.min_separation_m, sysids)
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
        self._last_t = self.clock.time()
        while True:
            await self.clock.sleep(self.period_s)
            now = self.clock.time()
            dt = min(max(now - self._last_t, 0.0), 5 * self.period_s)
            self._last_t = now
            try:
                self.step(dt)
            except Exception:  # noqa: BLE001 - the setpoint task must survive anything
                _log.exception("target ramp step failed")

    def start(self) -> None:
        """Start the periodic task on the running loop."""
        if self._task is None:
            self._task = spawn(self._run(), "the target ramp")

    async def stop(self) -> None:
        """Stop the task (setpoints stay where they are)."""
        await cancel_and_wait(self._task)
        self._task = None
        self._end_separation_episode()
