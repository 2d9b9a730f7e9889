"""The coordinator's phases before and after the seek: connect, preflight, takeoff, assemble, return.

Each function takes the :class:`~mission.flight.coordinator.Coordinator` and works on its vehicles,
ramp and log. Separation during takeoff, assembly and return comes from altitude layers
(:func:`mission.flight.targets.layered_altitudes`): every vehicle climbs over its own home to its own
layer, flies horizontally at that layer, then moves vertically, all vehicles finishing a step
before the next starts (see ``docs/mission.md``).
"""
from __future__ import annotations

import asyncio

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.flight.coordinator import MissionError, VehicleReadiness
from mission.flight.targets import TargetRamp, assign_slots, layered_altitudes

__all__ = ["connect", "preflight", "takeoff", "assemble", "return_home", "land_all_now",
           "formation_offsets", "build_envelope", "move_and_wait"]

_MAV_STATE_STANDBY = 3
_MAV_STATE_ACTIVE = 4


def formation_offsets(kind: str, n: int, radius_m: float, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` slot offsets of the formation about its centre (ENU metres)."""
    import formation

    if kind == "symmetric":
        return np.asarray(formation.symmetric_cylinder(n, radius_m), dtype=float)
    return np.asarray(formation.cvt_sphere(n, radius_m, seed=seed), dtype=float)


def build_envelope(plan):
    """The plan's :class:`mission.safety.envelope.SafetyEnvelope`, or None when no fence polygon is given."""
    if not plan.geofence.polygon_en_m:
        return None
    from mission.safety.envelope import Geofence, SafetyEnvelope

    fence = Geofence(np.asarray(plan.geofence.polygon_en_m, dtype=float),
                     plan.geofence.min_alt_m, plan.geofence.max_alt_m)
    return SafetyEnvelope(fence, plan.max_speed_m_s, plan.min_separation_m, plan.formation.radius_m)


# ------------------------------------------------------------------------------------ connect
async def connect(co, required: bool = True) -> None:
    """Open each distinct connection once and attach every vehicle of the plan to it."""
    from mission.link.endpoint import MavEndpoint, SysidRegistry
    from mission.link.poller import UdpPoller
    from mission.core.uri import parse_connection
    from mission.vehicle.vehicle_link import DEFAULT_RATES_HZ, VehicleLink

    co.set_phase("connect")
    plan = co.plan
    by_uri: dict[str, list] = {}
    for vp in plan.vehicles:
        by_uri.setdefault(vp.connection, []).append(vp)
    problems: list[str] = []
    # one registry: a system id heard on two endpoints is an error naming both; one poller for
    # many UDP sockets (cheaper than one loop wake-up per datagram from a few tens of vehicles on)
    registry = SysidRegistry()
    n_udp = sum(1 for uri in by_uri if _is_udp(parse_connection, uri))
    if n_udp >= _POLLER_MIN_UDP_ENDPOINTS and co.poller is None:
        co.poller = UdpPoller()

    async def _open(uri):
        try:
            co.endpoints[uri] = await MavEndpoint.open(uri, clock=co.clock, tlog_dir=co.tlog_dir,
                                                       signing=plan.security, registry=registry,
                                                       poller=co.poller)
        except (OSError, ValueError) as exc:
            problems.append(f"{uri}: {exc}")
            for vp in by_uri[uri]:
                co.status[vp.sysid] = "no link"
                co.readiness[vp.sysid] = VehicleReadiness(vp.sysid, vp.id, uri, {"connected": False},
                                                          [f"cannot open {uri}: {exc}"])

    await asyncio.gather(*(_open(uri) for uri in by_uri))

    async def _attach(vp):
        ep = co.endpoints.get(vp.connection)
        if ep is None:
            return
        try:
            v = await VehicleLink.create(ep, vp.sysid, clock=co.clock, mission_origin=plan.origin,
                                         heartbeat_timeout_s=plan.heartbeat_timeout_s)
        except Exception as exc:  # noqa: BLE001 - LinkError, timeouts: reported per vehicle
            problems.append(f"vehicle {vp.sysid} ({vp.id}) on {vp.connection}: {exc or type(exc).__name__}")
            co.status[vp.sysid] = "no heartbeat"
            co.readiness[vp.sysid] = VehicleReadiness(vp.sysid, vp.id, vp.connection, {"connected": False},
                                                      [f"no heartbeat: {exc or type(exc).__name__}"])
            return
        co.vehicles[vp.sysid] = v
        co.status[vp.sysid] = "connected"
        try:
            await v.request_autopilot_version()
        except Exception as exc:  # noqa: BLE001 - optional information
            co.event(f"vehicle {vp.sysid}: no AUTOPILOT_VERSION ({exc})", level="warning")
        try:  # only the telemetry the mission needs (CPU at N = 100+); refusals are not fatal
            refused = await v.set_message_rates(DEFAULT_RATES_HZ, strict=False)
        except Exception as exc:  # noqa: BLE001 - the autopilot's default rates still work
            refused = {"*": str(exc)}
        if refused:
            co.event(f"vehicle {vp.sysid}: telemetry rates not all set ({refused})", level="warning")

    await asyncio.gather(*(_attach(vp) for vp in plan.vehicles))
    dup = _duplicate_uids(co)
    if dup:
        problems.append(dup)
    for sysid, v in co.vehicles.items():
        co.event(f"vehicle {sysid} ({co.ids[sysid]}): {v.flavour} on {co.plan_vehicle(sysid).connection}",
                 sysid=sysid, flavour=v.flavour, uid=getattr(v, "uid", None))
    if problems and required:
        raise MissionError("connect failed: " + "; ".join(problems))
    for p in problems:
        co.event(p, level="error")


#: from this many UDP endpoints on, one poller task reads them all
_POLLER_MIN_UDP_ENDPOINTS = 16


def _is_udp(parse_connection, uri: str) -> bool:
    try:
        return parse_connection(uri).kind.startswith("udp")
    except (ValueError, AttributeError):
        return False


def _duplicate_uids(co) -> str | None:
    seen: dict[int, int] = {}
    for sysid, v in co.vehicles.items():
        uid = getattr(v, "uid", None)
        if not uid:
            continue
        if uid in seen:
            a, b = seen[uid], sysid
            return (f"vehicles {a} ({co.plan_vehicle(a).connection}) and {b} ({co.plan_vehicle(b).connection}) "
                    f"report the same autopilot uid {uid:#x}: one autopilot reached twice?")
        seen[uid] = sysid
    return None


# ---------------------------------------------------------------------------------- preflight
async def preflight(co, timeout_s: float = 30.0) -> None:
    """Check every connected vehicle: heartbeat, position estimate, home, battery, armable, fence."""
    co.set_phase("preflight")
    plan = co.plan
    envelope = None
    try:
        envelope = build_envelope(plan)
    except ValueError as exc:
        raise MissionError(f"preflight: the safety envelope cannot be built: {exc}") from None

    async def _check(sysid, v):
        vp = co.plan_vehicle(sysid)
        r = VehicleReadiness(sysid, vp.id, vp.connection, flavour=v.flavour)
        r.checks["connected"] = True
        r.checks["heartbeat"] = v.link_age_s() < 3.0
        if not r.checks["heartbeat"]:
            r.problems.append(f"last heartbeat {v.link_age_s():.1f} s ago")
        deadline = co.clock.time() + timeout_s
        while not v.state.position_ok and co.clock.time() < deadline:
            await co.clock.sleep(0.2)
        r.checks["position"] = bool(v.state.position_ok)
        if not r.checks["position"]:
            r.problems.append(f"no position estimate after {timeout_s:.0f} s")
        try:
            home = await v.wait_home(max(1.0, deadline - co.clock.time()))
            r.checks["home"] = True
        except Exception as exc:  # noqa: BLE001 - timeout or link error
            home = None
            r.checks["home"] = False
            r.problems.append(f"no home position ({exc or 'timeout'})")
        batt_deadline = co.clock.time() + 5.0
        while v.state.battery_remaining_pct is None and co.clock.time() < batt_deadline:
            await co.clock.sleep(0.2)
        batt = v.state.battery_remaining_pct
        r.checks["battery"] = batt is None or batt >= plan.min_battery_pct
        if batt is None:
            co.event(f"vehicle {sysid}: battery level not reported; not checked", level="warning")
        elif not r.checks["battery"]:
            r.problems.append(f"battery {batt:.0f} % below {plan.min_battery_pct:.0f} %")
        st = v.state.system_status
        r.checks["armable"] = (not v.state.armed) and st in (None, _MAV_STATE_STANDBY)
        if v.state.armed:
            r.problems.append("already armed")
        elif not r.checks["armable"]:
            r.problems.append(f"system status {st} (not STANDBY)")
        if home is not None and envelope is not None:
            h = geodetic_to_enu(home[0], home[1], home[2], plan.origin)
            inside = bool(envelope.fence.contains(np.array([h[0], h[1], plan.geofence.min_alt_m + 0.01])))
            r.checks["home_in_fence"] = inside
            if not inside:
                r.problems.append(f"home ({h[0]:.1f}, {h[1]:.1f}) m is outside the geofence")
        co.readiness[sysid] = r
        co.status[sysid] = "ready" if r.ready else "not ready: " + "; ".join(r.problems)

    await asyncio.gather(*(_check(s, v) for s, v in co.vehicles.items()))
    await _sensor_check(co)
    for sysid in sorted(co.readiness):
        r = co.readiness[sysid]
        co.event(f"vehicle {sysid} ({r.id}): " + ("ready" if r.ready else "NOT READY: " + "; ".join(r.problems)),
                 level="info" if r.ready else "warning", sysid=sysid, checks=r.checks)
    co.envelope = envelope


async def _sensor_check(co, timeout_s: float = 5.0) -> None:
    """Warn (not fail) about vehicles with no accepted zenoh reading yet.

    zenoh says nothing when a sensor's TLS handshake or login is refused, or when it connects
    elsewhere: without this, such a mission would take off and only notice in the seek.
    Not a readiness failure: a sensor may start publishing only once airborne.
    """
    if getattr(co, "_subscriber", None) is None:
        return  # no zenoh session (dry run)

    def _missing():
        return [s for s in sorted(co.vehicles) if co.store.latest(s) is None]

    deadline = co.clock.time() + timeout_s
    while _missing() and co.clock.time() < deadline:
        await co.clock.sleep(0.2)
    missing = _missing()
    if missing:
        counts = co.store.counts()
        rejected = {k: n for k, n in counts["rejected"].items() if n}
        co.event(f"preflight: no sensor reading accepted from vehicles {missing} within {timeout_s:g} s "
                 "(sensor not running or not connected to this zenoh session: a refused TLS handshake "
                 "or login is silent in zenoh; check the sensor's output)"
                 + (f"; readings rejected so far: {rejected}" if rejected else ""),
                 level="warning", sysids=missing, readings=counts)


# ------------------------------------------------------------------------------------ takeoff
def _home_enu(co, sysid) -> np.ndarray:
    v = co.vehicles[sysid]
    home = v.state.home
    if home is None:
        raise MissionError(f"vehicle {sysid} has no home position")
    return np.asarray(geodetic_to_enu(home[0], home[1], home[2], co.plan.origin), dtype=float)


def _plan_slots(co) -> None:
    """Formation slots, the assignment of vehicles to them (from their homes) and the layers."""
    plan = co.plan
    sysids = sorted(co.vehicles)
    offsets = formation_offsets(plan.formation.type, len(sysids), plan.formation.radius_m,
                                plan.formation.seed)
    start = plan.seeking.start_point()
    homes = np.array([_home_enu(co, s) for s in sysids])
    cur = np.column_stack([homes[:, :2], np.zeros(len(sysids))])
    slots = start + offsets
    perm = assign_slots(cur, np.column_stack([slots[:, :2], np.zeros(len(sysids))]))
    co.slot_offsets = {s: offsets[perm[i]] for i, s in enumerate(sysids)}
    from formation import metrics

    d_min = float(metrics(offsets).d_min)
    if d_min < plan.min_separation_m:
        raise MissionError(f"the {plan.formation.type} formation of {len(sysids)} vehicles with radius "
                           f"{plan.formation.radius_m} m has slots {d_min:.2f} m apart, below "
                           f"min_separation_m {plan.min_separation_m} m: increase the radius")
    base = float(np.max(homes[:, 2])) + plan.takeoff_alt_m
    try:
        alts = layered_altitudes(len(sysids), base, plan.geofence.max_alt_m - 0.5, plan.min_separation_m)
    except ValueError as exc:
        raise MissionError(f"takeoff layers: {exc}") from None
    order = sorted(sysids, key=lambda s: co.slot_offsets[s][2])  # lowest slot -> lowest layer
    co.layer_alt_m = {s: float(alts[i]) for i, s in enumerate(order)}
    co.home_enu = {s: homes[i] for i, s in enumerate(sysids)}
    co.event(f"formation {plan.formation.type}, {len(sysids)} slots, radius {plan.formation.radius_m} m, "
             f"d_min {d_min:.2f} m; layers {alts[0]:.1f}..{alts[-1]:.1f} m",
             slots={s: co.slot_offsets[s] for s in sysids}, layers=co.layer_alt_m)


async def takeoff(co) -> None:
    """Arm and take off, staggered by ``stagger_s``, each vehicle to its own altitude layer."""
    from mission.vehicle.streamer import SetpointStreamer

    co.set_phase("takeoff")
    plan = co.plan
    _plan_slots(co)
    co.streamer = SetpointStreamer(list(co.vehicles.values()), rate_hz=plan.setpoint_rate_hz, clock=co.clock,
                                 max_speed_m_s=plan.max_speed_m_s)
    # the ramp (new setpoints, each batch safety-checked) runs at most at 10 Hz; the streamer
    # repeats the latest setpoint at setpoint_rate_hz in between (identical, hence as safe)
    co.ramp = TargetRamp(co.streamer, co.clock, plan.max_speed_m_s, rate_hz=min(plan.setpoint_rate_hz, 10.0),
                         envelope=co.envelope, on_violation=lambda m: co.event(m, level="warning"))
    await co.streamer.start()
    co.ramp.start()
    order = sorted(co.vehicles, key=lambda s: co.layer_alt_m[s])
    waits = []
    for i, sysid in enumerate(order):
        if i:
            await co.clock.sleep(plan.stagger_s)
        v = co.vehicles[sysid]
        home = co.home_enu[sysid]
        rel_alt = co.layer_alt_m[sysid] - home[2]
        await _retried(co, lambda v=v: v.takeoff(rel_alt), f"takeoff of vehicle {sysid}")
        co.airborne.add(sysid)
        co.status[sysid] = "taking off"
        co.event(f"vehicle {sysid} taking off to {rel_alt:.1f} m above home", sysid=sysid)
        waits.append(asyncio.ensure_future(_hold_after_climb(co, sysid, home, co.layer_alt_m[sysid])))
    await asyncio.gather(*waits)


async def _hold_after_climb(co, sysid, home, layer_alt):
    """Wait until the vehicle is near its layer, then give it a setpoint there."""
    v = co.vehicles[sysid]
    target = np.array([home[0], home[1], layer_alt])
    if v.flavour == "px4":
        co.ramp.add(sysid, target)  # PX4 offboard: setpoints must keep streaming from now on

    def _near():
        if sysid in co.lost:
            return True
        p = co._telemetry_position(sysid)
        return p is not None and abs(float(p[2]) - layer_alt) < 0.6

    await co.wait_until(_near, 60.0 + 2.0 * layer_alt, f"vehicle {sysid} to climb to {layer_alt:.1f} m")
    if sysid in co.lost:
        return
    if sysid not in co.ramp.sysids:
        co.ramp.add(sysid, target)
    co.status[sysid] = "holding"


async def _retried(co, action, what: str, attempts: int = 3):
    """Run ``action()`` (a command coroutine, itself retried by ``command_long``) up to ``attempts``
    times: on a lossy link (20 % each way) one command with its 4 sends fails 1.7 % of the
    time; three rounds make it 5e-6. The commands used (mode, arm, takeoff, land) are idempotent."""
    for i in range(attempts):
        try:
            return await action()
        except Exception as exc:  # noqa: BLE001 - CommandError or link error
            if i + 1 == attempts:
                raise MissionError(f"{what} failed after {attempts} rounds of retries: {exc}") from None
            co.event(f"{what}: {exc}; trying again", level="warning")
            await co.clock.sleep(0.5)


# ----------------------------------------------------------------------------------- assemble
async def move_and_wait(co, goals: dict[int, np.ndarray], tol_m: float, timeout_s: float | None = None,
                        what: str = "vehicles to reach their goals") -> None:
    """Set ramp goals and wait until every setpoint is there and every vehicle within ``tol_m``.

    Lost vehicles (``co.lost``, also those lost while waiting) are not waited for.
    """
    goals = {s: g for s, g in goals.items() if s not in co.lost and s in co.ramp.sysids}
    co.ramp.set_goals(goals)
    if timeout_s is None:
        far = max((float(np.linalg.norm(co.ramp.setpoint(s) - g)) for s, g in goals.items()), default=0.0)
        timeout_s = 20.0 + 3.0 * far / min(co.ramp.max_speed_m_s, co.ramp.max_vertical_speed_m_s)

    def _arrived():
        co.update_odometry()
        for s, g in goals.items():
            if s in co.lost or s not in co.ramp.sysids:
                continue
            if not co.ramp.at_goal(s):
                return False
            p = co._telemetry_position(s)
            if p is None or float(np.linalg.norm(np.asarray(p) - g)) > tol_m:
                return False
        return True

    await co.wait_until(_arrived, timeout_s, what, poll_s=0.1)


async def assemble(co) -> None:
    """Fly from the takeoff layers into the formation at the start point (layered transfer).

    The legs keep clear of lost vehicles still flying (:func:`mission.flight.return_clear.fly_clear`).
    """
    co.set_phase("assemble")
    plan = co.plan
    sysids = sorted(s for s in co.vehicles if s not in co.lost and s in co.ramp.sysids)
    if len(sysids) < 4:
        raise MissionError(f"vehicles {sorted(co.lost)} lost before the formation was assembled: "
                           f"{len(sysids)} left, a formation needs 4")
    from mission.flight.return_clear import fly_clear

    centre = plan.seeking.start_point()
    # the layered legs, re-planned around lost vehicles still flying (e.g. one lost in takeoff)
    await fly_clear(co, sysids, {s: centre + co.slot_offsets[s] for s in sysids},
                    plan.seeking.arrival_tol_m, what="assembly")
    co.centre_enu = centre.copy()
    for s in sysids:
        co.status[s] = "in formation"
    co.event(f"formation assembled at ({centre[0]:.1f}, {centre[1]:.1f}, {centre[2]:.1f}) m")


# ------------------------------------------------------------------------------------- return
async def return_home(co) -> None:
    """Back over the homes by layers, then land (or RTL), staggered by ``stagger_s``.

    The paths, the descents included, keep ``min_separation_m + OBSTACLE_MARGIN_M`` from lost
    vehicles still flying (:func:`mission.flight.return_clear.fly_return`); a vehicle whose home is
    obstructed lands beside it.
    """
    from mission.flight.return_clear import fly_return

    co.set_phase("return", behaviour=co.plan.return_behaviour)
    plan = co.plan
    flying = [s for s in sorted(co.airborne) if co.ramp is not None and s in co.ramp.sysids]
    land_here: set[int] = set()
    if flying:
        land_here = await fly_return(co, flying)
    await _land_staggered(co, sorted(co.airborne, key=lambda s: co.layer_alt_m.get(s, 0.0)),
                          rtl=plan.return_behaviour == "rtl", land_only=land_here)


async def _land_staggered(co, order, rtl: bool, land_only=frozenset()) -> None:
    """Land (or RTL) ``order`` one after the other; vehicles in ``land_only`` land even with RTL."""
    waits = []
    for i, sysid in enumerate(order):
        if i:
            await co.clock.sleep(co.plan.stagger_s)
        v = co.vehicles[sysid]
        co.released.add(sysid)
        by_rtl = rtl and sysid not in land_only
        try:
            await _retried(co, (lambda v=v: v.rtl()) if by_rtl else (lambda v=v: v.land()),
                           f"{'RTL' if by_rtl else 'land'} of vehicle {sysid}")
        except MissionError as exc:
            co.event(str(exc), level="error")
            continue
        if co.ramp is not None and sysid in co.ramp.sysids:
            co.ramp.remove(sysid)
        co.status[sysid] = "returning" if by_rtl else "landing"
        waits.append(asyncio.ensure_future(_wait_landed(co, sysid)))
    await asyncio.gather(*waits)


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
    co.airborne.discard(sysid)
    co.status[sysid] = "landed"
    co.event(f"vehicle {sysid} landed", sysid=sysid)


async def land_all_now(co) -> None:
    """Emergency: land every airborne vehicle where it is (no stagger)."""
    await _land_staggered(co, sorted(co.airborne), rtl=False)
