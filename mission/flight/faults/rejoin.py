"""Lost vehicles that still fly (obstacles) and returning vehicles (re-admission).

* **Obstacles**: a vehicle lost by its link while armed and airborne (PX4 falls back to hold,
  ArduPilot GUIDED holds its last target) stays where it was. For ``OBSTACLE_TTL_S`` of the
  mission clock after its last frame, its last known position and its last setpoint (where it
  may still have been flying to) are obstacles: re-formed slots are rotated about the centre so
  that none is within ``min_separation_m + OBSTACLE_MARGIN_M`` of them
  (:func:`clear_offsets`), transfers are planned with them as fixed participants
  (:func:`plan_clear_transfer`), and the seek's per-iteration goals are checked likewise
  (:meth:`Rejoin.clear_goals`). A lost vehicle heard again is an obstacle at its live position.
* **Re-admission** (``[faults] readmit = true``): a vehicle lost by its link, heard again
  during the seek while armed, airborne and not in RTL/LAND, is re-admitted at the start of
  the next iteration (:meth:`Rejoin.readmit`): held where it is under setpoints, re-engaged
  (OFFBOARD/GUIDED), then the formation re-forms for N+1 (CVT warm-started from the current
  slots plus its position projected on the sphere, minimum-travel assignment) and a
  separation-keeping transfer is flown.
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from formation.assignment import assign_slots
from formation.cvt import cvt_from
from formation.symmetric import symmetric_cylinder

from mission.core.plan_types import FaultsPlan, FormationPlan
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.obstacles import OBSTACLE_MARGIN_M, clear_offsets, obstacles
from mission.flight.services import Clock, Events, Fleet, Motion, Waiter
from mission.flight.state import MissionState
from mission.safety.gate import SafetyGate

__all__ = ["Rejoin", "pending_readmissions", "readmitted_offsets"]


def pending_readmissions(state: MissionState, faults: FaultsPlan) -> list[int]:
    """Lost vehicles heard again and waiting to be re-admitted (``[faults] readmit = true``)."""
    if not faults.readmit:
        return []
    return sorted(s for s, x in state.lost.items() if x.reason == "link" and x.came_back_s is not None
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
    sysids = sorted(offsets) + sorted(returning)
    x = np.array([offsets[s] for s in sorted(offsets)] + [returning[s] for s in sorted(returning)], dtype=float)
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norms <= 1e-9):
        x = x + 1e-3 * np.random.default_rng(0).standard_normal(x.shape)
        norms = np.linalg.norm(x, axis=1, keepdims=True)
    proj = radius_m * x / norms
    if kind == "symmetric" and len(sysids) % 2 == 0:
        slots = np.asarray(symmetric_cylinder(len(sysids), radius_m), dtype=float)
        perm, slots = assign_slots(proj, slots, allow_rotation=False)
        return {s: slots[perm[k]] for k, s in enumerate(sysids)}, "symmetric"
    unit = cvt_from(proj / radius_m).points
    perm, slots = assign_slots(proj, radius_m * unit, allow_rotation=True)
    return {s: np.asarray(slots[perm[k]], dtype=float) for k, s in enumerate(sysids)}, "cvt"



class Rejoin:
    """Lost vehicles that still fly kept clear of; lost vehicles heard again re-admitted.

    Parameters
    ----------
    state : MissionState
        Who is lost, released, re-engaging; the slots and the formation type (changed here).
    fleet : Fleet
        The connected vehicles.
    gate : SafetyGate
        The safety gate a re-admitted vehicle is put back under.
    clock : Clock
        The mission clock.
    faults : FaultsPlan
        ``link_timeout_s``: a vehicle silent that long is not fit to re-join.
    formation : FormationPlan
        ``radius_m`` of the grown formation.
    min_separation_m : float
        The plan's separation (plus :data:`~mission.flight.obstacles.OBSTACLE_MARGIN_M` from obstacles).
    motion : Motion
        ``transfer_to`` (the formation re-formed or rotated), ``keep_out`` (a vehicle not re-admitted).
    waiter : Waiter
        Waits for a re-engaged vehicle to report its mode (an operator's stop ends the wait).
    events : Events
        Rotations, switches of formation type and re-admissions are told.
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate, clock: Clock, faults: FaultsPlan,
                 formation: FormationPlan, min_separation_m: float, motion: Motion, waiter: Waiter,
                 events: Events) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.faults, self.formation, self.min_separation_m = faults, formation, float(min_separation_m)
        self.motion, self.waiter, self.events = motion, waiter, events

    def clear_goals(self, centre_enu, sysids: list[int]) -> bool:
        """Rotate the formation's slots (about the centre) if a goal of this iteration is near an obstacle.

        Called by the seek before each iteration's move; logs an event when it rotates. Returns
        False if no clear rotation was found (the goals are then the best found).
        """
        obs = obstacles(self.state.lost, self.fleet, self.clock.time())
        if not len(obs):
            return True
        sep = self.min_separation_m + OBSTACLE_MARGIN_M
        offsets = {s: self.state.slot_offsets[s] for s in sysids}
        start = {s: self.gate.setpoint(s) for s in sysids if s in self.gate.sysids}
        if len(start) != len(sysids):
            start = None
        new, ok = clear_offsets(offsets, centre_enu, obs, sep, start_enu=start,
                                allow_tilt=self.state.formation_kind == "cvt")
        if any(not np.allclose(new[s], offsets[s]) for s in sysids):
            self.state.update_slots(new)
            self.events.event("formation rotated to keep clear of a lost vehicle still flying"
                              + ("" if ok else " (no rotation keeps the full clearance)"),
                              level="info" if ok else "warning", obstacles=obs, slots={s: new[s] for s in sysids})
        return ok

    async def fly_rotation(self, centre_enu, sysids: list[int], before: dict[int, np.ndarray]) -> None:
        """Fly a rotation of the slots made by :meth:`clear_goals` as a separation-keeping transfer.

        Flown straight, a large rotation takes the slots along chords that cross each other and
        pass near the centre (where a vehicle with a retired sensor is parked); as a transfer
        (the motion's ``transfer_to``) every path is planned and checked. ``before``: the slot
        offsets before :meth:`clear_goals`. Nothing is flown when nothing rotated.
        """
        members = [s for s in sysids if s not in self.state.lost and self.gate is not None and s in self.gate.sysids]
        if all(np.allclose(before[s], self.state.slot_offsets[s]) for s in members if s in before):
            return
        await self.motion.transfer_to(members, {s: self.state.slot_offsets[s] for s in members}, centre_enu,
                                      f"rotating the formation of {len(members)} clear of a lost vehicle", [])

    async def readmit(self, centre_enu, sysids: list[int], returning: list[int]) -> list[int]:
        """Re-admit ``returning`` into the formation of ``sysids`` about ``centre_enu``.

        Each returning vehicle still armed, airborne and heard is held at its position under
        setpoints and re-engaged (OFFBOARD/GUIDED, :meth:`_rejoin_one`); the formation re-forms for
        the larger number (:func:`readmitted_offsets`, rotated clear of obstacles) and a
        separation-keeping transfer is flown. A vehicle that cannot be re-engaged is kept out and
        landed. Returns the new formation's sysids.
        """
        joined = [sysid for sysid in returning if await self._rejoin_one(sysid)]
        if not joined:
            return sysids
        members = [s for s in sysids if s not in self.state.lost]
        centre = np.asarray(centre_enu, dtype=float)
        loop = asyncio.get_running_loop()
        new, kind = await loop.run_in_executor(None, functools.partial(
            readmitted_offsets, self.state.formation_kind, {s: self.state.slot_offsets[s] for s in members},
            {s: self.gate.setpoint(s) - centre for s in joined}, self.formation.radius_m))
        everyone = sorted(new)
        obs = obstacles(self.state.lost, self.fleet, self.clock.time())
        if len(obs):
            new, _ = clear_offsets(new, centre, obs, self.min_separation_m + OBSTACLE_MARGIN_M,
                                   allow_tilt=kind == "cvt")
        if kind != self.state.formation_kind:
            self.events.event(f"{len(everyone)} vehicles: the symmetric formation needs an even number; switching to "
                              "the CVT formation (and the Theorem 2 estimator)", level="warning")
        self.state.set_formation_kind(kind)
        await self.motion.transfer_to(everyone, new, centre, f"re-forming for {len(everyone)} vehicles ({kind}), "
                                      f"re-admitting {joined}", lost_here=[])
        return everyone

    async def _rejoin_one(self, sysid: int) -> bool:
        """Hold a returning vehicle at its position under setpoints and re-engage it; True when re-admitted.

        A vehicle no longer fit to re-join (disarmed, landed, silent, returning) or that cannot be
        re-engaged is kept out (the motion's ``keep_out``).
        """
        v = self.fleet.vehicles.get(sysid)
        pos = self.fleet.telemetry_position(sysid)
        alt = None if v is None else v.state.relative_alt_m
        if (v is None or pos is None or not v.state.armed or (alt is not None and alt < 1.0)
                or v.link_age_s() > self.faults.link_timeout_s or v.state.mode in LEFT_MODES.get(v.flavour, ())):
            await self.motion.keep_out(sysid, v, "no longer fit to re-join (disarmed, landed, silent or returning)")
            return False
        want = GUIDED_MODES[v.flavour]
        self.state.begin_reengaging(sysid)  # the watchdog must not race us
        try:
            self.gate.add(sysid, np.asarray(pos, dtype=float))
            self.state.unrelease(sysid)
            await self.clock.sleep(0.5)  # a few setpoints first: PX4 refuses OFFBOARD without them
            await asyncio.wait_for(v.set_mode(want), timeout=30.0)
            await self.waiter.wait_until(lambda: v.state.mode == want, 10.0, f"vehicle {sysid} in {want}")
        except Exception as exc:  # noqa: BLE001 - CommandError, MissionError, timeout: kept out
            self.gate.remove(sysid)
            self.state.release(sysid)
            await self.motion.keep_out(sysid, v, f"could not re-engage {want}: {exc}")
            return False
        finally:
            self.state.end_reengaging(sysid)
        self.state.readmit(sysid, self.clock.time())
        self.events.event(f"vehicle {sysid} re-admitted: re-engaged {want} at its position", sysid=sysid)
        return True
