"""The takeoff: slots assigned, layers chosen, every vehicle armed and climbed to its layer.

Built by :meth:`mission.flight.coordinator.Coordinator.takeoff_phase` with the narrow services it
uses (:mod:`mission.flight.services`), run with ``await Takeoff(...).run()``. Separation during
takeoff, assembly and return comes from altitude layers
(:func:`mission.flight.layers.shared_layers`): every vehicle climbs over its own home to its
layer, flies horizontally at that layer, then moves vertically, all vehicles finishing a step
before the next starts; vehicles share a layer when their horizontal paths keep
``min_separation_m + LAYER_MARGIN_M`` apart (see ``docs/mission.md``).

While a vehicle's arming is retried (``[preflight] autopilot_ready_timeout_s``) the vehicles
already in the air stay watched: the loss monitor and the watchdog run in this phase
(``docs/faults.md``, "A vehicle lost while another one's arming is retried"); the waits between two
attempts and between two takeoffs end at an operator's stop and, when the losses leave fewer than
:data:`MIN_FORMATION` vehicles that could still fly the formation, with :class:`TooFewLeft`: no
further vehicle is armed and the mission ends (those in the air come home).
"""
from __future__ import annotations

import asyncio
from typing import Any, Awaitable, Callable

import numpy as np

from formation.geodesy import geodetic_to_enu
from formation.metrics import metrics
from mission.core.plan_types import Plan
from mission.flight.control import OperatorStop
from mission.flight.layers import shared_layers
from mission.flight.services import Clock, Fleet, PhaseEvents, Waiter
from mission.flight.state import MissionError, MissionState
from mission.flight.faults.takeoff_loss import TakeoffLoss
from mission.flight.targets import assign_slots, solve_formation
from mission.safety.gate import SafetyGate

__all__ = ["ArmAndTakeoff", "MIN_FORMATION", "Takeoff", "TooFewLeft", "home_enu"]

#: the fewest vehicles a formation is flown with (:class:`mission.flight.phases.assemble.Assemble`)
MIN_FORMATION = 4


class TooFewLeft(MissionError):
    """The takeoff's losses leave fewer than :data:`MIN_FORMATION` vehicles: nothing more is armed."""


def home_enu(fleet: Fleet, origin, sysid: int) -> np.ndarray:
    """The home of vehicle ``sysid`` (mission ENU m, about ``origin``); MissionError without one."""
    home = fleet.vehicles[sysid].state.home
    if home is None:
        raise MissionError(f"vehicle {sysid} has no home position")
    return np.asarray(geodetic_to_enu(home[0], home[1], home[2], origin), dtype=float)


#: ``arm_and_takeoff(sysid, vehicle, rel_alt_m, before_takeoff, pause)``: arm one vehicle and command
#: its takeoff (:func:`mission.flight.readiness_autopilot.arm_and_takeoff`), awaiting ``pause(delay_s)``
#: between two attempts (what it raises goes through); MissionError when it fails
ArmAndTakeoff = Callable[[int, Any, float, Callable[[], None], Callable[[float], Awaitable[None]]], Awaitable[None]]


class Takeoff:
    """The takeoff phase: slots and layers planned, then every vehicle armed and climbing to its
    layer, staggered by ``stagger_s`` (lowest first).

    Parameters
    ----------
    plan : Plan
        The formation, the start point, the altitudes, ``stagger_s``, the origin.
    state : MissionState
        The formation, the layers, the homes and each vehicle's status are set there.
    fleet : Fleet
        The connected vehicles.
    clock : Clock
    events : PhaseEvents
    waiter : Waiter
        The climbs are waited for on it (an operator's stop ends them).
    open_setpoints : callable
        ``open_setpoints(vehicles) -> SafetyGate``: the setpoint stream for ``vehicles`` and the
        safety gate driving it (not started: the phase starts it).
    arm_and_takeoff : ArmAndTakeoff
        Arm one vehicle and command its takeoff.
    losses : callable
        ``losses() -> TakeoffLoss``: the takeoff's losses over the gate now.
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, clock: Clock, events: PhaseEvents,
                 waiter: Waiter, open_setpoints: Callable[[list], SafetyGate], arm_and_takeoff: ArmAndTakeoff,
                 losses: Callable[[], TakeoffLoss]) -> None:
        self.plan, self.state, self.fleet, self.clock = plan, state, fleet, clock
        self.events, self.waiter = events, waiter
        self.open_setpoints, self.arm_and_takeoff, self.losses = open_setpoints, arm_and_takeoff, losses
        self.gate: SafetyGate | None = None

    async def run(self) -> None:
        """Plan the slots, start the safety gate, arm and take off every vehicle, wait for the climbs."""
        self.events.set_phase("takeoff")
        plan, vehicles = self.plan, self.fleet.vehicles
        offsets = np.empty((0, 3))
        while len(offsets) != len(vehicles):  # one slot per vehicle, also if the set changed meanwhile
            offsets = await solve_formation(plan.formation.type, len(vehicles), plan.formation.radius_m,
                                            plan.formation.seed)
        self._plan_slots(offsets)
        self.gate = self.open_setpoints(list(vehicles.values()))
        self.gate.start()  # the safety gate: moves, checks and sends the setpoints
        order = sorted(vehicles, key=lambda s: (self.state.layer_alt_m[s], s))
        waits = []
        try:
            for i, sysid in enumerate(order):
                if i:
                    await self._pause(plan.stagger_s)
                wait = await self._take_off(sysid)
                if wait is not None:
                    waits.append(asyncio.ensure_future(wait))
            await asyncio.gather(*waits)
        finally:
            for w in waits:  # the climbs still waited for when the phase ends early (a stop, too few left)
                w.cancel()

    def _check_enough(self) -> None:
        """TooFewLeft when the vehicles not lost (in the air, being armed, still to take off) are fewer
        than :data:`MIN_FORMATION`."""
        state = self.state
        left = [s for s in self.fleet.vehicles if s not in state.lost]
        if len(left) >= MIN_FORMATION:
            return
        waiting = sorted(s for s in left if s not in state.airborne)
        raise TooFewLeft(f"vehicles {sorted(state.lost)} lost during the takeoff: {len(left)} left, a formation "
                         f"needs {MIN_FORMATION}" + (f"; vehicles {waiting} not armed" if waiting else ""))

    async def _pause(self, delay_s: float) -> None:
        """Wait ``delay_s`` (between two takeoffs, two arming attempts) with the vehicles in the air
        watched: :class:`TooFewLeft` as soon as their losses leave too few, OperatorStop at a stop."""
        end_s = self.clock.time() + delay_s

        def _over() -> bool:
            lost = self.state.lost
            return self.clock.time() >= end_s or sum(s not in lost for s in self.fleet.vehicles) < MIN_FORMATION

        self._check_enough()
        await self.waiter.wait_until(_over, delay_s + 5.0, "the next takeoff")
        self._check_enough()

    async def _take_off(self, sysid: int):
        """Arm ``sysid`` and command its takeoff; the wait for its climb (a coroutine), or None when it failed."""
        v = self.fleet.vehicles[sysid]
        home = self.state.home_enu[sysid]
        rel_alt = self.state.layer_alt_m[sysid] - home[2]
        held = {}

        def _note_start():
            # PX4's takeoff holds where the vehicle is at this instant (no await in between): the
            # ramp must start there, not at the home, or its first setpoint jumps by the GPS drift
            held["xy"] = v.position_enu_m()

        try:  # arming refusals retried with the autopilot's words, ArduPilot's mode re-checked
            await self.arm_and_takeoff(sysid, v, rel_alt, _note_start, self._pause)
        except (OperatorStop, TooFewLeft):
            raise  # the operator ended the mission, or the takeoff cannot go on: nobody failed
        except MissionError as exc:
            self.losses().lose_failed(sysid, str(exc))
            return None
        self.state.set_airborne(sysid, "taking off")
        self.events.event(f"vehicle {sysid} taking off to {rel_alt:.1f} m above home", sysid=sysid)
        start = home if held.get("xy") is None else held["xy"]
        return self._hold_after_climb(sysid, start, self.state.layer_alt_m[sysid])

    def _plan_slots(self, offsets: np.ndarray) -> None:
        """Formation slots (``offsets``, one per vehicle: :func:`solve_formation`), the assignment of
        vehicles to them (from their homes) and the layers."""
        plan, state = self.plan, self.state
        sysids = sorted(self.fleet.vehicles)
        start = plan.seeking.start_point()
        homes = np.array([home_enu(self.fleet, plan.origin, s) for s in sysids])
        cur = np.column_stack([homes[:, :2], np.zeros(len(sysids))])
        slots = start + offsets
        perm = assign_slots(cur, np.column_stack([slots[:, :2], np.zeros(len(sysids))]))
        slot_offsets = {s: offsets[perm[i]] for i, s in enumerate(sysids)}
        d_min = float(metrics(offsets).d_min)
        if d_min < plan.min_separation_m:
            raise MissionError(f"the {plan.formation.type} formation of {len(sysids)} vehicles with radius "
                               f"{plan.formation.radius_m} m has slots {d_min:.2f} m apart, below "
                               f"min_separation_m {plan.min_separation_m} m: increase the radius")
        base = float(np.max(homes[:, 2])) + plan.takeoff_alt_m
        goals = np.array([start + slot_offsets[s] for s in sysids])
        try:
            alts = shared_layers(homes, goals, base, plan.geofence.max_alt_m - 0.5, plan.min_separation_m)
        except ValueError as exc:
            raise MissionError(f"takeoff layers: {exc}") from None
        state.set_formation(slot_offsets, layer_alt_m={s: float(alts[i]) for i, s in enumerate(sysids)},
                            home_enu={s: homes[i] for i, s in enumerate(sysids)})
        self.events.event(f"formation {plan.formation.type}, {len(sysids)} slots, radius {plan.formation.radius_m} m, "
                          f"d_min {d_min:.2f} m; {len(np.unique(alts))} layers {alts.min():.1f}..{alts.max():.1f} m",
                          slots={s: state.slot_offsets[s] for s in sysids}, layers=dict(state.layer_alt_m))

    async def _hold_after_climb(self, sysid: int, start, layer_alt: float) -> None:
        """Wait until the vehicle is near its layer, then give it a setpoint there (above ``start``:
        the home, or for PX4 the point its takeoff held)."""
        v, gate, state = self.fleet.vehicles[sysid], self.gate, self.state
        target = np.array([start[0], start[1], layer_alt])
        if v.flavour == "px4":
            gate.add(sysid, target)  # PX4 offboard: setpoints must keep streaming from now on

        def _near():
            if sysid in state.lost:
                return True
            p = self.fleet.telemetry_position(sysid)
            return p is not None and abs(float(p[2]) - layer_alt) < 0.6

        try:
            await self.waiter.wait_until(_near, 60.0 + 2.0 * layer_alt,
                                         f"vehicle {sysid} to climb to {layer_alt:.1f} m")
        except OperatorStop:
            raise
        except MissionError as exc:
            self.losses().lose_failed(sysid, str(exc))
        if sysid in state.lost:
            return
        if sysid not in gate.sysids:
            gate.add(sysid, target)
        state.set_status(sysid, "holding")
