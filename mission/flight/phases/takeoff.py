"""The phases around the seek: takeoff, assemble, return (connect and preflight:
:mod:`mission.flight.connect`).

Each phase is an object built by :mod:`mission.flight.coordinator` with the narrow services it
uses (:mod:`mission.flight.services`), and run with ``await phase.run()``. Separation during
takeoff, assembly and return comes from altitude layers
(:func:`mission.flight.layers.shared_layers`): every vehicle climbs over its own home to its
layer, flies horizontally at that layer, then moves vertically, all vehicles finishing a step
before the next starts; vehicles share a layer when their horizontal paths keep
``min_separation_m + LAYER_MARGIN_M`` apart (see ``docs/mission.md``).
"""
from __future__ import annotations

import asyncio
from typing import Any, Awaitable, Callable

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.core.plan_types import Plan, SeekingPlan
from mission.flight.control import MissionControl, OperatorStop
from mission.flight.layers import shared_layers
from mission.flight.motion import retried, update_odometry
from mission.flight.services import Clock, Fleet, PhaseEvents, Waiter
from mission.flight.state import MissionError, MissionState
from mission.flight.faults.takeoff_loss import TakeoffLoss
from mission.flight.targets import assign_slots
from mission.safety.gate import SafetyGate

__all__ = ["Assemble", "ReturnHome", "Takeoff", "formation_offsets", "home_enu", "solve_formation"]


def formation_offsets(kind: str, n: int, radius_m: float, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` slot offsets of the formation about its centre (ENU metres).

    A CVT solve takes about 0.2 s of CPU for 8 vehicles: inside the event loop, await
    :func:`solve_formation` instead.
    """
    import formation

    if kind == "symmetric":
        return np.asarray(formation.symmetric_cylinder(n, radius_m), dtype=float)
    return np.asarray(formation.cvt_sphere(n, radius_m, seed=seed), dtype=float)


async def solve_formation(kind: str, n: int, radius_m: float, seed: int = 0) -> np.ndarray:
    """:func:`formation_offsets` in the loop's executor (a worker thread; inline, in zero simulated
    time, on a lock-step loop), so the event loop never waits on the solve."""
    return await asyncio.get_running_loop().run_in_executor(None, formation_offsets, kind, n, radius_m, seed)


# ------------------------------------------------------------------------------------ takeoff
def home_enu(fleet: Fleet, origin, sysid: int) -> np.ndarray:
    """The home of vehicle ``sysid`` (mission ENU m, about ``origin``); MissionError without one."""
    home = fleet.vehicles[sysid].state.home
    if home is None:
        raise MissionError(f"vehicle {sysid} has no home position")
    return np.asarray(geodetic_to_enu(home[0], home[1], home[2], origin), dtype=float)


#: ``arm_and_takeoff(sysid, vehicle, rel_alt_m, before_takeoff)``: arm one vehicle and command its
#: takeoff (:func:`mission.flight.readiness_autopilot.arm_and_takeoff`); MissionError when it fails
ArmAndTakeoff = Callable[[int, Any, float, Callable[[], None]], Awaitable[None]]


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
        for i, sysid in enumerate(order):
            if i:
                await self.clock.sleep(plan.stagger_s)
            wait = await self._take_off(sysid)
            if wait is not None:
                waits.append(asyncio.ensure_future(wait))
        await asyncio.gather(*waits)

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
            await self.arm_and_takeoff(sysid, v, rel_alt, _note_start)
        except OperatorStop:
            raise  # the operator ended the mission: nobody failed
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
        from formation import metrics

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


#: ``fly_clear(sysids, goals, tol_m, what)``: fly ``sysids`` to ``goals`` by their layers, clear of
#: lost vehicles (:meth:`mission.flight.return_clear.ReturnClear.fly_clear`); MissionError when one is late
FlyClear = Callable[[list, dict, float, str], Awaitable[None]]


class Assemble:
    """The assembly: from the takeoff layers into the formation at the start point (layered transfer).

    The legs keep clear of lost vehicles still flying (``fly_clear``); a vehicle that cannot reach
    its slot in time is lost, the others go on (if 4 are left).

    Parameters
    ----------
    seeking : SeekingPlan
        The plan's ``[seeking]``: the start point and ``arrival_tol_m``.
    state : MissionState
    gate : SafetyGate
        The vehicles under setpoints.
    events : PhaseEvents
    fly_clear : FlyClear
    losses : TakeoffLoss
        The vehicles late at their slot are lost there.
    """

    def __init__(self, seeking: SeekingPlan, state: MissionState, gate: SafetyGate, events: PhaseEvents,
                 fly_clear: FlyClear, losses: TakeoffLoss) -> None:
        self.seeking, self.state, self.gate, self.events = seeking, state, gate, events
        self.fly_clear, self.losses = fly_clear, losses

    async def run(self) -> None:
        """Fly into the formation; MissionError when fewer than 4 vehicles are left."""
        self.events.set_phase("assemble")
        state, tol_m = self.state, self.seeking.arrival_tol_m
        sysids = sorted(s for s in self.gate.sysids if s not in state.lost)
        if len(sysids) < 4:
            raise MissionError(f"vehicles {sorted(state.lost)} lost before the formation was assembled: "
                               f"{len(sysids)} left, a formation needs 4")
        centre = self.seeking.start_point()
        # the layered legs, re-planned around lost vehicles still flying (e.g. one lost in takeoff)
        goals = {s: centre + state.slot_offsets[s] for s in sysids}
        try:
            await self.fly_clear(sysids, goals, tol_m, "assembly")
        except OperatorStop:
            raise  # the operator ended the mission: nobody failed
        except MissionError as exc:
            late = self.losses.laggards(sysids, tol_m)
            if not late:
                raise
            for s in late:
                self.losses.lose_failed(s, str(exc))
            sysids = [s for s in sysids if s not in state.lost]
            if len(sysids) < 4:
                raise MissionError(f"vehicles {sorted(state.lost)} lost during the assembly: {len(sysids)} left, "
                                   "a formation needs 4") from None
            await self.fly_clear(sysids, goals, tol_m, "assembly")
        state.move_centre(centre)
        for s in sysids:
            state.set_status(s, "in formation")
        self.events.event(f"formation assembled at ({centre[0]:.1f}, {centre[1]:.1f}, {centre[2]:.1f}) m")


# ------------------------------------------------------------------------------------- return
#: ``fly_return(sysids) -> land_here``: bring ``sysids`` above their landing spots, clear of lost
#: vehicles (:meth:`mission.flight.return_clear.ReturnClear.fly_return`); those that must LAND (not RTL)
FlyReturn = Callable[[list], Awaitable[set]]


class ReturnHome:
    """The return: back over the homes by layers, then land (or RTL), staggered by ``stagger_s``;
    an operator's ``land`` / ``rtl`` instead, also half-way; or every vehicle landed where it is.

    Parameters
    ----------
    plan : Plan
        ``return_behaviour`` and ``stagger_s``.
    state : MissionState
    fleet : Fleet
    gate : SafetyGate or None
        The vehicles under setpoints (None: the mission ended before the takeoff).
    clock : Clock
    events : PhaseEvents
    waiter : Waiter
    control : MissionControl
        The operator's LAND / RTL orders.
    fly_return : FlyReturn
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, gate: SafetyGate | None, clock: Clock,
                 events: PhaseEvents, waiter: Waiter, control: MissionControl, fly_return: FlyReturn) -> None:
        self.plan, self.state, self.fleet, self.gate, self.clock = plan, state, fleet, gate, clock
        self.events, self.waiter, self.control, self.fly_return = events, waiter, control, fly_return

    async def run(self) -> None:
        """Fly every airborne vehicle home and land it (or the operator's LAND / RTL).

        The paths, the descents included, keep ``min_separation_m + OBSTACLE_MARGIN_M`` from lost
        vehicles still flying (``fly_return``); a vehicle whose home is obstructed lands beside it.
        An operator's ``land`` / ``rtl`` (:mod:`mission.flight.control`) replaces it, also
        half-way: every airborne vehicle is commanded to LAND / RTL at once.
        """
        order = self.control.landing
        if order is None:
            order = await self.control.unless_landing_ordered(self._return_home())
        while order is not None:
            self.events.set_phase("return", behaviour=f"{order} (operator)")
            done = order
            order = await self.control.unless_landing_ordered(
                self._land_staggered(sorted(self.state.airborne), rtl=order == "rtl", stagger_s=0.0), current=done)

    async def land_all_now(self) -> None:
        """Emergency: land every airborne vehicle where it is (no stagger)."""
        await self._land_staggered(sorted(self.state.airborne), rtl=False)

    async def _return_home(self) -> None:
        """The mission's own return (:meth:`run` without an operator's order)."""
        self.events.set_phase("return", behaviour=self.plan.return_behaviour)
        gate, state = self.gate, self.state
        flying = [s for s in sorted(state.airborne) if gate is not None and s in gate.sysids]
        land_here: set[int] = set()
        if flying:
            land_here = await self.fly_return(flying)
        await self._land_staggered(sorted(state.airborne, key=lambda s: state.layer_alt_m.get(s, 0.0)),
                                   rtl=self.plan.return_behaviour == "rtl", land_only=land_here)

    async def _land_staggered(self, order, rtl: bool, land_only=frozenset(), stagger_s: float | None = None) -> None:
        """Land (or RTL) ``order`` one after the other (``stagger_s`` apart, default the plan's);
        vehicles in ``land_only`` land even with RTL."""
        waits = []
        try:
            await self._command_down(order, rtl, land_only, self.plan.stagger_s if stagger_s is None else stagger_s,
                                     waits)
            await asyncio.gather(*waits)
        finally:  # cancelled (an operator's land / rtl): no orphan waits
            for w in waits:
                w.cancel()

    async def _command_down(self, order, rtl: bool, land_only, stagger_s: float, waits: list) -> None:
        gate = self.gate
        for i, sysid in enumerate(order):
            if i and stagger_s > 0:
                await self.clock.sleep(stagger_s)
            v = self.fleet.vehicles[sysid]
            self.state.release(sysid)
            by_rtl = rtl and sysid not in land_only
            try:
                await retried(self.events, self.clock, (lambda v=v: v.rtl()) if by_rtl else (lambda v=v: v.land()),
                              f"{'RTL' if by_rtl else 'land'} of vehicle {sysid}")
            except MissionError as exc:
                self.events.event(str(exc), level="error")
                continue
            if gate is not None and sysid in gate.sysids:
                gate.remove(sysid)
            self.state.set_status(sysid, "returning" if by_rtl else "landing")
            waits.append(asyncio.ensure_future(self._wait_landed(sysid)))

    async def _wait_landed(self, sysid: int, timeout_s: float = 180.0) -> None:
        v = self.fleet.vehicles[sysid]

        def _down():
            update_odometry(self.state, self.fleet)
            return (v.state.landed is True) or not v.state.armed

        try:
            await self.waiter.wait_until(_down, timeout_s, f"vehicle {sysid} to land", poll_s=0.2)
        except MissionError as exc:
            self.events.event(str(exc), level="error")
            return
        self.state.set_landed(sysid)
        self.events.event(f"vehicle {sysid} landed", sysid=sysid)
