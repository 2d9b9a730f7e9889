"""Vehicle loss: detection, the re-formed formation for the survivors, and returning vehicles.

Rules (see ``docs/faults.md``):

* **link lost**: no MAVLink message from the vehicle for ``[faults] link_timeout_s`` (1 s) of
  the mission clock (crash, link cut, vehicle switched off). Checked every 0.1 s of the mission
  clock, hence detected within 1.1 s of the last frame heard.
* **left the mission**: the autopilot switched, without being asked, to a mode that ends its
  part in the mission: RTL or LAND (PX4 ``AUTO.RTL`` / ``AUTO.LAND``, ArduPilot ``RTL``,
  ``SMART_RTL``, ``LAND``): a failsafe (low battery, geofence, GCS loss) or a pilot. The
  coordinator does not fight it. Any *other* mode change (PX4 offboard loss -> hold, ArduPilot
  GUIDED -> LOITER/BRAKE) is re-engaged by the watchdog (``mission.flight.coordinator``). A vehicle
  that disarms in the air (not commanded) also left.
* A lost vehicle is taken off the setpoint stream, released (never re-engaged) and no longer
  waited for; the seek loop re-forms the formation for the survivors (:func:`reformed_offsets`)
  and flies a separation-keeping transfer (:func:`mission.safety.envelope.plan_transfer`) to it.
* **coming back** (link heard again after a link loss): with ``[faults] readmit = false`` the
  vehicle is kept out and commanded to land or RTL (the plan's ``return``), once; with
  ``readmit = true`` and during the seek, armed, airborne and not in RTL/LAND, it is re-admitted
  at the start of the next iteration (:func:`mission.flight.rejoin.readmit`).
* A lost vehicle that still flies is an obstacle for the re-formed slots and the transfers
  (:mod:`mission.flight.rejoin`).
"""
from __future__ import annotations

import asyncio
import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["LEFT_MODES", "VehicleLoss", "classify_loss", "keep_out", "reform", "reformed_offsets", "survivor_slots",
           "fly_timed", "transfer_to", "watch_losses"]

#: modes that mean "this vehicle left the mission" when the coordinator did not ask for them
LEFT_MODES = {"px4": frozenset({"AUTO.RTL", "AUTO.LAND"}),
              "ardupilot": frozenset({"RTL", "SMART_RTL", "LAND"})}


@dataclass
class VehicleLoss:
    """One lost vehicle.

    Attributes
    ----------
    sysid : int
    reason : str
        ``link`` (silent) or ``left`` (failsafe / unrequested mode, or disarmed in the air).
    detail : str
        Human-readable cause (mode seen, silence length).
    detected_s : float
        Mission clock at detection.
    since_s : float
        Mission clock of the last frame heard (``link``) or of the first sight of the new
        mode (``left``); ``detected_s - since_s`` is the detection latency seen by the coordinator.
    phase : str
        Coordinator phase at detection.
    came_back_s : float or None
        Mission clock when its frames were heard again (link losses).
    last_setpoint_enu : numpy.ndarray or None
        Its last setpoint when it was lost (a silent vehicle may still fly there).
    readmit_pending : bool
        Heard again and waiting for re-admission at the next seek iteration.
    """

    sysid: int
    reason: str
    detail: str
    detected_s: float
    since_s: float
    phase: str = ""
    came_back_s: float | None = None
    last_setpoint_enu: np.ndarray | None = None
    readmit_pending: bool = False

    @property
    def latency_s(self) -> float:
        """Seconds from the last sign of the vehicle (or of its mode change) to the detection."""
        return float(self.detected_s - self.since_s)


def classify_loss(vehicle, now_s: float, link_timeout_s: float, commanded: bool,
                  seen_armed: bool = True) -> tuple[str, str] | None:
    """``(reason, detail)`` if ``vehicle`` is lost, else None.

    Parameters
    ----------
    vehicle
        A ``mission.vehicle.vehicle_link.VehicleLink`` (``link_age_s()``, ``flavour``, ``state.mode``,
        ``state.armed``).
    now_s : float
        Mission clock now (unused by the rules, kept for callers' logging).
    link_timeout_s : float
        Silence after which the link is lost.
    commanded : bool
        The coordinator itself asked this vehicle to land / RTL (then it did not "leave").
    seen_armed : bool
        The vehicle has been seen armed since its takeoff command (a disarmed state before
        that is the arming still on its way, not a vehicle that left).
    """
    age = float(vehicle.link_age_s())
    if age > link_timeout_s:
        return "link", f"no MAVLink frame for {age:.2f} s"
    if commanded:
        return None
    mode = vehicle.state.mode
    if mode in LEFT_MODES.get(vehicle.flavour, ()):
        return "left", f"switched to {mode} by itself (failsafe)"
    if seen_armed and not vehicle.state.armed:
        return "left", "disarmed in the air"
    return None


def reformed_offsets(kind: str, offsets: dict[int, np.ndarray], lost, radius_m: float,
                     seed: int = 0) -> tuple[dict[int, np.ndarray], str]:
    """New slot offsets of the survivors and the formation type used.

    Parameters
    ----------
    kind : {"cvt", "symmetric"}
        The current formation type.
    offsets : dict
        Current offset (from the formation centre) of every vehicle of the formation, lost
        ones included, by sysid.
    lost : iterable of int
        Sysids that left the formation.
    radius_m : float
    seed : int
        Seed of a fresh symmetric formation.

    Returns
    -------
    (dict, str)
        Survivor sysid -> new offset, and ``cvt`` or ``symmetric``. CVT: warm-started
        :func:`formation.reconfigure` (minimum travel, rotation allowed). Symmetric: a new
        symmetric cylinder if the survivors are an even number >= 4, else switch to CVT.

    Raises
    ------
    ValueError
        Fewer than 4 survivors.
    """
    import formation

    sysids = sorted(offsets)
    lost = set(lost)
    survivors = [s for s in sysids if s not in lost]
    if len(survivors) < 4:
        raise ValueError(f"a formation needs at least 4 vehicles, {len(survivors)} left")
    x = np.array([offsets[s] for s in sysids], dtype=float)
    if kind == "symmetric" and len(survivors) % 2 == 0:
        slots = np.asarray(formation.symmetric_cylinder(len(survivors), radius_m), dtype=float)
        xs = x[[sysids.index(s) for s in survivors]]
        perm, _ = formation.assign_slots(xs, slots, allow_rotation=False)
        return {s: slots[perm[k]] for k, s in enumerate(survivors)}, "symmetric"
    mask = np.array([s in lost for s in sysids])
    rec = formation.reconfigure(x, mask, radius_m)
    out = {}
    for k, idx in enumerate(rec.survivors):
        out[sysids[int(idx)]] = np.asarray(rec.slots[int(rec.assignment[k])], dtype=float)
    return out, "cvt"


async def watch_losses(co, period_s: float = 0.1) -> None:
    """Detect lost vehicles every ``period_s`` of the mission clock (task run by the coordinator).

    Only vehicles under the mission's setpoints, or airborne and not yet released, are watched,
    from the takeoff on. A detection logs a ``vehicle lost`` event with its latency, takes the
    vehicle off the stream and marks it in ``co.lost``; the seek loop re-forms.
    """
    faults = co.plan.faults
    seen_armed: set[int] = set()
    while True:
        t_before = co.clock.time()
        await co.clock.sleep(period_s)
        if co.phase not in ("takeoff", "assemble", "seek", "finish", "return"):
            continue
        if co.clock.time() - t_before > period_s + 0.5 * faults.link_timeout_s:
            # this task woke up late: the event loop was busy and frames may be waiting in the
            # sockets; a silence measured now could be the loop's, not the vehicles'
            await asyncio.sleep(0)
            continue
        now = co.clock.time()
        watched = co.airborne | set(co.lost) | set(co.ramp.sysids if co.ramp is not None else ())
        for sysid in sorted(watched):
            v = co.vehicles.get(sysid)
            if v is None:
                continue
            loss = co.lost.get(sysid)
            if loss is not None:
                await _maybe_came_back(co, v, loss, now)
                continue
            if sysid in co.released:
                continue  # commanded by the coordinator to land / RTL
            if v.state.armed:
                seen_armed.add(sysid)
            found = classify_loss(v, now, faults.link_timeout_s, commanded=False,
                                  seen_armed=sysid in seen_armed)
            if found is not None and found[0] == "link":
                # let the event loop read whatever is pending before concluding
                await asyncio.sleep(0)
                await asyncio.sleep(0)
                now = co.clock.time()
                found = classify_loss(v, now, faults.link_timeout_s, commanded=False,
                                      seen_armed=sysid in seen_armed)
            if found is None:
                continue
            reason, detail = found
            if reason == "link":
                since = now - float(v.link_age_s())
            else:
                hb = getattr(v.state, "last_heartbeat_s", None)
                since = now if hb is None else min(now, float(hb))
            _declare_lost(co, VehicleLoss(sysid, reason, detail, now, since, co.phase))


def _declare_lost(co, loss: VehicleLoss) -> None:
    sysid = loss.sysid
    co.lost[sysid] = loss
    co.released.add(sysid)
    co.airborne.discard(sysid)
    if co.ramp is not None and sysid in co.ramp.sysids:
        loss.last_setpoint_enu = co.ramp.setpoint(sysid)
        co.ramp.remove(sysid)
    co.status[sysid] = f"lost ({loss.reason}: {loss.detail})"
    co.event(f"vehicle {sysid} lost: {loss.detail}; detected {loss.latency_s:.2f} s after its last sign "
             f"(phase {loss.phase})", level="warning", sysid=sysid, reason=loss.reason,
             latency_s=round(loss.latency_s, 3), detected_s=loss.detected_s, since_s=loss.since_s)


async def _maybe_came_back(co, v, loss: VehicleLoss, now: float) -> None:
    if loss.reason != "link" or loss.came_back_s is not None or v.link_age_s() > 0.5:
        return
    loss.came_back_s = now
    alt = getattr(v.state, "relative_alt_m", None)
    if co.plan.faults.readmit:
        if (co.phase == "seek" and v.state.armed and (alt is None or alt >= 1.0)
                and v.state.mode not in LEFT_MODES.get(v.flavour, ())):
            loss.readmit_pending = True
            co.event(f"vehicle {loss.sysid} is heard again after its link loss; re-admitted at the next "
                     "iteration (faults.readmit = true)", level="warning", sysid=loss.sysid)
            return
        why = f"faults.readmit = true, but not re-admissible (phase {co.phase}, mode {v.state.mode})"
    else:
        why = "faults.readmit = false"
    await keep_out(co, loss.sysid, v, loss, why)


async def keep_out(co, sysid: int, v, loss: VehicleLoss, why: str) -> None:
    """Keep a returning vehicle out of the formation and command it to land (or RTL), once."""
    rtl = co.plan.return_behaviour == "rtl"
    loss.readmit_pending = False
    co.event(f"vehicle {sysid} is heard again after its link loss; kept out of the formation "
             f"({why}) and commanded to {'RTL' if rtl else 'land'}", level="warning", sysid=sysid)
    if v is None or not v.state.armed:
        co.status[sysid] = "lost (back, on the ground)"
        return
    co.status[sysid] = "kept out: " + ("returning" if rtl else "landing")
    try:
        await asyncio.wait_for(v.rtl() if rtl else v.land(), timeout=30.0)
    except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported
        co.event(f"vehicle {sysid}: {'RTL' if rtl else 'land'} after its return failed: {exc}",
                 level="error", sysid=sysid)


async def reform(co, centre_enu, sysids: list[int]) -> list[int]:
    """Re-form the formation about ``centre_enu`` for the vehicles of ``sysids`` not lost.

    Computes the survivors' slots (:func:`survivor_slots`), then :func:`transfer_to`. Returns
    the survivors; with fewer than 4 nothing is flown (the caller ends the mission).
    """
    survivors = [s for s in sysids if s not in co.lost and co.ramp is not None and s in co.ramp.sysids]
    if len(survivors) < 4:
        return survivors
    lost_here = [s for s in sysids if s not in survivors]
    new, kind = await survivor_slots(co, centre_enu, sysids, lost_here, "vehicles",
                                     " (and the Theorem 2 estimator)")
    await transfer_to(co, survivors, new, centre_enu, f"re-forming for {len(survivors)} vehicles ({kind})",
                      lost_here)
    return [s for s in survivors if s not in co.lost]


async def survivor_slots(co, centre_enu, sysids: list[int], gone: list[int], who: str = "vehicles",
                         switch_note: str = "") -> tuple[dict[int, np.ndarray], str]:
    """New slot offsets for ``sysids`` without ``gone``, and the formation type.

    :func:`reformed_offsets` (a switch from symmetric to CVT is logged, ``who`` and
    ``switch_note`` in its message), rotated about the centre clear of the lost vehicles still
    flying (:func:`mission.flight.rejoin.clear_offsets`, logged). Both run in a worker thread: the CVT
    solve takes 0.1-0.3 s of CPU and the event loop must keep streaming setpoints (at 10x,
    0.1 s of wall time is PX4's 1 s offboard-loss timeout).
    """
    from mission.flight.rejoin import OBSTACLE_MARGIN_M, clear_offsets, obstacles

    plan = co.plan
    loop = asyncio.get_running_loop()
    new, kind = await loop.run_in_executor(None, functools.partial(
        reformed_offsets, co.formation_kind, {s: co.slot_offsets[s] for s in sysids}, gone,
        plan.formation.radius_m, plan.formation.seed))
    if kind != co.formation_kind:
        co.event(f"{len(sysids) - len(gone)} {who} left: the symmetric formation needs an even number; "
                 f"switching to the CVT formation{switch_note}", level="warning")
        co.formation_kind = kind
    obs = obstacles(co)
    if len(obs):
        new, ok = await loop.run_in_executor(None, functools.partial(
            clear_offsets, new, centre_enu, obs, plan.min_separation_m + OBSTACLE_MARGIN_M,
            allow_tilt=kind == "cvt"))
        co.event(f"re-formed slots rotated clear of {len(obs)} position(s) of lost vehicles still flying"
                 + ("" if ok else " (no rotation keeps the full clearance)"),
                 level="info" if ok else "warning", obstacles=obs)
    return new, kind


async def transfer_to(co, sysids: list[int], new_offsets: dict, centre_enu, what: str,
                      lost_here: list[int]) -> None:
    """Fly ``sysids`` from their setpoints to ``centre_enu + new_offsets`` and adopt those slots.

    The transfer is planned by :func:`mission.flight.rejoin.plan_clear_transfer` (separation kept
    between the vehicles and from the lost vehicles still flying, inside the fence, at 80 % of
    the speed limit so that the ramp keeps up), flown leg by leg (interpolated goals every 0.1 s
    of the mission clock); then ``co.slot_offsets`` is updated and the formation settles.
    Without a separation-keeping plan the vehicles fly straight under the safety envelope.
    Vehicles parked at the centre (retired sensors, :mod:`mission.flight.retire`) not in ``sysids`` are
    part of the transfer too, at the new centre.
    """
    from mission.flight.phases import move_and_wait
    from mission.flight.rejoin import obstacles, plan_clear_transfer
    from mission.flight.retire import parked
    from mission.safety.envelope import TransferError

    still = parked(co)
    members = [s for s in sysids if s not in still]  # the formation's (sensing) vehicles
    extra = [s for s in still if s not in sysids]
    sysids = list(sysids) + extra
    new_offsets = {**new_offsets, **{s: np.zeros(3) for s in extra}}
    plan = co.plan
    loop = asyncio.get_running_loop()
    centre = np.asarray(centre_enu, dtype=float)
    start = np.array([co.ramp.setpoint(s) for s in sysids])
    goal = np.array([centre + new_offsets[s] for s in sysids])
    fence = None if co.envelope is None else co.envelope.fence
    t0 = co.clock.time()
    try:
        tp = await loop.run_in_executor(None, functools.partial(
            plan_clear_transfer, start, goal, obstacles(co), plan.min_separation_m, 0.8 * plan.max_speed_m_s,
            fence=fence))
    except (TransferError, ValueError) as exc:
        tp = None
        co.event(f"{what}: no separation-keeping transfer ({exc}); flying straight to the new "
                 "slots under the safety envelope", level="warning")
    if tp is not None:
        co.event(f"{what}: transfer {tp.strategy}, {tp.duration_s:.1f} s, closest approach "
                 f"{tp.min_separation_m:.2f} m", survivors=members, lost=lost_here, strategy=tp.strategy,
                 min_separation_m=tp.min_separation_m, slots={s: new_offsets[s] for s in sysids},
                 parked=parked(co))
        await _fly_transfer(co, sysids, tp)
    for s in sysids:
        co.slot_offsets[s] = new_offsets[s]
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
    ramp = co.ramp
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
        ramp.set_goals({s: pos[i] for i, s in enumerate(sysids) if s in ramp.sysids and s not in co.lost})
        if t >= times[-1]:
            return
        await co.clock.sleep(0.1)
