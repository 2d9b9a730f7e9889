"""Motion primitives shared by the phases: commands retried, goals flown and waited for, transfers.

* :func:`setpoint_stream`: the setpoint streamer and the safety gate driving it;
* :func:`update_odometry`: each vehicle's flown distance accumulated;
* :func:`retried`: a vehicle command retried a few rounds (lossy links);
* :class:`GateMotion`: the formation's moves on the safety gate, built from narrow services (the
  :class:`mission.flight.services.Motion` the fault responses, the return and the seek are handed):
  ``move_and_wait`` (gate goals set, then waited for: setpoints there, vehicles within a tolerance),
  ``fly_timed`` (a synchronous plan fed to the gate as interpolated goals), ``transfer_to`` (a
  separation-keeping transfer to new slots, planned clear of obstacles), ``keep_out`` (a returning
  lost vehicle kept out of the formation and landed), ``parked`` (vehicles whose sensor was retired,
  parked at the formation centre).
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from typing import Any, Callable

from mission.flight.obstacles import obstacles, plan_survivor_transfer
from mission.core.plan_types import Plan
from mission.flight.services import Clock, Events, Fleet, Waiter
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate

__all__ = ["GateMotion", "paced", "retried", "setpoint_stream", "update_odometry"]


def setpoint_stream(vehicles: list, plan: Plan, clock: Clock, envelope, events: Events):
    """A setpoint streamer for ``vehicles`` and the safety gate driving it: ``(streamer, gate)``
    (not started: ``gate.start()`` starts both).

    The gate (:class:`mission.safety.gate.SafetyGate`) moves, checks (against ``envelope``, a
    :class:`mission.safety.envelope.SafetyEnvelope` or None) and sends every vehicle's setpoint
    at the plan's ``setpoint_rate_hz``, in one task: the one speed limiter. Its violations are
    warning events.
    """
    from mission.vehicle.streamer import SetpointStreamer

    streamer = SetpointStreamer(vehicles, rate_hz=plan.setpoint_rate_hz, clock=clock)
    gate = SafetyGate(streamer, clock, plan.max_speed_m_s,
                      envelope=envelope, on_violation=lambda m: events.event(m, level="warning"))
    return streamer, gate


def update_odometry(state: MissionState, fleet: Fleet) -> None:
    """Accumulate each vehicle's flown distance (``state``) from its telemetry position."""
    state.add_positions({s: fleet.telemetry_position(s) for s in fleet.vehicles})


async def paced(clock, period_s: float, last_s: float) -> float:
    """The clock's time now, returned after waiting out what is left of ``period_s`` since
    ``last_s`` (the seek loop's ``1 / rate_hz`` between estimates)."""
    t_s = clock.time()
    wait_s = period_s - (t_s - last_s)
    if wait_s > 0:
        await clock.sleep(wait_s)
    return t_s


async def retried(events: Events, clock: Clock, action, what: str, attempts: int = 3):
    """Run ``action()`` (a command coroutine, itself retried by ``command_long``) up to ``attempts``
    times: on a lossy link (20 % each way) one command with its 4 sends fails 1.7 % of the
    time; three rounds make it 5e-6. The commands used (mode, arm, takeoff, land) are idempotent."""
    for i in range(attempts):
        try:
            return await action()
        except Exception as exc:  # noqa: BLE001 - CommandError or link error
            if i + 1 == attempts:
                raise MissionError(f"{what} failed after {attempts} rounds of retries: {exc}") from None
            events.event(f"{what}: {exc}; trying again", level="warning")
            await clock.sleep(0.5)


class GateMotion:
    """The moves of the formation flown on the safety gate: goals set and waited for, timed plans,
    separation-keeping transfers, returning vehicles kept out, parked vehicles.

    The :class:`mission.flight.services.Motion` the fault responses, the return and the seek are
    handed. Lost vehicles (``state.lost``, also those lost while moving) are skipped by every move.

    Parameters
    ----------
    state : MissionState
        Losses, retired sensors, slots (updated by a transfer), odometry.
    fleet : Fleet
        The connected vehicles (telemetry positions; lost vehicles still flying as obstacles).
    gate : callable
        The mission's safety gate now (:class:`mission.safety.gate.SafetyGate`, None before the
        takeoff): the gate is opened after this object is built, and again on a resume.
    fence : callable
        The geofence the transfers are planned inside now (None: no envelope yet, or no fence).
    clock : Clock
    events : Events
    waiter : Waiter
        Waits on the mission clock; an operator's stop ends the wait.
    return_behaviour : str
        ``"rtl"`` or ``"land"``: what a vehicle kept out is commanded to do.
    min_separation_m, max_speed_m_s : float
        The plan's separation and speed limit (transfers are planned at 80 % of the speed).
    arrival_tol_m : float
        The seeking section's arrival tolerance (a re-formed formation settles within it).
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: Callable[[], SafetyGate | None],
                 fence: Callable[[], Any], clock: Clock, events: Events, waiter: Waiter, *,
                 return_behaviour: str, min_separation_m: float, max_speed_m_s: float,
                 arrival_tol_m: float) -> None:
        self.state, self.fleet, self.gate, self.fence = state, fleet, gate, fence
        self.clock, self.events, self.waiter = clock, events, waiter
        self.rtl = return_behaviour == "rtl"
        self.min_separation_m, self.max_speed_m_s = float(min_separation_m), float(max_speed_m_s)
        self.arrival_tol_m = float(arrival_tol_m)

    async def move_and_wait(self, goals: dict[int, np.ndarray], tol_m: float, timeout_s: float | None = None,
                            what: str = "vehicles to reach their goals") -> None:
        """Set gate goals and wait until every setpoint is there and every vehicle within ``tol_m``.

        Lost vehicles (also those lost while waiting) are not waited for.
        """
        gate, state = self.gate(), self.state
        goals = {s: g for s, g in goals.items() if s not in state.lost and s in gate.sysids}
        gate.set_goals(goals)
        if timeout_s is None:
            far = max((float(np.linalg.norm(gate.setpoint(s) - g)) for s, g in goals.items()), default=0.0)
            timeout_s = 20.0 + 3.0 * far / min(gate.max_speed_m_s, gate.max_vertical_speed_m_s)

        def _arrived():
            update_odometry(state, self.fleet)
            for s, g in goals.items():
                if s in state.lost or s not in gate.sysids:
                    continue
                if not gate.at_goal(s):
                    return False
                p = self.fleet.telemetry_position(s)
                if p is None or float(np.linalg.norm(np.asarray(p) - g)) > tol_m:
                    return False
            return True

        await self.waiter.wait_until(_arrived, timeout_s, what, poll_s=0.1)

    def parked(self) -> list[int]:
        """Vehicles whose sensor was retired, still under the mission's setpoints (sorted)."""
        gate, state = self.gate(), self.state
        return sorted(s for s in state.retired if s not in state.lost and gate is not None and s in gate.sysids)

    async def keep_out(self, sysid: int, v, why: str) -> None:
        """Keep a returning vehicle out of the formation and command it to land (or RTL), once."""
        rtl, events = self.rtl, self.events
        if v is None or not v.state.armed:
            events.event(f"vehicle {sysid} is heard again after its link loss; kept out of the formation "
                         f"({why}); disarmed: not commanded", level="warning", sysid=sysid)
            self.state.keep_out(sysid, "lost (back, on the ground)")
            return
        events.event(f"vehicle {sysid} is heard again after its link loss; kept out of the formation "
                     f"({why}) and commanded to {'RTL' if rtl else 'land'}", level="warning", sysid=sysid)
        self.state.keep_out(sysid, "kept out: " + ("returning" if rtl else "landing"))
        try:
            await asyncio.wait_for(v.rtl() if rtl else v.land(), timeout=30.0)
        except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported
            events.event(f"vehicle {sysid}: {'RTL' if rtl else 'land'} after its return failed: {exc}",
                         level="error", sysid=sysid)

    async def transfer_to(self, sysids: list[int], new_offsets: dict, centre_enu, what: str,
                          lost_here: list[int]) -> None:
        """Fly ``sysids`` from their setpoints to ``centre_enu + new_offsets`` and adopt those slots.

        The transfer is planned by :func:`mission.flight.obstacles.plan_survivor_transfer` (separation
        kept between the vehicles and from the lost vehicles still flying, or, when no plan keeps
        clear of those, between the vehicles only; inside the fence, at 80 % of the speed limit so
        that the gate keeps up), flown leg by leg (:meth:`fly_timed`); then ``state.slot_offsets``
        is updated and the formation settles. Without a separation-keeping plan the vehicles fly
        straight under the safety envelope. Vehicles parked at the centre (retired sensors,
        :mod:`mission.flight.faults.retire`) not in ``sysids`` are part of the transfer too, at the
        new centre.
        """
        gate, events, t0 = self.gate(), self.events, self.clock.time()
        still = self.parked()
        # a vehicle lost (and taken off the gate) since the caller chose ``sysids`` is not flown: on
        # the wall clock that can happen while the slots were being computed
        sysids = [s for s in sysids if s in gate.sysids]
        members = [s for s in sysids if s not in still]  # the formation's (sensing) vehicles
        extra = [s for s in still if s not in sysids and s in gate.sysids]
        sysids = list(sysids) + extra
        new_offsets = {**new_offsets, **{s: np.zeros(3) for s in extra}}
        centre = np.asarray(centre_enu, dtype=float)
        start = np.array([gate.setpoint(s) for s in sysids])
        goal = np.array([centre + new_offsets[s] for s in sysids])
        tp, not_clear = await self._plan_transfer(start, goal, what)
        if not_clear:
            events.event(f"{what}: {not_clear}; the transfer keeps the survivors' separation only",
                         level="warning")
        if tp is not None:
            events.event(f"{what}: transfer {tp.strategy}, {tp.duration_s:.1f} s, closest approach "
                         f"{tp.min_separation_m:.2f} m", survivors=members, lost=lost_here, strategy=tp.strategy,
                         min_separation_m=tp.min_separation_m, slots={s: new_offsets[s] for s in sysids},
                         parked=self.parked())
            await self.fly_timed(sysids, tp.times_s, tp.waypoints_enu)
        self.state.update_slots({s: new_offsets[s] for s in sysids})
        await self.move_and_wait({s: goal[i] for i, s in enumerate(sysids)}, self.arrival_tol_m,
                                 what="the re-formed formation to settle")
        events.event(f"formation re-formed for {len(members)} vehicles in {self.clock.time() - t0:.1f} s",
                     survivors=members, duration_s=self.clock.time() - t0)

    async def _plan_transfer(self, start: np.ndarray, goal: np.ndarray, what: str):
        """``(transfer plan, not clear)`` from ``start`` to ``goal`` (off the event loop), or
        ``(None, None)`` (told) when no separation-keeping plan exists."""
        from mission.safety.transfer import TransferError

        loop = asyncio.get_running_loop()
        try:
            return await loop.run_in_executor(None, functools.partial(
                plan_survivor_transfer, start, goal, obstacles(self.state.lost, self.fleet, self.clock.time()),
                self.min_separation_m, 0.8 * self.max_speed_m_s, fence=self.fence()))
        except (TransferError, ValueError) as exc:
            self.events.event(f"{what}: no separation-keeping transfer ({exc}); flying straight to the new "
                              "slots under the safety envelope", level="warning")
            return None, None

    async def fly_timed(self, sysids: list[int], times_s, waypoints_enu) -> None:
        """Feed a synchronous plan's interpolated positions to the gate as goals, every 0.1 s.

        ``waypoints_enu`` ``(K, N, 3)`` at ``times_s`` ``(K,)`` for ``sysids``; the legs are
        stretched to 80 % of the gate's horizontal and vertical limits (:func:`_ramp_times`), so
        every vehicle follows the plan's timing and the pairs keep the separation it was checked
        for. Lost vehicles are skipped.
        """
        wps = np.asarray(waypoints_enu, dtype=float)
        gate, clock, state = self.gate(), self.clock, self.state
        times = _ramp_times(times_s, wps, 0.8 * gate.max_speed_m_s, 0.8 * gate.max_vertical_speed_m_s)
        t0 = clock.time()
        while True:
            t = clock.time() - t0
            if t >= times[-1]:
                pos = wps[-1]
            else:
                k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
                span = max(times[k + 1] - times[k], 1e-9)
                pos = wps[k] + (t - times[k]) / span * (wps[k + 1] - wps[k])
            gate.set_goals({s: pos[i] for i, s in enumerate(sysids) if s in gate.sysids and s not in state.lost})
            if t >= times[-1]:
                return
            await clock.sleep(0.1)


def _ramp_times(times_s, waypoints_enu, max_speed_m_s: float, max_vertical_speed_m_s: float) -> np.ndarray:
    """Waypoint times no faster than the ramp: every leg at least as long as its slowest vehicle
    needs under the horizontal and the vertical speed limits.

    The planned legs are synchronous straight lines, so stretching a leg keeps the geometry (and
    the separation) of the plan; a leg timed faster than the ramp can fly (the planner's single
    speed applies to the climbs of the layered strategies too, the ramp climbs at 1 m/s) would
    let each vehicle lag by its own amount, out of step with the others.
    """
    t = np.asarray(times_s, dtype=float)
    d = np.diff(np.asarray(waypoints_enu, dtype=float), axis=0)          # (K-1, N, 3)
    need = np.maximum(np.linalg.norm(d, axis=-1) / max_speed_m_s,
                      np.abs(d[..., 2]) / max_vertical_speed_m_s).max(axis=1, initial=0.0)
    return np.r_[0.0, np.cumsum(np.maximum(np.diff(t), need))]
