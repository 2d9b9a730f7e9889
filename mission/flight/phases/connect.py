"""The first phases: connect to every vehicle (:class:`Connect`), then the preflight checks
(:class:`Preflight`).

Both are objects built by :mod:`mission.flight.coordinator` with the narrow services they use;
nothing is armed here (``swarmseek dry-run`` runs only these two phases).
"""
from __future__ import annotations

import asyncio
from typing import Any, Callable, Protocol

import numpy as np

from formation.geodesy import geodetic_to_enu
# imported with the module, not in the mission's event loop: a first import there holds the loop
# (tests/mission/sim/test_loop_debug.py found vehicle_link's 0.04-0.1 s in the first connect task)
from mission.core.uri import parse_connection
from mission.core.plan_types import Plan
from mission.flight.failsafe_params import check_failsafe_params
from mission.flight.readiness_autopilot import wait_autopilots_ready
from mission.flight.readiness_mission import MissionChecks
from mission.flight.services import Clock, Fleet, PhaseEvents
from mission.flight.state import MissionError, MissionState, VehicleReadiness
from mission.link.endpoint import MavEndpoint
from mission.link.endpoint_registry import SysidRegistry
from mission.link.poller import UdpPoller
from mission.safety.envelope import SafetyEnvelope
from mission.safety.fence import Geofence
from mission.vehicle.prearm import extra_rates_hz
from mission.vehicle.vehicle_link import DEFAULT_RATES_HZ, VehicleLink
from mission.vehicle.wind import wind_rates_hz

__all__ = ["Connect", "Links", "Preflight", "REFUSAL_SETTLE_S", "build_envelope", "standby_refusal", "wait_standby"]

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
class Links(Protocol):
    """The mission's MAVLink endpoints and UDP poller (closed at the end by their owner)."""

    endpoints: dict
    poller: Any

    def add_endpoint(self, uri: str, endpoint) -> None:
        """A MAVLink endpoint opened for ``uri``."""

    def use_poller(self, poller) -> None:
        """The UDP poller reading every UDP endpoint."""


class Connect:
    """The connect phase: open each distinct connection once, attach every vehicle of the plan to it.

    Parameters
    ----------
    plan : Plan
        The vehicles and their connections, the origin, the signing, the heartbeat timeout.
    state : MissionState
        Each vehicle's status (``connected``) or readiness (``no link``, ``no heartbeat``).
    fleet : Fleet
        Each attached vehicle is added to it.
    links : Links
        Where the endpoints and the poller go.
    clock : Clock
    events : PhaseEvents
    tlog_dir : path or None
        Where each endpoint writes its ``.tlog``.
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, links: Links, clock: Clock,
                 events: PhaseEvents, tlog_dir=None) -> None:
        self.plan, self.state, self.fleet, self.links, self.clock = plan, state, fleet, links, clock
        self.events, self.tlog_dir = events, tlog_dir
        self._plan_vehicles = {vp.sysid: vp for vp in plan.vehicles}

    async def run(self, required: bool = True) -> None:
        """Connect; MissionError naming every problem when ``required``, else each problem an error event."""
        self.events.set_phase("connect")
        by_uri: dict[str, list] = {}
        for vp in self.plan.vehicles:
            by_uri.setdefault(vp.connection, []).append(vp)
        problems: list[str] = []
        # one registry: a system id heard on two endpoints is an error naming both; one poller for
        # many UDP sockets (cheaper than one loop wake-up per datagram from a few tens of vehicles on)
        registry = SysidRegistry()
        n_udp = sum(1 for uri in by_uri if _is_udp(parse_connection, uri))
        if n_udp >= _POLLER_MIN_UDP_ENDPOINTS and self.links.poller is None:
            self.links.use_poller(UdpPoller())
        await asyncio.gather(*(self._open(uri, by_uri[uri], registry, problems) for uri in by_uri))
        await asyncio.gather(*(self._attach(vp, problems) for vp in self.plan.vehicles))
        dup = self._duplicate_uids()
        if dup:
            problems.append(dup)
        for sysid, v in self.fleet.vehicles.items():
            self.events.event(f"vehicle {sysid} ({self.fleet.ids[sysid]}): {v.flavour} on "
                              f"{self._plan_vehicles[sysid].connection}",
                              sysid=sysid, flavour=v.flavour, uid=v.uid)
        if problems and required:
            raise MissionError("connect failed: " + "; ".join(problems))
        for p in problems:
            self.events.event(p, level="error")

    async def _open(self, uri: str, vehicles: list, registry, problems: list[str]) -> None:
        """Open the endpoint of ``uri`` for ``vehicles`` (the only system ids it accepts); on failure
        every vehicle on it is not ready (``no link``)."""
        try:
            self.links.add_endpoint(uri, await MavEndpoint.open(uri, clock=self.clock, tlog_dir=self.tlog_dir,
                                                                signing=self.plan.security, registry=registry,
                                                                poller=self.links.poller,
                                                                planned_sysids=[vp.sysid for vp in vehicles]))
        except (OSError, ValueError) as exc:
            problems.append(f"{uri}: {exc}")
            for vp in vehicles:
                self.state.set_readiness(VehicleReadiness(vp.sysid, vp.id, uri, {"connected": False},
                                                          [f"cannot open {uri}: {exc}"]), "no link")

    async def _attach(self, vp, problems: list[str]) -> None:
        """Attach vehicle ``vp`` to its endpoint (heartbeat, autopilot version, telemetry rates)."""
        ep = self.links.endpoints.get(vp.connection)
        if ep is None:
            return
        try:
            v = await VehicleLink.create(ep, vp.sysid, clock=self.clock, mission_origin=self.plan.origin,
                                         heartbeat_timeout_s=self.plan.heartbeat_timeout_s)
        except Exception as exc:  # noqa: BLE001 - LinkError, timeouts: reported per vehicle
            problems.append(f"vehicle {vp.sysid} ({vp.id}) on {vp.connection}: {exc or type(exc).__name__}")
            self.state.set_readiness(VehicleReadiness(vp.sysid, vp.id, vp.connection, {"connected": False},
                                                      [f"no heartbeat: {exc or type(exc).__name__}"]), "no heartbeat")
            return
        self.fleet.add(v)
        self.state.set_status(vp.sysid, "connected")
        try:
            await v.request_autopilot_version()
        except Exception as exc:  # noqa: BLE001 - optional information
            self.events.event(f"vehicle {vp.sysid}: no AUTOPILOT_VERSION ({exc})", level="warning")
        try:  # only the telemetry the mission needs (CPU at N = 100+); refusals are not fatal
            refused = await v.set_message_rates(DEFAULT_RATES_HZ | extra_rates_hz(v.flavour)
                                                | wind_rates_hz(v.flavour), strict=False)
        except Exception as exc:  # noqa: BLE001 - the autopilot's default rates still work
            refused = {"*": str(exc)}
        if refused:
            self.events.event(f"vehicle {vp.sysid}: telemetry rates not all set ({refused})", level="warning")

    def _duplicate_uids(self) -> str | None:
        seen: dict[int, int] = {}
        for sysid, v in self.fleet.vehicles.items():
            uid = v.uid
            if not uid:
                continue
            if uid in seen:
                a, b = seen[uid], sysid
                return (f"vehicles {a} ({self._plan_vehicles[a].connection}) and {b} "
                        f"({self._plan_vehicles[b].connection}) report the same autopilot uid {uid:#x}: "
                        "one autopilot reached twice?")
            seen[uid] = sysid
        return None


#: from this many UDP endpoints on, one poller task reads them all
_POLLER_MIN_UDP_ENDPOINTS = 16


def _is_udp(parse_connection, uri: str) -> bool:
    try:
        return parse_connection(uri).kind.startswith("udp")
    except (ValueError, AttributeError):
        return False


# ---------------------------------------------------------------------------------- preflight
class Preflight:
    """The preflight phase: every connected vehicle checked; arms nothing.

    Heartbeat, position estimate, home, battery, armable, home in the fence, its
    ground-station-loss failsafe (:mod:`mission.flight.failsafe_params`), the autopilot's own
    pre-arm state (:mod:`mission.flight.readiness_autopilot`, waited for), then the mission-wide
    checks (:mod:`mission.flight.readiness_mission`; a missing reading fails the vehicle's
    readiness unless ``[preflight] require_readings = false``).

    Parameters
    ----------
    plan : Plan
        The fence, ``min_battery_pct``, ``[preflight]``, the origin.
    state : MissionState
        Each vehicle's readiness is recorded there.
    fleet : Fleet
    clock : Clock
    events : PhaseEvents
    mission_checks : callable
        ``mission_checks() -> MissionChecks``: the mission-wide checks over the readings now.
    simulated_fleet : bool
        The vehicles are the embedded mock fleet (:class:`mission.flight.coordinator.Coordinator`).
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, clock: Clock, events: PhaseEvents,
                 mission_checks: Callable[[], MissionChecks], simulated_fleet: bool = False) -> None:
        self.plan, self.state, self.fleet, self.clock, self.events = plan, state, fleet, clock, events
        self.mission_checks, self.simulated_fleet = mission_checks, simulated_fleet

    async def run(self, timeout_s: float = 30.0):
        """Check every vehicle; the plan's safety envelope (None: no fence), for the mission to use from now on."""
        self.events.set_phase("preflight")
        plan, state, vehicles = self.plan, self.state, self.fleet.vehicles
        envelope = None
        try:
            envelope = build_envelope(plan)
        except ValueError as exc:
            raise MissionError(f"preflight: the safety envelope cannot be built: {exc}") from None

        await asyncio.gather(*(self._check_vehicle(s, v, envelope, timeout_s) for s, v in vehicles.items()))

        await check_failsafe_params(state, vehicles, plan.preflight, self.simulated_fleet, self.events)
        await wait_autopilots_ready(state, vehicles, self.clock, self.events, plan.preflight.autopilot_ready_timeout_s)
        await self.mission_checks().check()
        for sysid in sorted(state.readiness):
            r = state.readiness[sysid]
            self.events.event(f"vehicle {sysid} ({r.id}): " + ("ready" if r.ready else "NOT READY: " + "; ".join(r.problems)),
                              level="info" if r.ready else "warning", sysid=sysid, checks=r.checks, warnings=r.warnings)
        return envelope

    async def _check_vehicle(self, sysid: int, v, envelope, timeout_s: float) -> None:
        """One vehicle's preflight checks; records its readiness and status."""
        clock = self.clock
        vp = next(p for p in self.plan.vehicles if p.sysid == sysid)
        r = VehicleReadiness(sysid, vp.id, vp.connection, flavour=v.flavour)
        r.checks["connected"] = True
        r.checks["heartbeat"] = v.link_age_s() < 3.0
        if not r.checks["heartbeat"]:
            r.problems.append(f"last heartbeat {v.link_age_s():.1f} s ago")
        deadline = clock.time() + timeout_s
        while not v.state.position_ok and clock.time() < deadline:
            await clock.sleep(0.2)
        r.checks["position"] = bool(v.state.position_ok)
        if not r.checks["position"]:
            r.problems.append(f"no position estimate after {timeout_s:.0f} s")
        try:
            home = await v.wait_home(max(1.0, deadline - clock.time()))
            r.checks["home"] = True
        except Exception as exc:  # noqa: BLE001 - timeout or link error
            home = None
            r.checks["home"] = False
            r.problems.append(f"no home position ({exc or 'timeout'})")
        await self._check_battery(sysid, v, r)
        waited_from = clock.time()
        reason = await wait_standby(v, clock, deadline)
        st = v.state.system_status
        r.checks["armable"] = (not v.state.armed) and st in (None, _MAV_STATE_STANDBY)
        if v.state.armed:
            r.problems.append("already armed (flying from an earlier mission? `swarmseek resume LOG` brings it home)")
        elif not r.checks["armable"]:
            r.problems.append(f"system status {st} (not STANDBY)" + (f"; {reason}" if reason else ""))
            self.events.event(f"vehicle {sysid}: system status {st} (not STANDBY) after "
                              f"{clock.time() - waited_from:.1f} s" + (f": {reason}" if reason else ""),
                              level="warning", sysid=sysid, reason=reason)
        if home is not None and envelope is not None:
            h = geodetic_to_enu(home[0], home[1], home[2], self.plan.origin)
            inside = bool(envelope.fence.contains(np.array([h[0], h[1], self.plan.geofence.min_alt_m + 0.01])))
            r.checks["home_in_fence"] = inside
            if not inside:
                r.problems.append(f"home ({h[0]:.1f}, {h[1]:.1f}) m is outside the geofence")
        self.state.set_readiness(r, "ready" if r.ready else "not ready: " + "; ".join(r.problems))

    async def _check_battery(self, sysid: int, v, r: VehicleReadiness) -> None:
        """The battery check (waited for up to 5 s; a vehicle that reports none is not checked)."""
        batt_deadline = self.clock.time() + 5.0
        while v.state.battery_remaining_pct is None and self.clock.time() < batt_deadline:
            await self.clock.sleep(0.2)
        batt, min_pct = v.state.battery_remaining_pct, self.plan.min_battery_pct
        r.checks["battery"] = batt is None or batt >= min_pct
        if batt is None:
            self.events.event(f"vehicle {sysid}: battery level not reported; not checked", level="warning")
        elif not r.checks["battery"]:
            r.problems.append(f"battery {batt:.0f} % below {min_pct:.0f} %")


def standby_refusal(v, now_s: float) -> str | None:
    """Why vehicle ``v``'s autopilot says it will not arm: its last pre-arm / arming refusal
    STATUSTEXT while recent, else its SYS_STATUS pre-arm check bit unhealthy; None when it says
    nothing."""
    status = v.prearm
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
