"""Motion primitives shared by the phases: commands retried, goals flown and waited for, transfers.

* :func:`setpoint_stream`: the setpoint streamer and the safety gate driving it;
* :func:`update_odometry`: each vehicle's flown distance accumulated;
* :func:`retried`: a vehicle command retried a few rounds (lossy links);
* :func:`move_and_wait`: ramp goals set, then waited for (setpoints there, vehicles within a tolerance);
* :func:`fly_timed`: a synchronous plan fed to the ramp as interpolated goals;
* :func:`transfer_to`: a separation-keeping transfer to new slots (planned clear of obstacles);
* :func:`keep_out`: a returning lost vehicle kept out of the formation and landed;
* :func:`parked`: vehicles whose sensor was retired, parked at the formation centre.
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from mission.flight.obstacles import obstacles, plan_survivor_transfer
from mission.core.plan_types import Plan
from mission.flight.services import Clock, Events, Fleet
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate

__all__ = ["fly_timed", "keep_out", "move_and_wait", "paced", "parked", "retried", "setpoint_stream", "transfer_to",
           "update_odometry"]


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


async def move_and_wait(co, goals: dict[int, np.ndarray], tol_m: float, timeout_s: float | None = None,
                        what: str = "vehicles to reach their goals") -> None:
    """Set ramp goals and wait until every setpoint is there and every vehicle within ``tol_m``.

    Lost vehicles (``co.state.lost``, also those lost while waiting) are not waited for.
    """
    goals = {s: g for s, g in goals.items() if s not in co.state.lost and s in co.gate.sysids}
    co.gate.set_goals(goals)
    if timeout_s is None:
        far = max((float(np.linalg.norm(co.gate.setpoint(s) - g)) for s, g in goals.items()), default=0.0)
        timeout_s = 20.0 + 3.0 * far / min(co.gate.max_speed_m_s, co.gate.max_vertical_speed_m_s)

    def _arrived():
        co.update_odometry()
        for s, g in goals.items():
            if s in co.state.lost or s not in co.gate.sysids:
                continue
            if not co.gate.at_goal(s):
                return False
            p = co.telemetry_position(s)
            if p is None or float(np.linalg.norm(np.asarray(p) - g)) > tol_m:
                return False
        return True

    await co.wait_until(_arrived, timeout_s, what, poll_s=0.1)


def parked(co) -> list[int]:
    """Vehicles whose sensor was retired, still under the mission's setpoints (sorted)."""
    retired = co.state.retired
    return sorted(s for s in retired if s not in co.state.lost and co.gate is not None and s in co.gate.sysids)


async def keep_out(co, sysid: int, v, why: str) -> None:
    """Keep a returning vehicle out of the formation and command it to land (or RTL), once."""
    rtl = co.plan.return_behaviour == "rtl"
    if v is None or not v.state.armed:
        co.event(f"vehicle {sysid} is heard again after its link loss; kept out of the formation "
                 f"({why}); disarmed: not commanded", level="warning", sysid=sysid)
        co.state.keep_out(sysid, "lost (back, on the ground)")
        return
    co.event(f"vehicle {sysid} is heard again after its link loss; kept out of the formation "
             f"({why}) and commanded to {'RTL' if rtl else 'land'}", level="warning", sysid=sysid)
    co.state.keep_out(sysid, "kept out: " + ("returning" if rtl else "landing"))
    try:
        await asyncio.wait_for(v.rtl() if rtl else v.land(), timeout=30.0)
    except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported
        co.event(f"vehicle {sysid}: {'RTL' if rtl else 'land'} after its return failed: {exc}",
                 level="error", sysid=sysid)


async def transfer_to(co, sysids: list[int], new_offsets: dict, centre_enu, what: str,
                      lost_here: list[int]) -> None:
    """Fly ``sysids`` from their setpoints to ``centre_enu + new_offsets`` and adopt those slots.

    The transfer is planned by :func:`mission.flight.obstacles.plan_survivor_transfer` (separation kept
    between the vehicles and from the lost vehicles still flying, or, when no plan keeps clear of
    those, between the vehicles only; inside the fence, at 80 % of the speed limit so that the
    ramp keeps up), flown leg by leg (interpolated goals every 0.1 s
    of the mission clock); then ``co.state.slot_offsets`` is updated and the formation settles.
    Without a separation-keeping plan the vehicles fly straight under the safety envelope.
    Vehicles parked at the centre (retired sensors, :mod:`mission.flight.faults.retire`) not in ``sysids`` are
    part of the transfer too, at the new centre.
    """
    from mission.safety.transfer import TransferError

    still = parked(co)
    # a vehicle lost (and taken off the ramp) since the caller chose ``sysids`` is not flown: on the
    # wall clock that can happen while the slots were being computed
    sysids = [s for s in sysids if s in co.gate.sysids]
    members = [s for s in sysids if s not in still]  # the formation's (sensing) vehicles
    extra = [s for s in still if s not in sysids and s in co.gate.sysids]
    sysids = list(sysids) + extra
    new_offsets = {**new_offsets, **{s: np.zeros(3) for s in extra}}
    plan = co.plan
    loop = asyncio.get_running_loop()
    centre = np.asarray(centre_enu, dtype=float)
    start = np.array([co.gate.setpoint(s) for s in sysids])
    goal = np.array([centre + new_offsets[s] for s in sysids])
    fence = None if co.envelope is None else co.envelope.fence
    t0 = co.clock.time()
    try:
        tp, not_clear = await loop.run_in_executor(None, functools.partial(
            plan_survivor_transfer, start, goal, obstacles(co.state.lost, co.fleet, co.clock.time()),
            plan.min_separation_m, 0.8 * plan.max_speed_m_s,
            fence=fence))
    except (TransferError, ValueError) as exc:
        tp = not_clear = None
        co.event(f"{what}: no separation-keeping transfer ({exc}); flying straight to the new "
                 "slots under the safety envelope", level="warning")
    if not_clear:
        co.event(f"{what}: {not_clear}; the transfer keeps the survivors' separation only",
                 level="warning")
    if tp is not None:
        co.event(f"{what}: transfer {tp.strategy}, {tp.duration_s:.1f} s, closest approach "
                 f"{tp.min_separation_m:.2f} m", survivors=members, lost=lost_here, strategy=tp.strategy,
                 min_separation_m=tp.min_separation_m, slots={s: new_offsets[s] for s in sysids},
                 parked=parked(co))
        await _fly_transfer(co, sysids, tp)
    co.state.update_slots({s: new_offsets[s] for s in sysids})
    await move_and_wait(co, {s: goal[i] for i, s in enumerate(sysids)}, plan.seeking.arrival_tol_m,
                        what="the re-formed formation to settle")
    co.event(f"formation re-formed for {len(members)} vehicles in {co.clock.time() - t0:.1f} s",
             survivors=members, duration_s=co.clock.time() - t0)


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


async def _fly_transfer(co, sysids: list[int], tp) -> None:
    """Fly a planned transfer (:func:`fly_timed`)."""
    await fly_timed(co, sysids, tp.times_s, tp.waypoints_enu)


async def fly_timed(co, sysids: list[int], times_s, waypoints_enu) -> None:
    """Feed a synchronous plan's interpolated positions to the ramp as goals, every 0.1 s.

    ``waypoints_enu`` ``(K, N, 3)`` at ``times_s`` ``(K,)`` for ``sysids``; the legs are
    stretched to 80 % of the ramp's horizontal and vertical limits (:func:`_ramp_times`), so
    every vehicle follows the plan's timing and the pairs keep the separation it was checked
    for. Lost vehicles are skipped.
    """
    wps = np.asarray(waypoints_enu, dtype=float)
    ramp = co.gate
    times = _ramp_times(times_s, wps, 0.8 * ramp.max_speed_m_s,
                        0.8 * getattr(ramp, "max_vertical_speed_m_s", ramp.max_speed_m_s))
    t0 = co.clock.time()
    while True:
        t = co.clock.time() - t0
        if t >= times[-1]:
            pos = wps[-1]
        else:
            k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
            span = max(times[k + 1] - times[k], 1e-9)
            pos = wps[k] + (t - times[k]) / span * (wps[k + 1] - wps[k])
        ramp.set_goals({s: pos[i] for i, s in enumerate(sysids) if s in ramp.sysids and s not in co.state.lost})
        if t >= times[-1]:
            return
        await co.clock.sleep(0.1)
