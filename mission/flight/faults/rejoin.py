"""Lost vehicles that still fly (obstacles) and returning vehicles (re-admission).

* **Obstacles**: a vehicle lost by its link while armed and airborne (PX4 falls back to hold,
  ArduPilot GUIDED holds its last target) stays where it was. For ``OBSTACLE_TTL_S`` of the
  mission clock after its last frame, its last known position and its last setpoint (where it
  may still have been flying to) are obstacles: re-formed slots are rotated about the centre so
  that none is within ``min_separation_m + OBSTACLE_MARGIN_M`` of them
  (:func:`clear_offsets`), transfers are planned with them as fixed participants
  (:func:`plan_clear_transfer`), and the seek's per-iteration goals are checked likewise
  (:func:`clear_goals`). A lost vehicle heard again is an obstacle at its live position.
* **Re-admission** (``[faults] readmit = true``): a vehicle lost by its link, heard again
  during the seek while armed, airborne and not in RTL/LAND, is re-admitted at the start of
  the next iteration (:func:`readmit`): held where it is under setpoints, re-engaged
  (OFFBOARD/GUIDED), then the formation re-forms for N+1 (CVT warm-started from the current
  slots plus its position projected on the sphere, minimum-travel assignment) and a
  separation-keeping transfer is flown.
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.motion import keep_out, transfer_to
from mission.flight.obstacles import OBSTACLE_MARGIN_M, clear_offsets, obstacles

__all__ = ["clear_goals", "fly_rotation", "pending_readmissions", "readmit", "readmitted_offsets"]


def clear_goals(co, centre_enu, sysids: list[int]) -> bool:
    """Rotate the formation's slots (about the centre) if a goal of this iteration is near an obstacle.

    Called by the seek before each iteration's move; logs an event when it rotates. Returns
    False if no clear rotation was found (the goals are then the best found).
    """
    obs = obstacles(co.state.lost, co.fleet, co.clock.time())
    if not len(obs):
        return True
    sep = co.plan.min_separation_m + OBSTACLE_MARGIN_M
    offsets = {s: co.state.slot_offsets[s] for s in sysids}
    start = {s: co.gate.setpoint(s) for s in sysids if s in co.gate.sysids}
    if len(start) != len(sysids):
        start = None
    new, ok = clear_offsets(offsets, centre_enu, obs, sep, start_enu=start,
                            allow_tilt=co.state.formation_kind == "cvt")
    if any(not np.allclose(new[s], offsets[s]) for s in sysids):
        co.state.update_slots(new)
        co.event("formation rotated to keep clear of a lost vehicle still flying"
                 + ("" if ok else " (no rotation keeps the full clearance)"),
                 level="info" if ok else "warning", obstacles=obs, slots={s: new[s] for s in sysids})
    return ok


async def fly_rotation(co, centre_enu, sysids: list[int], before: dict[int, np.ndarray]) -> None:
    """Fly a rotation of the slots made by :func:`clear_goals` as a separation-keeping transfer.

    Flown straight, a large rotation takes the slots along chords that cross each other and
    pass near the centre (where a vehicle with a retired sensor is parked); as a transfer
    (:func:`mission.flight.motion.transfer_to`) every path is planned and checked. ``before``: the slot
    offsets before :func:`clear_goals`. Nothing is flown when nothing rotated.
    """
    members = [s for s in sysids if s not in co.state.lost and co.gate is not None and s in co.gate.sysids]
    if all(np.allclose(before[s], co.state.slot_offsets[s]) for s in members if s in before):
        return
    await transfer_to(co, members, {s: co.state.slot_offsets[s] for s in members}, centre_enu,
                      f"rotating the formation of {len(members)} clear of a lost vehicle", [])


def pending_readmissions(co) -> list[int]:
    """Lost vehicles heard again and waiting to be re-admitted (``[faults] readmit = true``)."""
    if not co.plan.faults.readmit:
        return []
    return sorted(s for s, x in co.state.lost.items() if x.reason == "link" and x.came_back_s is not None
                  and x.readmit_pending)


def readmitted_offsets(kind: str, offsets: dict[int, np.ndarray], returning: dict[int, np.ndarray],
                       radius_m: float) -> tuple[dict[int, np.ndarray], str]:
    """Slot offsets of the formation grown by the returning vehicles.

    Parameters
    ----------
    kind : {"cvt", "symmetric"}
    offsets : dict
        Current members' offsets (by sysid).
    returning : dict
        Returning vehicles' current offsets from the centre (projected on the sphere).
    radius_m : float

    Returns
    -------
    (dict, str)
        Every vehicle's new offset and the formation type: symmetric if it was and the new
        number is even, else a CVT warm-started from the current slots and the returning
        positions; minimum-travel assignment (rotation allowed for CVT).
    """
    import formation

    sysids = sorted(offsets) + sorted(returning)
    x = np.array([offsets[s] for s in sorted(offsets)] + [returning[s] for s in sorted(returning)], dtype=float)
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norms <= 1e-9):
        x = x + 1e-3 * np.random.default_rng(0).standard_normal(x.shape)
        norms = np.linalg.norm(x, axis=1, keepdims=True)
    proj = radius_m * x / norms
    if kind == "symmetric" and len(sysids) % 2 == 0:
        slots = np.asarray(formation.symmetric_cylinder(len(sysids), radius_m), dtype=float)
        perm, slots = formation.assign_slots(proj, slots, allow_rotation=False)
        return {s: slots[perm[k]] for k, s in enumerate(sysids)}, "symmetric"
    unit = formation.cvt_from(proj / radius_m).points
    perm, slots = formation.assign_slots(proj, radius_m * unit, allow_rotation=True)
    return {s: np.asarray(slots[perm[k]], dtype=float) for k, s in enumerate(sysids)}, "cvt"


async def readmit(co, centre_enu, sysids: list[int], returning: list[int]) -> list[int]:
    """Re-admit ``returning`` into the formation of ``sysids`` about ``centre_enu``.

    Each returning vehicle still armed, airborne and heard is held at its position under
    setpoints and re-engaged (OFFBOARD/GUIDED, :func:`_rejoin_one`); the formation re-forms for
    the larger number (:func:`readmitted_offsets`, rotated clear of obstacles) and a
    separation-keeping transfer is flown. A vehicle that cannot be re-engaged is kept out and
    landed. Returns the new formation's sysids.
    """
    plan = co.plan
    joined = [sysid for sysid in returning if await _rejoin_one(co, sysid)]
    if not joined:
        return sysids
    members = [s for s in sysids if s not in co.state.lost]
    centre = np.asarray(centre_enu, dtype=float)
    loop = asyncio.get_running_loop()
    new, kind = await loop.run_in_executor(None, functools.partial(
        readmitted_offsets, co.state.formation_kind, {s: co.state.slot_offsets[s] for s in members},
        {s: co.gate.setpoint(s) - centre for s in joined}, plan.formation.radius_m))
    everyone = sorted(new)
    obs = obstacles(co.state.lost, co.fleet, co.clock.time())
    if len(obs):
        new, _ = clear_offsets(new, centre, obs, plan.min_separation_m + OBSTACLE_MARGIN_M,
                               allow_tilt=kind == "cvt")
    if kind != co.state.formation_kind:
        co.event(f"{len(everyone)} vehicles: the symmetric formation needs an even number; switching to "
                 "the CVT formation (and the Theorem 2 estimator)", level="warning")
    co.state.set_formation_kind(kind)
    await transfer_to(co, everyone, new, centre, f"re-forming for {len(everyone)} vehicles ({kind}), "
                      f"re-admitting {joined}", lost_here=[])
    return everyone


async def _rejoin_one(co, sysid: int) -> bool:
    """Hold a returning vehicle at its position under setpoints and re-engage it; True when re-admitted.

    A vehicle no longer fit to re-join (disarmed, landed, silent, returning) or that cannot be
    re-engaged is kept out (:func:`mission.flight.motion.keep_out`).
    """
    v = co.vehicles.get(sysid)
    pos = co.telemetry_position(sysid)
    alt = None if v is None else getattr(v.state, "relative_alt_m", None)
    if (v is None or pos is None or not v.state.armed or (alt is not None and alt < 1.0)
            or v.link_age_s() > co.plan.faults.link_timeout_s or v.state.mode in LEFT_MODES.get(v.flavour, ())):
        await keep_out(co, sysid, v, "no longer fit to re-join (disarmed, landed, silent or returning)")
        return False
    want = GUIDED_MODES[v.flavour]
    co.state.begin_reengaging(sysid)  # the watchdog must not race us
    try:
        co.gate.add(sysid, np.asarray(pos, dtype=float))
        co.state.unrelease(sysid)
        await co.clock.sleep(0.5)  # a few setpoints first: PX4 refuses OFFBOARD without them
        await asyncio.wait_for(v.set_mode(want), timeout=30.0)
        await co.wait_until(lambda: v.state.mode == want, 10.0, f"vehicle {sysid} in {want}")
    except Exception as exc:  # noqa: BLE001 - CommandError, MissionError, timeout: kept out
        co.gate.remove(sysid)
        co.state.release(sysid)
        await keep_out(co, sysid, v, f"could not re-engage {want}: {exc}")
        return False
    finally:
        co.state.end_reengaging(sysid)
    co.state.readmit(sysid, co.clock.time())
    co.event(f"vehicle {sysid} re-admitted: re-engaged {want} at its position", sysid=sysid)
    return True
