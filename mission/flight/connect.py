"""The coordinator's first phases: connect to every vehicle, then the preflight checks.

Each function takes the :class:`~mission.flight.coordinator.Coordinator`; nothing is armed here
(``swarmseek dry-run`` runs only these two phases).
"""
from __future__ import annotations

import asyncio

import numpy as np

from formation.geodesy import geodetic_to_enu
# imported with the module, not in the mission's event loop: a first import there holds the loop
# (tests/mission/sim/test_loop_debug.py found vehicle_link's 0.04-0.1 s in the first connect task)
from mission.core.uri import parse_connection
from mission.flight.failsafe_params import check_failsafe_params
from mission.flight.readiness_autopilot import wait_autopilots_ready
from mission.flight.state import MissionError, VehicleReadiness
from mission.link.endpoint import MavEndpoint
from mission.link.endpoint_registry import SysidRegistry
from mission.link.poller import UdpPoller
from mission.safety.envelope import SafetyEnvelope
from mission.safety.fence import Geofence
from mission.vehicle.prearm import extra_rates_hz
from mission.vehicle.vehicle_link import DEFAULT_RATES_HZ, VehicleLink
from mission.vehicle.wind import wind_rates_hz

__all__ = ["build_envelope", "connect", "preflight", "standby_refusal", "wait_standby", "REFUSAL_SETTLE_S"]

_MAV_STATE_STANDBY = 3
#: clock seconds an autopilot not in STANDBY must keep saying why it will not arm before the
#: preflight stops waiting for STANDBY (a booting PX4 may say so for a moment, then be ready)
REFUSAL_SETTLE_S = 2.0


def build_envelope(plan):
    """The plan's :class:`mission.safety.envelope.SafetyEnvelope`, or None when no fence polygon is given."""
    if not plan.geofence.polygon_en_m:
        return None

    fence = Geofence(np.asarray(plan.geofence.polygon_en_m, dtype=float),
                     plan.geofence.min_alt_m, plan.geofence.max_alt_m)
    return SafetyEnvelope(fence, plan.max_speed_m_s, plan.min_separation_m, plan.formation.radius_m)


# ------------------------------------------------------------------------------------ connect
async def connect(co, required: bool = True) -> None:
    """Open each distinct connection once and attach every vehicle of the plan to it."""

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
        co.use_poller(UdpPoller())
    await asyncio.gather(*(_open(co, uri, by_uri[uri], registry, problems) for uri in by_uri))
    await asyncio.gather(*(_attach(co, vp, problems) for vp in plan.vehicles))
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


async def _open(co, uri: str, vehicles: list, registry, problems: list[str]) -> None:
    """Open the endpoint of ``uri`` for ``vehicles`` (the only system ids it accepts); on failure
    every vehicle on it is not ready (``no link``)."""

    try:
        co.add_endpoint(uri, await MavEndpoint.open(uri, clock=co.clock, tlog_dir=co.tlog_dir,
                                                    signing=co.plan.security, registry=registry,
                                                    poller=co.poller,
                                                    planned_sysids=[vp.sysid for vp in vehicles]))
    except (OSError, ValueError) as exc:
        problems.append(f"{uri}: {exc}")
        for vp in vehicles:
            co.state.set_readiness(VehicleReadiness(vp.sysid, vp.id, uri, {"connected": False},
                                                    [f"cannot open {uri}: {exc}"]), "no link")


async def _attach(co, vp, problems: list[str]) -> None:
    """Attach vehicle ``vp`` to its endpoint (heartbeat, autopilot version, telemetry rates)."""

    ep = co.endpoints.get(vp.connection)
    if ep is None:
        return
    try:
        v = await VehicleLink.create(ep, vp.sysid, clock=co.clock, mission_origin=co.plan.origin,
                                     heartbeat_timeout_s=co.plan.heartbeat_timeout_s)
    except Exception as exc:  # noqa: BLE001 - LinkError, timeouts: reported per vehicle
        problems.append(f"vehicle {vp.sysid} ({vp.id}) on {vp.connection}: {exc or type(exc).__name__}")
        co.state.set_readiness(VehicleReadiness(vp.sysid, vp.id, vp.connection, {"connected": False},
                                                [f"no heartbeat: {exc or type(exc).__name__}"]), "no heartbeat")
        return
    co.add_vehicle(v)
    co.state.set_status(vp.sysid, "connected")
    try:
        await v.request_autopilot_version()
    except Exception as exc:  # noqa: BLE001 - optional information
        co.event(f"vehicle {vp.sysid}: no AUTOPILOT_VERSION ({exc})", level="warning")
    try:  # only the telemetry the mission needs (CPU at N = 100+); refusals are not fatal
        refused = await v.set_message_rates(DEFAULT_RATES_HZ | extra_rates_hz(v.flavour)
                                            | wind_rates_hz(v.flavour), strict=False)
    except Exception as exc:  # noqa: BLE001 - the autopilot's default rates still work
        refused = {"*": str(exc)}
    if refused:
        co.event(f"vehicle {vp.sysid}: telemetry rates not all set ({refused})", level="warning")


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
    """Check every connected vehicle: heartbeat, position estimate, home, battery, armable, fence,
    its ground-station-loss failsafe (:mod:`mission.flight.failsafe_params`) and the autopilot's own
    pre-arm state (:mod:`mission.flight.readiness_autopilot`, waited for)."""
    co.set_phase("preflight")
    plan = co.plan
    envelope = None
    try:
        envelope = build_envelope(plan)
    except ValueError as exc:
        raise MissionError(f"preflight: the safety envelope cannot be built: {exc}") from None

    await asyncio.gather(*(_check_vehicle(co, s, v, envelope, timeout_s) for s, v in co.vehicles.items()))

    await check_failsafe_params(co.state, co.vehicles, plan.preflight, co.simulated_fleet, co)
    await wait_autopilots_ready(co.state, co.vehicles, co.clock, co, plan.preflight.autopilot_ready_timeout_s)
    await _sensor_check(co)
    for sysid in sorted(co.state.readiness):
        r = co.state.readiness[sysid]
        co.event(f"vehicle {sysid} ({r.id}): " + ("ready" if r.ready else "NOT READY: " + "; ".join(r.problems)),
                 level="info" if r.ready else "warning", sysid=sysid, checks=r.checks, warnings=r.warnings)
    co.use_envelope(envelope)


async def _check_vehicle(co, sysid: int, v, envelope, timeout_s: float) -> None:
    """One vehicle's preflight checks (:func:`preflight`); records its readiness and status."""
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
    r.checks["battery"] = batt is None or batt >= co.plan.min_battery_pct
    if batt is None:
        co.event(f"vehicle {sysid}: battery level not reported; not checked", level="warning")
    elif not r.checks["battery"]:
        r.problems.append(f"battery {batt:.0f} % below {co.plan.min_battery_pct:.0f} %")
    waited_from = co.clock.time()
    reason = await wait_standby(v, co.clock, deadline)
    st = v.state.system_status
    r.checks["armable"] = (not v.state.armed) and st in (None, _MAV_STATE_STANDBY)
    if v.state.armed:
        r.problems.append("already armed (flying from an earlier mission? `swarmseek resume LOG` brings it home)")
    elif not r.checks["armable"]:
        r.problems.append(f"system status {st} (not STANDBY)" + (f"; {reason}" if reason else ""))
        co.event(f"vehicle {sysid}: system status {st} (not STANDBY) after {co.clock.time() - waited_from:.1f} s"
                 + (f": {reason}" if reason else ""), level="warning", sysid=sysid, reason=reason)
    if home is not None and envelope is not None:
        h = geodetic_to_enu(home[0], home[1], home[2], co.plan.origin)
        inside = bool(envelope.fence.contains(np.array([h[0], h[1], co.plan.geofence.min_alt_m + 0.01])))
        r.checks["home_in_fence"] = inside
        if not inside:
            r.problems.append(f"home ({h[0]:.1f}, {h[1]:.1f}) m is outside the geofence")
    co.state.set_readiness(r, "ready" if r.ready else "not ready: " + "; ".join(r.problems))


def standby_refusal(v, now_s: float) -> str | None:
    """Why vehicle ``v``'s autopilot says it will not arm: its last pre-arm / arming refusal
    STATUSTEXT while recent, else its SYS_STATUS pre-arm check bit unhealthy; None when it says
    nothing (or the link has no pre-arm status, e.g. a test double)."""
    status = getattr(v, "prearm", None)
    if status is None:
        return None
    says = status.autopilot_says(now_s)
    if says:
        return f"autopilot says: {says!r}"
    if status.prearm_check_fails():
        return "the autopilot's pre-arm checks fail (SYS_STATUS PREARM_CHECK unhealthy)"
    return None


async def wait_standby(v, clock, deadline_s: float) -> str | None:
    """Wait until vehicle ``v`` reports STANDBY (or is armed, or reports no status).

    An autopilot still booting reports UNINIT/BOOT/CALIBRATING for a while (PX4 SIH just after
    start): that is waited for, until ``deadline_s`` (clock time). A PX4 whose pre-arm checks
    fail stays in UNINIT for good: the wait ends as soon as the autopilot has said why
    (:func:`standby_refusal`) for :data:`REFUSAL_SETTLE_S` in a row, not at the deadline.

    Returns
    -------
    str or None
        The autopilot's reason when the vehicle is still not in STANDBY at the end, else None.
    """
    def waiting() -> bool:
        return not v.state.armed and v.state.system_status not in (None, _MAV_STATE_STANDBY)

    said_since = None
    while waiting() and clock.time() < deadline_s:
        now = clock.time()
        if standby_refusal(v, now) is None:
            said_since = None
        elif said_since is None:
            said_since = now
        elif now - said_since >= REFUSAL_SETTLE_S:
            break
        await clock.sleep(0.2)
    return standby_refusal(v, clock.time()) if waiting() else None


async def _sensor_check(co) -> None:
    """The mission-wide checks: zenoh, a reading from every sensor, start and paths inside the
    fence (:mod:`mission.flight.readiness_mission`; a missing reading fails the vehicle's
    readiness unless ``[preflight] require_readings = false``)."""
    await co.readiness_checks().check()
