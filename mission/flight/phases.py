"""The coordinator's phases around the seek: takeoff, assemble, return (connect and preflight:
:mod:`mission.flight.connect`).

Each function takes the :class:`~mission.flight.coordinator.Coordinator` and works on its vehicles,
ramp and log. Separation during takeoff, assembly and return comes from altitude layers
(:func:`mission.flight.layers.shared_layers`): every vehicle climbs over its own home to its
layer, flies horizontally at that layer, then moves vertically, all vehicles finishing a step
before the next starts; vehicles share a layer when their horizontal paths keep
``min_separation_m + LAYER_MARGIN_M`` apart (see ``docs/mission.md``).
"""
from __future__ import annotations

import asyncio

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.flight.motion import retried, setpoint_stream
from mission.flight.readiness_autopilot import arm_and_takeoff
from mission.flight.control import OperatorStop
from mission.flight.state import MissionError
from mission.flight.layers import shared_layers
from mission.flight.targets import assign_slots

__all__ = ["takeoff", "assemble", "return_home", "land_all_now", "formation_offsets", "solve_formation"]


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
def _home_enu(co, sysid) -> np.ndarray:
    v = co.vehicles[sysid]
    home = v.state.home
    if home is None:
        raise MissionError(f"vehicle {sysid} has no home position")
    return np.asarray(geodetic_to_enu(home[0], home[1], home[2], co.plan.origin), dtype=float)


def _plan_slots(co, offsets: np.ndarray) -> None:
    """Formation slots (``offsets``, one per vehicle: :func:`solve_formation`), the assignment of
    vehicles to them (from their homes) and the layers."""
    plan = co.plan
    sysids = sorted(co.vehicles)
    start = plan.seeking.start_point()
    homes = np.array([_home_enu(co, s) for s in sysids])
    cur = np.column_stack([homes[:, :2], np.zeros(len(sysids))])
    slots = start + offsets
    perm = assign_slots(cur, np.column_stack([slots[:, :2], np.zeros(len(sysids))]))
    slot_offsets = {s: offsets[perm[i]] for i, s in enumerate(sysids)}
    from formation import metrics

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
    co.state.set_formation(slot_offsets, layer_alt_m={s: float(alts[i]) for i, s in enumerate(sysids)},
                           home_enu={s: homes[i] for i, s in enumerate(sysids)})
    co.event(f"formation {plan.formation.type}, {len(sysids)} slots, radius {plan.formation.radius_m} m, "
             f"d_min {d_min:.2f} m; {len(np.unique(alts))} layers {alts.min():.1f}..{alts.max():.1f} m",
             slots={s: co.state.slot_offsets[s] for s in sysids}, layers=dict(co.state.layer_alt_m))


async def takeoff(co) -> None:
    """Arm and take off, staggered by ``stagger_s``, each vehicle to its altitude layer (lowest first)."""
    co.set_phase("takeoff")
    plan = co.plan
    offsets = np.empty((0, 3))
    while len(offsets) != len(co.vehicles):  # one slot per vehicle, also if the set changed meanwhile
        offsets = await solve_formation(plan.formation.type, len(co.vehicles), plan.formation.radius_m,
                                        plan.formation.seed)
    _plan_slots(co, offsets)
    setpoint_stream(co, list(co.vehicles.values()))
    co.gate.start()  # the safety gate: moves, checks and sends the setpoints
    order = sorted(co.vehicles, key=lambda s: (co.state.layer_alt_m[s], s))
    waits = []
    for i, sysid in enumerate(order):
        if i:
            await co.clock.sleep(plan.stagger_s)
        v = co.vehicles[sysid]
        home = co.state.home_enu[sysid]
        rel_alt = co.state.layer_alt_m[sysid] - home[2]
        held = {}

        def _note_start(v=v, held=held):
            # PX4's takeoff holds where the vehicle is at this instant (no await in between): the
            # ramp must start there, not at the home, or its first setpoint jumps by the GPS drift
            held["xy"] = v.position_enu_m()

        try:  # arming refusals retried with the autopilot's words, ArduPilot's mode re-checked
            await arm_and_takeoff(sysid, v, rel_alt, co.clock, co, co.plan.preflight.autopilot_ready_timeout_s,
                                  before_takeoff=_note_start)
        except OperatorStop:
            raise  # the operator ended the mission: nobody failed
        except MissionError as exc:
            co.takeoff_loss().lose_failed(sysid, str(exc))
            continue
        co.state.set_airborne(sysid, "taking off")
        co.event(f"vehicle {sysid} taking off to {rel_alt:.1f} m above home", sysid=sysid)
        start = home if held.get("xy") is None else held["xy"]
        waits.append(asyncio.ensure_future(_hold_after_climb(co, sysid, start, co.state.layer_alt_m[sysid])))
    await asyncio.gather(*waits)


async def _hold_after_climb(co, sysid, start, layer_alt):
    """Wait until the vehicle is near its layer, then give it a setpoint there (above ``start``:
    the home, or for PX4 the point its takeoff held)."""
    v = co.vehicles[sysid]
    target = np.array([start[0], start[1], layer_alt])
    if v.flavour == "px4":
        co.gate.add(sysid, target)  # PX4 offboard: setpoints must keep streaming from now on

    def _near():
        if sysid in co.state.lost:
            return True
        p = co.telemetry_position(sysid)
        return p is not None and abs(float(p[2]) - layer_alt) < 0.6

    try:
        await co.wait_until(_near, 60.0 + 2.0 * layer_alt, f"vehicle {sysid} to climb to {layer_alt:.1f} m")
    except OperatorStop:
        raise
    except MissionError as exc:
        co.takeoff_loss().lose_failed(sysid, str(exc))
    if sysid in co.state.lost:
        return
    if sysid not in co.gate.sysids:
        co.gate.add(sysid, target)
    co.state.set_status(sysid, "holding")




async def assemble(co) -> None:
    """Fly from the takeoff layers into the formation at the start point (layered transfer).

    The legs keep clear of lost vehicles still flying (:meth:`mission.flight.return_clear.ReturnClear.fly_clear`).
    """
    co.set_phase("assemble")
    plan = co.plan
    sysids = sorted(s for s in co.vehicles if s not in co.state.lost and s in co.gate.sysids)
    if len(sysids) < 4:
        raise MissionError(f"vehicles {sorted(co.state.lost)} lost before the formation was assembled: "
                           f"{len(sysids)} left, a formation needs 4")
    centre = plan.seeking.start_point()
    # the layered legs, re-planned around lost vehicles still flying (e.g. one lost in takeoff);
    # a vehicle that cannot reach its slot in time is lost, the others go on (if 4 are left)
    goals = {s: centre + co.state.slot_offsets[s] for s in sysids}
    try:
        await co.return_clear().fly_clear(sysids, goals, plan.seeking.arrival_tol_m, what="assembly")
    except OperatorStop:
        raise  # the operator ended the mission: nobody failed
    except MissionError as exc:
        late = co.takeoff_loss().laggards(sysids, plan.seeking.arrival_tol_m)
        if not late:
            raise
        for s in late:
            co.takeoff_loss().lose_failed(s, str(exc))
        sysids = [s for s in sysids if s not in co.state.lost]
        if len(sysids) < 4:
            raise MissionError(f"vehicles {sorted(co.state.lost)} lost during the assembly: {len(sysids)} left, "
                               "a formation needs 4") from None
        await co.return_clear().fly_clear(sysids, goals, plan.seeking.arrival_tol_m, what="assembly")
    co.state.move_centre(centre)
    for s in sysids:
        co.state.set_status(s, "in formation")
    co.event(f"formation assembled at ({centre[0]:.1f}, {centre[1]:.1f}, {centre[2]:.1f}) m")


# ------------------------------------------------------------------------------------- return
async def return_home(co) -> None:
    """Back over the homes by layers, then land (or RTL), staggered by ``stagger_s``.

    The paths, the descents included, keep ``min_separation_m + OBSTACLE_MARGIN_M`` from lost
    vehicles still flying (:meth:`mission.flight.return_clear.ReturnClear.fly_return`); a vehicle whose home is
    obstructed lands beside it. An operator's ``land`` / ``rtl`` (:mod:`mission.flight.control`)
    replaces it, also half-way: every airborne vehicle is commanded to LAND / RTL at once.
    """
    order = co.control.landing
    if order is None:
        order = await co.control.unless_landing_ordered(_return_home(co))
    while order is not None:
        co.set_phase("return", behaviour=f"{order} (operator)")
        done = order
        order = await co.control.unless_landing_ordered(
            _land_staggered(co, sorted(co.state.airborne), rtl=order == "rtl", stagger_s=0.0), current=done)


async def _return_home(co) -> None:
    """The mission's own return (:func:`return_home` without an operator's order)."""
    co.set_phase("return", behaviour=co.plan.return_behaviour)
    plan = co.plan
    flying = [s for s in sorted(co.state.airborne) if co.gate is not None and s in co.gate.sysids]
    land_here: set[int] = set()
    if flying:
        land_here = await co.return_clear().fly_return(flying)
    await _land_staggered(co, sorted(co.state.airborne, key=lambda s: co.state.layer_alt_m.get(s, 0.0)),
                          rtl=plan.return_behaviour == "rtl", land_only=land_here)


async def _land_staggered(co, order, rtl: bool, land_only=frozenset(), stagger_s: float | None = None) -> None:
    """Land (or RTL) ``order`` one after the other (``stagger_s`` apart, default the plan's);
    vehicles in ``land_only`` land even with RTL."""
    waits = []
    try:
        await _command_down(co, order, rtl, land_only, co.plan.stagger_s if stagger_s is None else stagger_s,
                            waits)
        await asyncio.gather(*waits)
    finally:  # cancelled (an operator's land / rtl): no orphan waits
        for w in waits:
            w.cancel()


async def _command_down(co, order, rtl: bool, land_only, stagger_s: float, waits: list) -> None:
    for i, sysid in enumerate(order):
        if i and stagger_s > 0:
            await co.clock.sleep(stagger_s)
        v = co.vehicles[sysid]
        co.state.release(sysid)
        by_rtl = rtl and sysid not in land_only
        try:
            await retried(co, (lambda v=v: v.rtl()) if by_rtl else (lambda v=v: v.land()),
                           f"{'RTL' if by_rtl else 'land'} of vehicle {sysid}")
        except MissionError as exc:
            co.event(str(exc), level="error")
            continue
        if co.gate is not None and sysid in co.gate.sysids:
            co.gate.remove(sysid)
        co.state.set_status(sysid, "returning" if by_rtl else "landing")
        waits.append(asyncio.ensure_future(_wait_landed(co, sysid)))


async def _wait_landed(co, sysid, timeout_s: float = 180.0) -> None:
    v = co.vehicles[sysid]

    def _down():
        co.update_odometry()
        return (v.state.landed is True) or not v.state.armed

    try:
        await co.wait_until(_down, timeout_s, f"vehicle {sysid} to land", poll_s=0.2)
    except MissionError as exc:
        co.event(str(exc), level="error")
        return
    co.state.set_landed(sysid)
    co.event(f"vehicle {sysid} landed", sysid=sysid)


async def land_all_now(co) -> None:
    """Emergency: land every airborne vehicle where it is (no stagger)."""
    await _land_staggered(co, sorted(co.state.airborne), rtl=False)
