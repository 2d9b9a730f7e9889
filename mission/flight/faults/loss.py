"""Vehicle loss: detection, the re-formed formation for the survivors, and returning vehicles.

Rules (see ``docs/faults.md``):

* **link lost**: no MAVLink message from the vehicle for ``[faults] link_timeout_s`` (1 s) of
  the mission clock (crash, link cut, vehicle switched off). Checked every 0.1 s of the mission
  clock, hence detected within 1.1 s of the last frame heard.
* **left the mission**: the autopilot switched, without being asked, to a mode that ends its
  part in the mission: RTL or LAND (PX4 ``AUTO.RTL`` / ``AUTO.LAND``, ArduPilot ``RTL``,
  ``SMART_RTL``, ``LAND``): a failsafe (low battery, geofence, GCS loss) or a pilot; or to any
  other mode with its heartbeat saying it is in a failsafe of its own (``system_status``
  CRITICAL/EMERGENCY), a mode its offboard loss would not give (or, that mode unknown, while the
  ground station's setpoints to it never paused), or after its autopilot announced a hold before a
  failsafe action or named the failsafe's cause in a STATUSTEXT (:func:`autopilot_failsafe`,
  :func:`announced_failsafe`: PX4's hold before its battery, geofence or data-link action, its
  geofence, battery or data-link words). The coordinator does not
  fight it. Any *other* mode change (PX4 offboard loss -> its offboard-loss mode,
  ArduPilot GUIDED -> LOITER/BRAKE without a failsafe) is re-engaged by the watchdog
  (:mod:`mission.flight.faults.watchdog`). A vehicle
  that disarms in the air (not commanded) also left. Without signing a heartbeat proves nothing,
  so a mode change or a disarm counts only when corroborated by the vehicle's own stream: two
  heartbeats in a row (the endpoint delivers only those from the vehicle's pinned address) say
  so; after the first one the coordinator asks for an immediate HEARTBEAT
  (``VehicleLink.request_heartbeat``), so a real failsafe is confirmed within a round trip.
* :class:`LossMonitor` detects. A lost vehicle is taken off the setpoint stream, released (never re-engaged) and no longer
  waited for (one still armed in OFFBOARD/GUIDED with its link alive is commanded to land or
  RTL, the plan's ``return``: never left hovering under its last setpoint); the seek loop re-forms the formation for the survivors (:class:`Reformation`, :func:`reformed_offsets`)
  and flies a separation-keeping transfer (:func:`mission.safety.envelope.plan_transfer`) to it.
* **coming back** (link heard again after a link loss): with ``[faults] readmit = false`` the
  vehicle is kept out and commanded to land or RTL (the plan's ``return``), once; with
  ``readmit = true`` and during the seek, armed, airborne and not in RTL/LAND, it is re-admitted
  at the start of the next iteration (:meth:`mission.flight.faults.rejoin.Rejoin.readmit`).
* A lost vehicle that still flies is an obstacle for the re-formed slots and the transfers
  (:mod:`mission.flight.faults.rejoin`).
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

from formation.assignment import assign_slots, reconfigure
from formation.symmetric import symmetric_cylinder

from typing import Callable

from mission.core.plan_types import FaultsPlan, FormationPlan
from mission.core.tasks import spawn
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.obstacles import OBSTACLE_MARGIN_M, clear_offsets, obstacles
from mission.flight.services import Clock, Events, Fleet, Motion
from mission.flight.state import MissionState, VehicleLoss
from mission.safety.gate import SafetyGate
from mission.vehicle.vehicle_link import VehicleLink

__all__ = ["CORROBORATING_HEARTBEATS", "DATA_LINK_LOST_TEXT", "FAILSAFE_STATES", "OWN_PAUSE_S", "PX4_FAILSAFE_TEXTS",
           "LossMonitor", "Reformation", "announced_failsafe", "autopilot_failsafe", "classify_loss", "data_link_acts",
           "offboard_loss_mode", "own_stream_gap_s", "reformed_offsets"]

#: heartbeats in a row that must report a mode change or a disarm before the vehicle "left"
CORROBORATING_HEARTBEATS = 2

#: a RTL/LAND mode reported since before the mission engaged the vehicle (ArduPilot stays in RTL
#: after an RTL landing) is no mode change; it counts only if it lasts this long after engagement
STALE_MODE_GRACE_S = 3.0


#: HEARTBEAT ``system_status`` of an armed autopilot acting on a failsafe of its own: MAV_STATE_CRITICAL
#: (PX4 while ``vehicle_status.failsafe``: offboard loss, geofence, battery, data link; ArduPilot
#: while a failsafe is on) and MAV_STATE_EMERGENCY
FAILSAFE_STATES = frozenset({5, 6})
_STATE_NAMES = {5: "CRITICAL", 6: "EMERGENCY"}

#: a pause of the ground station's own setpoint stream at least this long (mission clock) may have
#: caused an offboard-loss failsafe itself (PX4 ``COM_OF_LOSS_T``, 1 s by default, counts on the
#: vehicle, where a pause arrives stretched by the link): such a hold is re-engaged, not "left"
OWN_PAUSE_S = 0.5

#: how far before the mode change was first heard the stream is searched for such a pause
_PAUSE_LOOKBACK_S = 3.0


#: how real PX4 v1.16's STATUSTEXTs begin that announce a failsafe of its own
#: (strings of the SIH build, heard by ``tests/conformance/test_conformance_px4_hold_failsafes.py``):
#: ``FailsafeBase::notifyUser``'s hold before a Return / Land action ("Failsafe activated: entering
#: Hold for %i seconds"); the geofence check ("Geofence: exceeding maximum altitude above Home",
#: "... distance to Home", "Geofence: approaching or outside geofence", just before "Failsafe
#: activated" even when the action is Hold itself, ``GF_ACTION`` 2); the battery check at the levels
#: that act ("Critical battery", "Emergency battery level"; "Low battery" only warns); the commander's
#: data-link check ("Connection to ground station lost", :data:`DATA_LINK_LOST_TEXT`). The offboard
#: loss says only "Failsafe activated": none of these.
PX4_FAILSAFE_TEXTS = ("Failsafe activated: entering Hold", "Geofence: ", "Critical battery", "Emergency battery level",
                      "Dangerously low battery", "Connection to ground station lost")

#: the data-link check's words: a cause only when its action (``NAV_DLL_ACT``) is not 0 (disabled)
DATA_LINK_LOST_TEXT = "Connection to ground station lost"


#: the mode real PX4 shows after its offboard loss, by ``COM_OBL_RC_ACT`` (0: position mode, measured
#: on PX4 v1.16 SIH without RC; 5: Hold); 6 (terminate) has none
_PX4_OFFBOARD_LOSS_MODES = {0: "POSCTL", 1: "ALTCTL", 2: "MANUAL", 3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LOITER"}


def offboard_loss_mode(state: MissionState, sysid: int, flavour: str) -> str | None:
    """The mode ``sysid``'s autopilot takes on losing the mission's setpoints, from the failsafe
    parameters the preflight read (PX4 ``COM_OBL_RC_ACT``); None when unknown (not read, or not PX4)."""
    r = state.readiness.get(sysid)
    value = None if r is None or flavour != "px4" else r.failsafe_params.get("COM_OBL_RC_ACT")
    return None if value is None else _PX4_OFFBOARD_LOSS_MODES.get(int(value))


def own_stream_gap_s(gate: SafetyGate | None, sysid: int, vehicle: VehicleLink) -> float | None:
    """The longest pause of the setpoints sent to ``sysid`` from :data:`_PAUSE_LOOKBACK_S` before its
    current mode was first reported until now (None: unknown, e.g. not under the gate)."""
    since = vehicle.status_since_s
    if gate is None or since is None:
        return None
    return gate.stream_gap_s(sysid, float(since) - _PAUSE_LOOKBACK_S)


def data_link_acts(state: MissionState, sysid: int, flavour: str) -> bool:
    """Whether ``sysid``'s PX4 acts on a data-link loss: False only when the preflight read
    ``NAV_DLL_ACT`` 0 (disabled); True when unknown (not read, a ``resume``), or not PX4."""
    r = state.readiness.get(sysid)
    value = None if r is None or flavour != "px4" else r.failsafe_params.get("NAV_DLL_ACT")
    return value is None or int(value) != 0


def announced_failsafe(vehicle: VehicleLink, data_link_acts: bool = True) -> str | None:
    """The STATUSTEXT by which ``vehicle``'s PX4 announced a failsafe of its own
    (:data:`PX4_FAILSAFE_TEXTS`; :data:`DATA_LINK_LOST_TEXT` only if ``data_link_acts``), heard from
    :data:`_PAUSE_LOOKBACK_S` before its current mode was first reported until now; None if none
    (or not PX4). PX4 holds its STATUSTEXTs back while it hears no ground station (measured on SIH:
    the data-link loss's words came only with the first GCS heartbeat back), so they may arrive
    seconds after the mode they explain."""
    since = vehicle.status_since_s
    if since is None or vehicle.flavour != "px4":
        return None
    for t_s, _severity, text in reversed(vehicle.statustexts):
        if t_s < float(since) - _PAUSE_LOOKBACK_S:
            return None  # in arrival order: older ones do not count
        said = text.strip()
        if said.startswith(DATA_LINK_LOST_TEXT) and not data_link_acts:
            continue
        if said.startswith(PX4_FAILSAFE_TEXTS):
            return said
    return None


def autopilot_failsafe(vehicle: VehicleLink, stream_gap_s: float | None, loss_mode: str | None = None,
                       data_link_acts: bool = True) -> str | None:
    """Why ``vehicle`` is under its autopilot's own failsafe, one the ground station did not cause;
    None if it is not (or that cannot be told).

    Armed, out of the mission's mode (and not RTL/LAND, which "left" anyway), with a HEARTBEAT
    ``system_status`` in :data:`FAILSAFE_STATES`, and either in another mode than its offboard loss
    gives (``loss_mode``, :func:`offboard_loss_mode`: e.g. AUTO.LOITER, PX4's hold for
    ``COM_FAIL_ACT_T`` before its battery or geofence action, while ``COM_OBL_RC_ACT`` 0 gives
    POSCTL), or, when that mode is unknown, while the setpoints to it never paused for
    :data:`OWN_PAUSE_S` (``stream_gap_s``, :func:`own_stream_gap_s`), or, whatever its mode, after
    its PX4 named a failsafe of its own (:func:`announced_failsafe`, ``data_link_acts`` passed on: with
    ``COM_OBL_RC_ACT`` 5 the offboard loss, a geofence hold (``GF_ACTION`` 2) and the hold before a
    geofence, battery or data-link action are all AUTO.LOITER; only the words tell them apart). Such a vehicle is handed to its
    autopilot: never re-engaged (:mod:`mission.flight.faults.watchdog`), declared "left". In its
    offboard-loss mode it is taken for an offboard loss (its cause, missing setpoints, is gone
    once they arrive again: re-engaged), whatever the stream did: an uplink lost for a while
    (our sends steady) is one too.
    """
    want = GUIDED_MODES.get(vehicle.flavour)
    mode = vehicle.state.mode
    if want is None or mode == want or mode in LEFT_MODES.get(vehicle.flavour, ()) or not vehicle.state.armed:
        return None
    status = vehicle.state.system_status
    if status not in FAILSAFE_STATES:
        return None
    why = f"switched to {mode} in its own failsafe (system status {_STATE_NAMES[status]}; "
    said = announced_failsafe(vehicle, data_link_acts)
    if said is not None:
        return why + f"it said {said!r})"
    if loss_mode is not None:
        return why + f"not {loss_mode}, its offboard-loss mode)" if mode != loss_mode else None
    if stream_gap_s is None or stream_gap_s >= OWN_PAUSE_S:
        return None
    return why + f"setpoints steady, longest pause {stream_gap_s:.2f} s)"


def classify_loss(vehicle, now_s: float, link_timeout_s: float, commanded: bool,
                  seen_armed: bool = True, engaged_s: float | None = None,
                  stream_gap_s: float | None = None, loss_mode: str | None = None,
                  data_link_acts: bool = True) -> tuple[str, str] | None:
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
    engaged_s : float, optional
        Mission clock when the mission engaged the vehicle (its takeoff or re-engagement
        commanded). A RTL/LAND mode reported by heartbeats that began before it is what the
        vehicle was doing on the ground (ArduPilot stays in RTL after an RTL landing), not a
        mode change: it counts only once it outlasts :data:`STALE_MODE_GRACE_S` after ``engaged_s``
        (the vehicle did not take the mission's mode).
    stream_gap_s : float, optional
        The longest pause of the ground station's setpoints to it around its mode change
        (:func:`own_stream_gap_s`): with it, a vehicle under its autopilot's own failsafe in another
        mode (:func:`autopilot_failsafe`, e.g. PX4's geofence hold) also "left".
    loss_mode : str, optional
        The mode its offboard loss would give (:func:`offboard_loss_mode`), for the same rule.
    data_link_acts : bool
        Its data-link-loss failsafe acts (:func:`data_link_acts`): PX4's words of a data-link loss
        name a failsafe of its own (:func:`announced_failsafe`).

    Returns
    -------
    tuple of str or None
        ``("link", detail)``, ``("left", detail)``, or ``("unconfirmed", detail)`` when the
        mode or disarm that would make it "left" was reported by fewer than
        :data:`CORROBORATING_HEARTBEATS` heartbeats in a row (``vehicle.status_heartbeats``;
        vehicles without it count as corroborated): not a loss yet.
    """
    age = float(vehicle.link_age_s())
    if age > link_timeout_s:
        return "link", f"no MAVLink frame for {age:.2f} s"
    if commanded:
        return None
    mode = vehicle.state.mode
    if mode in LEFT_MODES.get(vehicle.flavour, ()):
        since = vehicle.status_since_s
        if engaged_s is not None and since is not None and since < engaged_s:
            if now_s - engaged_s < STALE_MODE_GRACE_S:
                return None  # still reporting the mode it had before the takeoff: not a change
            detail = f"still in {mode} {now_s - engaged_s:.1f} s after the mission engaged it"
        else:
            detail = f"switched to {mode} by itself (failsafe)"
    elif seen_armed and not vehicle.state.armed:
        detail = "disarmed in the air"
    elif (own := autopilot_failsafe(vehicle, stream_gap_s, loss_mode, data_link_acts)) is not None:
        detail = own
    else:
        return None
    if vehicle.status_heartbeats < CORROBORATING_HEARTBEATS:
        return "unconfirmed", detail
    return "left", detail


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
    sysids = sorted(offsets)
    lost = set(lost)
    survivors = [s for s in sysids if s not in lost]
    if len(survivors) < 4:
        raise ValueError(f"a formation needs at least 4 vehicles, {len(survivors)} left")
    x = np.array([offsets[s] for s in sysids], dtype=float)
    if kind == "symmetric" and len(survivors) % 2 == 0:
        slots = np.asarray(symmetric_cylinder(len(survivors), radius_m), dtype=float)
        xs = x[[sysids.index(s) for s in survivors]]
        perm, _ = assign_slots(xs, slots, allow_rotation=False)
        return {s: slots[perm[k]] for k, s in enumerate(survivors)}, "symmetric"
    mask = np.array([s in lost for s in sysids])
    rec = reconfigure(x, mask, radius_m)
    out = {}
    for k, idx in enumerate(rec.survivors):
        out[sysids[int(idx)]] = np.asarray(rec.slots[int(rec.assignment[k])], dtype=float)
    return out, "cvt"


class LossMonitor:
    """Detects lost vehicles every ``period_s`` of the mission clock (a task the coordinator runs).

    Parameters
    ----------
    state : MissionState
        The phase, who is airborne, released, lost; where a loss is declared.
    fleet : Fleet
        The connected vehicles.
    gate : callable
        ``gate()``: the safety gate now (None before the setpoints stream); a lost vehicle is
        taken off it. The monitor runs from before the connection to the end.
    clock : Clock
        The mission clock.
    faults : FaultsPlan
        ``link_timeout_s``, ``readmit``.
    return_behaviour : {"land", "rtl"}
        The plan's ``return``: what a released vehicle still in OFFBOARD/GUIDED is commanded.
    motion : Motion
        ``keep_out`` for a vehicle heard again that is not re-admitted.
    events : Events
        Each loss, release and return is told as an event.
    report : callable
        ``report(message)``: a failed background command (:func:`mission.core.tasks.spawn`).
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: Callable[[], SafetyGate | None], clock: Clock,
                 faults: FaultsPlan, return_behaviour: str, motion: Motion, events: Events,
                 report: Callable[[str], None]) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.faults, self.rtl = faults, return_behaviour == "rtl"
        self.motion, self.events, self.report = motion, events, report

    async def run(self, period_s: float = 0.1) -> None:
        """Watch until cancelled.

        Only vehicles under the mission's setpoints, or airborne and not yet released, are watched,
        from the takeoff on. A detection logs a ``vehicle lost`` event with its latency, takes the
        vehicle off the stream and marks it lost in the mission state; the seek loop re-forms.
        """
        seen_armed: set[int] = set()
        engaged_s: dict[int, float] = {}  # when the watch of each vehicle began (its takeoff commanded)
        while True:
            t_before = self.clock.time()
            await self.clock.sleep(period_s)
            if self.state.phase not in ("takeoff", "assemble", "seek", "finish", "return"):
                continue
            if self.clock.time() - t_before > period_s + 0.5 * self.faults.link_timeout_s:
                # this task woke up late: the event loop was busy and frames may be waiting in the
                # sockets; a silence measured now could be the loop's, not the vehicles'
                await asyncio.sleep(0)
                continue
            now = self.clock.time()
            gate = self.gate()
            watched = self.state.airborne | set(self.state.lost) | set(gate.sysids if gate is not None else ())
            for sysid in sorted(watched):
                v = self.fleet.vehicles.get(sysid)
                if v is None:
                    continue
                loss = self.state.lost.get(sysid)
                if loss is not None:
                    await self._maybe_came_back(v, loss, now)
                    continue
                if sysid in self.state.released:
                    continue  # commanded by the coordinator to land / RTL
                if v.state.armed:
                    seen_armed.add(sysid)
                loss = await self._check(sysid, v, sysid in seen_armed, engaged_s.setdefault(sysid, now))
                if loss is not None:
                    self._declare_lost(loss)

    async def _check(self, sysid: int, v, seen_armed: bool, engaged_s: float) -> VehicleLoss | None:
        """The loss of ``v`` found now, or None (an unconfirmed "left" asks the vehicle to confirm)."""
        timeout_s = self.faults.link_timeout_s
        now = self.clock.time()
        gap, loss_mode = own_stream_gap_s(self.gate(), sysid, v), offboard_loss_mode(self.state, sysid, v.flavour)
        dll = data_link_acts(self.state, sysid, v.flavour)
        found = classify_loss(v, now, timeout_s, commanded=False, seen_armed=seen_armed, engaged_s=engaged_s,
                              stream_gap_s=gap, loss_mode=loss_mode, data_link_acts=dll)
        if found is not None and found[0] == "link":
            # let the event loop read whatever is pending before concluding
            await asyncio.sleep(0)
            await asyncio.sleep(0)
            now = self.clock.time()
            found = classify_loss(v, now, timeout_s, commanded=False, seen_armed=seen_armed, engaged_s=engaged_s,
                                  stream_gap_s=gap, loss_mode=loss_mode, data_link_acts=dll)
        if found is None:
            return None
        reason, detail = found
        if reason == "unconfirmed":  # one heartbeat said so: ask the vehicle itself, decide on its answer
            v.request_heartbeat()
            return None
        if reason == "link":
            since = now - float(v.link_age_s())
        else:  # the first of the heartbeats that reported it
            hb = v.status_since_s or v.state.last_heartbeat_s
            since = now if hb is None else min(now, float(hb))
        return VehicleLoss(sysid, reason, detail, now, since, self.state.phase)

    def _declare_lost(self, loss: VehicleLoss) -> None:
        sysid = loss.sysid
        gate = self.gate()
        if gate is not None and sysid in gate.sysids:
            loss.last_setpoint_enu = gate.setpoint(sysid)
            gate.remove(sysid)
        self.state.declare_lost(loss, f"lost ({loss.reason}: {loss.detail})")
        self.events.event(f"vehicle {sysid} lost: {loss.detail}; detected {loss.latency_s:.2f} s after its last sign "
                          f"(phase {loss.phase})", level="warning", sysid=sysid, reason=loss.reason,
                          latency_s=round(loss.latency_s, 3), detected_s=loss.detected_s, since_s=loss.since_s)
        v = self.fleet.vehicles.get(sysid)
        if v is not None and loss.reason == "left" and v.state.armed and v.state.mode == GUIDED_MODES.get(v.flavour):
            spawn(self._settle_released(sysid, v), f"settling released vehicle {sysid}", self.report)

    async def _settle_released(self, sysid: int, v) -> None:
        """A vehicle released while still armed in OFFBOARD/GUIDED is told to land (or RTL), once:
        off the stream it would hover at its last setpoint (ArduPilot GUIDED has no setpoint timeout)."""
        what = "RTL" if self.rtl else "land"
        self.events.event(f"vehicle {sysid} released while still in {v.state.mode}: commanded to {what}",
                          level="warning", sysid=sysid)
        try:
            await asyncio.wait_for(v.rtl() if self.rtl else v.land(), timeout=30.0)
        except Exception as exc:  # noqa: BLE001 - CommandError, link, timeout: reported
            self.events.event(f"vehicle {sysid}: {what} after its release failed: {exc}", level="error", sysid=sysid)

    async def _maybe_came_back(self, v, loss: VehicleLoss, now: float) -> None:
        """A vehicle lost by its link and heard again is judged (re-admitted or kept out) once a
        HEARTBEAT came after the loss: its first frames back may be positions while its mode and
        armed state are still the ones from before the loss (ArduCopter SITL, in LAND by itself, was
        first called re-admissible in GUIDED; real PX4 SIH, disarmed on the ground after its
        offboard-loss descent, was judged "OFFBOARD, armed" and commanded to land). One whose PX4
        named a failsafe of its own (:func:`announced_failsafe`: e.g. its hold before the data-link
        loss's Return, said once it heard the ground station again) is not re-admitted."""
        if loss.reason != "link" or loss.came_back_s is not None or v.link_age_s() > 0.5:
            return
        heartbeat_s = v.state.last_heartbeat_s
        if heartbeat_s is None or heartbeat_s <= loss.detected_s:
            return
        state = self.state
        alt = v.state.relative_alt_m
        said = announced_failsafe(v, data_link_acts(state, loss.sysid, v.flavour))
        readmissible = (self.faults.readmit and state.phase == "seek" and v.state.armed and said is None
                        and (alt is None or alt >= 1.0) and v.state.mode not in LEFT_MODES.get(v.flavour, ()))
        state.came_back(loss.sysid, now, readmit=readmissible)
        if readmissible:
            self.events.event(f"vehicle {loss.sysid} is heard again after its link loss; re-admitted at the next "
                              "iteration (faults.readmit = true)", level="warning", sysid=loss.sysid)
            return
        if self.faults.readmit:
            why = (f"faults.readmit = true, but not re-admissible (phase {state.phase}, mode {v.state.mode}, "
                   f"{'armed' if v.state.armed else 'disarmed'}"
                   f"{'' if alt is None else f', {alt:.1f} m above home'}"
                   f"{'' if said is None else f'; in its own failsafe: it said {said!r}'})")
        else:
            why = "faults.readmit = false"
        await self.motion.keep_out(loss.sysid, v, why)


class Reformation:
    """The formation re-formed for the vehicles left (after a loss, a retired sensor).

    Parameters
    ----------
    state : MissionState
        Who is lost, the slots and the formation type (changed here).
    fleet : Fleet
        The connected vehicles (lost vehicles still flying are obstacles).
    gate : SafetyGate
        Who is under setpoints.
    clock : Clock
        The mission clock.
    formation : FormationPlan
        ``radius_m``, ``seed`` of a fresh symmetric formation.
    min_separation_m : float
        The plan's separation (plus :data:`~mission.flight.obstacles.OBSTACLE_MARGIN_M` from obstacles).
    motion : Motion
        ``transfer_to``: the separation-keeping transfer to the new slots.
    events : Events
        A switch of formation type and a rotation clear of obstacles are told.
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: SafetyGate, clock: Clock, formation: FormationPlan,
                 min_separation_m: float, motion: Motion, events: Events) -> None:
        self.state, self.fleet, self.gate, self.clock = state, fleet, gate, clock
        self.formation, self.min_separation_m = formation, float(min_separation_m)
        self.motion, self.events = motion, events

    async def reform(self, centre_enu, sysids: list[int]) -> list[int]:
        """Re-form the formation about ``centre_enu`` for the vehicles of ``sysids`` not lost.

        Computes the survivors' slots (:meth:`survivor_slots`), then the motion's ``transfer_to``.
        Returns the survivors; with fewer than 4 nothing is flown (the caller ends the mission).
        """
        lost = self.state.lost
        survivors = [s for s in sysids if s not in lost and self.gate is not None and s in self.gate.sysids]
        if len(survivors) < 4:
            return survivors
        lost_here = [s for s in sysids if s not in survivors]
        new, kind = await self.survivor_slots(centre_enu, sysids, lost_here, "vehicles",
                                              " (and the Theorem 2 estimator)")
        await self.motion.transfer_to(survivors, new, centre_enu,
                                      f"re-forming for {len(survivors)} vehicles ({kind})", lost_here)
        return [s for s in survivors if s not in self.state.lost]

    async def survivor_slots(self, centre_enu, sysids: list[int], gone: list[int], who: str = "vehicles",
                             switch_note: str = "") -> tuple[dict[int, np.ndarray], str]:
        """New slot offsets for ``sysids`` without ``gone``, and the formation type.

        :func:`reformed_offsets` (a switch from symmetric to CVT is logged, ``who`` and
        ``switch_note`` in its message), rotated about the centre clear of the lost vehicles still
        flying (:func:`mission.flight.obstacles.clear_offsets`, logged). Both run in a worker thread: the CVT
        solve takes 0.1-0.3 s of CPU and the event loop must keep streaming setpoints (at 10x,
        0.1 s of wall time is PX4's 1 s offboard-loss timeout).
        """
        state, loop = self.state, asyncio.get_running_loop()
        new, kind = await loop.run_in_executor(None, functools.partial(
            reformed_offsets, state.formation_kind, {s: state.slot_offsets[s] for s in sysids}, gone,
            self.formation.radius_m, self.formation.seed))
        if kind != state.formation_kind:
            self.events.event(f"{len(sysids) - len(gone)} {who} left: the symmetric formation needs an even number; "
                              f"switching to the CVT formation{switch_note}", level="warning")
            state.set_formation_kind(kind)
        obs = obstacles(state.lost, self.fleet, self.clock.time())
        if len(obs):
            new, ok = await loop.run_in_executor(None, functools.partial(
                clear_offsets, new, centre_enu, obs, self.min_separation_m + OBSTACLE_MARGIN_M,
                allow_tilt=kind == "cvt"))
            self.events.event(f"re-formed slots rotated clear of {len(obs)} position(s) of lost vehicles still flying"
                              + ("" if ok else " (no rotation keeps the full clearance)"),
                              level="info" if ok else "warning", obstacles=obs)
        return new, kind
