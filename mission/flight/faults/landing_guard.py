"""Never abandon an airborne vehicle: the invariant every mission path ends with.

Every vehicle this ground station engaged (took off, re-engaged at a resume, or lost on the way)
ends the mission

* **down**: disarmed (landed), or
* **landing**: armed under a landing behaviour of its autopilot, confirmed by its own heartbeat
  (RTL / SMART_RTL / LAND, PX4 ``AUTO.RTL`` / ``AUTO.LAND``: :data:`mission.flight.modes.LEFT_MODES`), or
* **reported**: still airborne (armed in another mode, or not heard any more while it was):
  the operator is told loudly (standard error, else standard output, and an ``airborne_left`` record in the mission log:
  which vehicles, where, in which mode, and what to do).

:meth:`LandingGuard.secure` runs at the end of :meth:`mission.flight.coordinator.Coordinator.run` on every
path (converged, aborted, exception, interrupted once or twice): a vehicle still armed and
flying in OFFBOARD/GUIDED or a hold mode is first commanded to LAND (released from the setpoint
stream so the watchdog does not re-engage it) and given ``confirm_timeout_s`` to report LAND.
:meth:`LandingGuard.land_now` is the emergency of a second interrupt: LAND for every airborne vehicle at
once, where it is (no return flight). See ``docs/faults.md``.
"""
from __future__ import annotations

import asyncio

import numpy as np

from mission.core.plan_types import FaultsPlan
from mission.flight.modes import LEFT_MODES
from mission.flight.services import Clock, Events, Fleet
from mission.flight.state import MissionState
from mission.safety.gate import SafetyGate
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import alert

__all__ = ["ADVICE", "DISARM_TIMEOUT_S", "DISARM_COMMAND_AFTER_S", "LandingGuard", "verdict"]

#: mission-clock seconds the end of a mission waits for the landed (or landing) vehicles to disarm, plus
#: the time the highest of them needs to descend at ``SLOWEST_LAND_SPEED_M_S``
DISARM_TIMEOUT_S = 15.0
#: the slowest landing descent of a supported autopilot (ArduPilot ``LAND_SPEED`` 50 cm/s; PX4
#: ``MPC_LAND_SPEED`` 0.7 m/s): a vehicle LANDed where it is, high up, is waited for to the ground
SLOWEST_LAND_SPEED_M_S = 0.5
#: a vehicle its autopilot reports on the ground (``MAV_LANDED_STATE_ON_GROUND``) but still armed this
#: long is sent a disarm command (PX4 ``COM_DISARM_LAND`` is 2 s by default, ArduPilot disarms on touchdown)
DISARM_COMMAND_AFTER_S = 4.0

#: what the operator should do about a vehicle left airborne
ADVICE = ("take manual control (RC) or command LAND/RTL from another ground station "
          "(QGroundControl, MAVProxy), or run `swarmseek resume LOG` to bring them home")


def verdict(v, link_timeout_s: float) -> tuple[str, str]:
    """``(kind, detail)`` of a vehicle now: ``down``, ``landing``, ``airborne`` or ``unheard``.

    ``unheard``: no frame for ``link_timeout_s`` while its last known state was armed and not
    under a landing mode (its last state is in ``detail``).
    """
    if v is None:
        return "unheard", "not connected to this ground station: its state is unknown"
    st = v.state
    age = float(v.link_age_s())
    landing_mode = st.mode in LEFT_MODES.get(v.flavour, ())
    if not st.armed:
        return "down", "disarmed" + (f" (last heard {age:.1f} s ago)" if age > link_timeout_s else "")
    if landing_mode and st.landed is True:
        return "down", f"landed under {st.mode}, disarming"
    if landing_mode:
        return "landing", f"under {st.mode}" + (f" (last heard {age:.1f} s ago)" if age > link_timeout_s else "")
    if age > link_timeout_s:
        return "unheard", f"not heard for {age:.1f} s; last seen armed in {st.mode}"
    return "airborne", f"armed in {st.mode}"


class LandingGuard:
    """The never-abandon check at the end of every mission path, and the emergency LAND.

    Parameters
    ----------
    state : MissionState
        Who is airborne, released, lost, commanded to LAND; where the verdicts go.
    fleet : Fleet
        The connected vehicles (their heartbeats, commands and positions).
    gate : SafetyGate or None
        The safety gate a vehicle commanded to LAND is taken off (None: no setpoints were streamed).
    clock : Clock
        The mission clock.
    faults : FaultsPlan
        The plan's ``[faults]`` (``link_timeout_s``: when a vehicle counts as unheard).
    log : MissionLog or None
        Where the ``airborne_left`` and ``still_armed`` records go.
    events : Events
        Events told to the operator.
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate | None, clock: Clock,
                 faults: FaultsPlan, log: MissionLog | None, events: Events) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.faults, self.log, self.events = faults, log, events

    def engaged_vehicles(self) -> list[int]:
        """Vehicles this ground station engaged: airborne, released (landing / RTL) or lost."""
        return sorted(set(self.state.airborne) | set(self.state.released) | set(self.state.lost))

    def _where(self, sysid: int, v) -> dict:
        """Where a vehicle is (or was last heard): mission ENU, latitude, longitude, altitude."""
        out: dict = {"sysid": sysid, "id": self.fleet.ids.get(sysid)}
        if v is None:
            return out
        st = v.state
        pos = self.fleet.telemetry_position(sysid)
        out.update(mode=st.mode, armed=bool(st.armed), last_heard_s_ago=round(float(v.link_age_s()), 1),
                   position_enu=None if pos is None else [round(float(x), 2) for x in np.asarray(pos, float)],
                   lat_deg=st.lat_deg, lon_deg=st.lon_deg, alt_amsl_m=st.alt_m, relative_alt_m=st.relative_alt_m)
        return out

    def report_airborne(self, entries: list[dict], why: str) -> None:
        """Tell the operator loudly: standard error, an ``airborne_left`` log record, an error event."""
        who = [e["sysid"] for e in entries]
        lines = [f"swarmseek: WARNING: vehicles {who} are still AIRBORNE and no ground station flies them ({why}):"]
        for e in entries:
            lat, lon, alt = e.get("lat_deg"), e.get("lon_deg"), e.get("alt_amsl_m")
            where = (f"lat {lat:.7f} lon {lon:.7f} alt {alt:.1f} m AMSL" if None not in (lat, lon, alt)
                     else "position unknown")
            lines.append(f"  vehicle {e['sysid']} ({e.get('id')}): {e.get('state', '')}; {where}; "
                         f"ENU {e.get('position_enu')}")
        lines.append(f"  what to do: {ADVICE}")
        alert("\n".join(lines))  # standard error, else standard output (mission.telemetry.terminal)
        if self.log is not None:
            self.log.write("airborne_left", sync=True, vehicles=entries, reason=why, advice=ADVICE)
        self.events.event(f"vehicles {who} left AIRBORNE: {why}; {ADVICE}", level="error", sysids=who)

    def report_still_armed(self, entries: list[dict], why: str) -> None:
        """Tell the operator loudly which vehicles are still armed at the end (landed or landing):
        standard error, a ``still_armed`` log record, an error event."""
        who = [e["sysid"] for e in entries]
        lines = [f"swarmseek: WARNING: vehicles {who} are still ARMED at the end of the mission ({why}):"]
        lines += [f"  vehicle {e['sysid']} ({e.get('id')}): {e.get('state', '')}; ENU {e.get('position_enu')}"
                  for e in entries]
        lines.append("  what to do: keep clear of the propellers; disarm them (RC kill switch, or DISARM from "
                     "QGroundControl / MAVProxy) before approaching")
        alert("\n".join(lines))  # standard error, else standard output (mission.telemetry.terminal)
        if self.log is not None:
            self.log.write("still_armed", sync=True, vehicles=entries, reason=why)
        self.events.event(f"vehicles {who} still ARMED at the end of the mission: {why}", level="error", sysids=who)

    async def _send_disarm(self, sysid: int, v, timeout_s: float = 5.0) -> None:
        """A (non-forced) disarm command to a vehicle its autopilot reports on the ground; failures are events."""
        self.events.event(f"vehicle {sysid} is on the ground but still armed: sending DISARM", level="warning", sysid=sysid)
        try:
            await asyncio.wait_for(v.disarm(), timeout=timeout_s)
        except (asyncio.TimeoutError, OSError, RuntimeError, ValueError) as exc:
            self.events.event(f"vehicle {sysid}: DISARM failed: {type(exc).__name__}: {exc}", level="error", sysid=sysid)

    async def await_disarm(self, timeout_s: float = DISARM_TIMEOUT_S,
                           command_after_s: float = DISARM_COMMAND_AFTER_S) -> list[dict]:
        """Wait until every engaged vehicle that is down or landing has disarmed; the ones still armed.

        A vehicle its autopilot reports on the ground (landed state) but still armed for
        ``command_after_s`` (its own auto-disarm did not come) is sent one disarm command. Vehicles
        left airborne or unheard are not waited for (:meth:`secure` reports them). Returns the
        ``still_armed`` entries (where, mode, state) after ``timeout_s`` of mission clock plus the
        time the highest of them needs to descend at ``SLOWEST_LAND_SPEED_M_S`` (a vehicle LANDed where
        it is, 12 m up, is waited for to the ground: 24 s more).
        """
        link_timeout = self.faults.link_timeout_s

        def _armed() -> list[int]:
            return [e["sysid"] for e in self.still_armed(link_timeout)]

        grounded: dict[int, float] = {}
        sent: set[int] = set()
        heights_m = [self.fleet.vehicles[s].state.relative_alt_m for s in _armed()]
        descent_s = max([h / SLOWEST_LAND_SPEED_M_S for h in heights_m if h is not None and h > 0], default=0.0)
        deadline = self.clock.time() + timeout_s + descent_s
        while (armed := _armed()) and self.clock.time() < deadline:
            now = self.clock.time()
            for s in armed:
                if self.fleet.vehicles[s].state.landed is True:
                    grounded.setdefault(s, now)
                else:
                    grounded.pop(s, None)
            due = [s for s in armed if s not in sent and s in grounded and now - grounded[s] >= command_after_s]
            sent.update(due)
            await asyncio.gather(*(self._send_disarm(s, self.fleet.vehicles[s]) for s in due))
            await self.clock.sleep(0.2)
        return self.still_armed(link_timeout)

    def still_armed(self, link_timeout_s: float) -> list[dict]:
        """Engaged vehicles heard armed while down or landing (not airborne, not unheard): where, and why."""
        out = []
        for s in self.engaged_vehicles():
            v = self.fleet.vehicles.get(s)
            if v is None or not v.state.armed:
                continue
            kind, detail = verdict(v, link_timeout_s)
            if kind in ("down", "landing"):
                out.append(self._where(s, v) | {"state": detail})
        return out

    async def _command_land(self, sysid: int, v, timeout_s: float) -> str | None:
        """Release ``sysid`` from the stream and command LAND; the error text, or None."""
        self.state.release(sysid, "landing (end of mission)")
        if self.gate is not None and sysid in self.gate.sysids:
            self.gate.remove(sysid)
        try:
            await asyncio.wait_for(v.land(), timeout=timeout_s)
        except (asyncio.TimeoutError, OSError, RuntimeError, ValueError) as exc:
            return f"{type(exc).__name__}: {exc}"
        return None

    async def land_now(self, timeout_s: float = 5.0) -> list[int]:
        """Emergency LAND of every engaged vehicle still armed outside a landing mode, all at once.

        Returns the vehicles commanded. No return flight, no stagger: each descends where it is.
        """
        timeout = self.faults.link_timeout_s
        done = self.state.land_commanded  # LAND accepted here: not sent twice
        todo = [s for s in self.engaged_vehicles()
                if s not in done and verdict(self.fleet.vehicles.get(s), timeout)[0] == "airborne"]
        if not todo:
            return []
        self.events.event(f"LANDING vehicles {todo} where they are, now", level="error", sysids=todo)
        errors = await asyncio.gather(*(self._command_land(s, self.fleet.vehicles[s], timeout_s) for s in todo))
        for s, err in zip(todo, errors):
            if err is not None:
                self.events.event(f"vehicle {s}: LAND command failed: {err}", level="error", sysid=s)
            else:
                self.state.mark_land_commanded(s)
        return todo

    async def secure(self, why: str, confirm_timeout_s: float = 5.0,
                     land: bool = True) -> tuple[list[dict], bool]:
        """Enforce the invariant at the end of a mission.

        Returns the ``airborne_left`` entries (empty: none left airborne) and whether a
        cancellation cut the wait short (it is handled here: the caller decides what follows). The
        vehicles still armed though down or landing, after :meth:`await_disarm`, are reported
        (:meth:`report_still_armed`) and kept in ``self.state.still_armed`` (the summary's ``still_armed``).

        Parameters
        ----------
        why : str
            How the mission ended (in the report).
        confirm_timeout_s : float
            Mission-clock seconds a vehicle commanded to LAND here has to report LAND.
        land : bool
            Command LAND to the vehicles still flying (False: a ground station told to just stop,
            ``Coordinator.return_on_interrupt = False``: they are only reported).

        A cancellation (the operator insists) stops the wait: what is not confirmed by then is
        reported.
        """
        timeout = self.faults.link_timeout_s
        cancelled = False
        try:
            if land:
                await self.land_now(confirm_timeout_s)
            commanded = self.state.land_commanded  # here or by an earlier land_now
            deadline = self.clock.time() + confirm_timeout_s
            while self.clock.time() < deadline and any(
                    verdict(self.fleet.vehicles.get(s), timeout)[0] == "airborne" for s in commanded):
                await self.clock.sleep(0.2)
            if land:
                await self.await_disarm()
        except asyncio.CancelledError:
            cancelled = True
            task = asyncio.current_task()
            if task is not None and task.cancelling():
                task.uncancel()
        entries = []
        for s in self.engaged_vehicles():
            v = self.fleet.vehicles.get(s)
            kind, detail = verdict(v, timeout)
            if kind in ("airborne", "unheard"):
                entries.append(self._where(s, v) | {"state": detail})
            elif kind == "landing":
                self.events.event(f"vehicle {s} ends the mission {detail}, confirmed by its autopilot", sysid=s)
            else:
                self.state.set_landed(s)  # down (a no-op if already said): the log says it landed
        if entries:
            self.report_airborne(entries, why)
        armed = self.still_armed(timeout)
        if armed:
            self.report_still_armed(armed, why)
        self.state.set_still_armed(armed)
        return entries, cancelled
