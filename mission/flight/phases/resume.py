"""Resume a stopped mission from its mission log (``swarmseek resume LOG``).

What the log holds and the resumed coordinator uses: the plan (``plan`` record), the formation
slots and altitude layers (the ``formation ...`` event, then every ``re-forming ...`` event), the
vehicles lost so far (``vehicle N lost`` events), the formation type in use, and the seek's
progress (the last ``iteration`` record: its ``k``, ``new_centre_enu``, ``distance_flown_m``; the
last ``convergence_window`` centres prefill the convergence monitor), and the retired sensors
(``vehicle N's sensor retired`` events: those vehicles stay parked at the centre, their readings
ignored, :mod:`mission.flight.faults.retire`).

The resumed coordinator reconnects, and re-engages every vehicle still flying (armed, above
1 m, not in RTL/LAND): setpoints at its current position first, then OFFBOARD (PX4) or GUIDED
(ArduPilot); there is no new takeoff. Vehicles on the ground, or returning/landing by themselves
(their autopilot's failsafe while the ground station was away), are counted as lost and left
to their autopilot; if fewer than 4 fly, the resumed mission brings the others home. The seek
goes on from the last centre and iteration, appending to the same log.

The seek goes on only for a log cut in the takeoff, assembly or seek (a ground station killed or
crashed there) or stopped there by an interrupt of a ground station told to just stop; every other
ending (finished, returning, aborted by an error or an operator's stop, interrupted with the
return: :mod:`mission.flight.phases.resume_endings`, the table in docs/faults.md) is taken over to
**bring the vehicles home**: the vehicles still flying are re-engaged the same way, then fly the
return (outcome ``recovered``); if none flies, there is nothing to do (outcome ``recovered``,
every vehicle down).
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Awaitable, Callable

import numpy as np

from formation.geodesy import geodetic_to_enu
from mission.core.zenoh_config import ZenohPlan
from mission.core.plan_types import (
    ControlPlan,
    ForwardPlan,
    PreflightPlan,
    FaultsPlan,
    FormationPlan,
    GeofencePlan,
    Plan,
    SeekingPlan,
    VehiclePlan,
)
from mission.core.signing_config import SigningConfig
from mission.flight.phases.connect import build_envelope
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.motion import retried
from mission.flight.phases.resume_endings import classify_ending
from mission.flight.services import Clock, Events, Fleet, Waiter
from mission.flight.state import MissionError, MissionState, VehicleLoss
from mission.safety.gate import SafetyGate
from wire.signing import SigningError

__all__ = ["Resume", "ResumeError", "ResumeState", "plan_from_json", "load_resume_state"]

#: why a vehicle of the stopped mission is not re-engaged when it is already down (accounted for)
ON_GROUND = "on the ground (disarmed)"


class ResumeError(ValueError):
    """The log cannot be resumed (not a mission log, finished, or stopped before the takeoff)."""


@dataclass
class ResumeState:
    """What a stopped mission's log says about where it was.

    Attributes
    ----------
    plan : Plan
    iteration : int
        Seek iterations done (0: stopped before the seek).
    centre_enu : numpy.ndarray
        Formation centre to go on from.
    centres : list of numpy.ndarray
        The last centres (for the convergence monitor).
    slot_offsets : dict
        Slot offset of every vehicle still in the formation, by sysid.
    layer_alt_m : dict
        Altitude layer of every vehicle (for the return).
    formation_kind : str
    lost : list of int
        Vehicles lost before the stop.
    distance_flown_m : float
    last_phase : str
    embedded : dict or None
        The ``embedded mock fleet`` event of a ``swarmseek run`` log (source, seed...).
    retired : dict
        Sysid -> the fields of its ``sensor retired`` event (:class:`mission.flight.faults.retire.RetiredSensor`).
    go_on : bool
        The seek goes on (the log was cut in the takeoff, assembly or seek, or a ground station
        told to just stop was interrupted there); False (finished, returning, aborted,
        interrupted with the return): bring the vehicles still flying home.
    ending : str
        How the log ends (:data:`mission.flight.phases.resume_endings.ENDINGS`).
    """

    plan: Plan
    iteration: int
    centre_enu: np.ndarray
    centres: list = field(default_factory=list)
    slot_offsets: dict = field(default_factory=dict)
    layer_alt_m: dict = field(default_factory=dict)
    formation_kind: str = "cvt"
    lost: list = field(default_factory=list)
    distance_flown_m: float = 0.0
    last_phase: str = ""
    embedded: dict | None = None
    retired: dict = field(default_factory=dict)
    go_on: bool = True
    ending: str = "cut"


def _tuple_of_tuples(x):
    return tuple(tuple(float(v) for v in p) for p in x)


def plan_from_json(d: dict) -> Plan:
    """Rebuild a :class:`~mission.core.plan.Plan` from the ``plan`` record of a mission log.

    Raises
    ------
    ResumeError
        A field is missing or malformed.
    """
    try:
        sk = dict(d["seeking"])
        if sk.get("start_enu_m") is not None:
            sk["start_enu_m"] = tuple(float(v) for v in sk["start_enu_m"])
        gf = dict(d["geofence"])
        gf["polygon_en_m"] = _tuple_of_tuples(gf.get("polygon_en_m") or ())
        gf["source_latlon_deg"] = _tuple_of_tuples(gf.get("source_latlon_deg") or ())
        zn = dict(d["zenoh"])
        zn["listen"], zn["connect"] = tuple(zn.get("listen") or ()), tuple(zn.get("connect") or ())
        top = {k: d[k] for k in ("fleet", "max_speed_m_s", "min_separation_m", "takeoff_alt_m",
                                 "return_behaviour", "stagger_s", "setpoint_rate_hz",
                                 "heartbeat_timeout_s", "min_battery_pct", "version", "require_signing") if k in d}
        return Plan(origin=tuple(float(v) for v in d["origin"]),
                    vehicles=tuple(VehiclePlan(**v) for v in d["vehicles"]),
                    formation=FormationPlan(**d["formation"]), seeking=SeekingPlan(**sk),
                    geofence=GeofencePlan(**gf), zenoh=ZenohPlan(**zn),
                    faults=FaultsPlan(**d.get("faults", {})), security=_signing_from_json(d.get("security")),
                    preflight=PreflightPlan(**d.get("preflight", {})), control=ControlPlan(**d.get("control", {})),
                    forward=_forward_from_json(d.get("forward")), **top)
    except ResumeError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise ResumeError(f"the log's plan record cannot be read back: {type(exc).__name__}: {exc}") from None


def _forward_from_json(fwd: dict | None) -> ForwardPlan:
    """The ``[forward]`` of a ``plan`` record (older logs have none: the default, read-only and off)."""
    if not fwd:
        return ForwardPlan()
    return ForwardPlan(out=tuple(str(o) for o in fwd.get("out") or ()),
                       allow_commands=bool(fwd.get("allow_commands", False)))


def _signing_from_json(sec: dict | None) -> SigningConfig | None:
    """The signing configuration of a ``plan`` record: the key read again from its key file.

    The log holds the key's fingerprint, never the key (see
    :meth:`~mission.core.signing_config.SigningConfig.to_json`); the key file must still hold
    the same key.

    Raises
    ------
    ResumeError
        The plan signed with a key not read from a file, or the key file is unusable or now
        holds another key.
    """
    if sec is None:
        return None
    path, fingerprint = sec.get("key_file"), sec.get("fingerprint")
    if not path:
        raise ResumeError(f"the log's plan signs with a key not read from a file (fingerprint "
                          f"{fingerprint}): give the plan with --plan")
    try:
        config = SigningConfig.from_key_file(
            path, link_id=int(sec.get("link_id", 0)), send_setup=bool(sec.get("send_setup", True)),
            **({"allow_unsigned": frozenset(sec["allow_unsigned"])}
               if isinstance(sec.get("allow_unsigned"), list) else {}))
    except SigningError as exc:
        raise ResumeError(f"the log's plan signs with the key of {path}: {exc}") from None
    if fingerprint is not None and config.fingerprint != fingerprint:
        raise ResumeError(f"{path} now holds another signing key (fingerprint {config.fingerprint}, "
                          f"the mission flew with {fingerprint}): give the plan with --plan")
    return config


def load_resume_state(log_path: str | Path, plan: Plan | None = None) -> ResumeState:
    """Read a mission log and say where the mission was.

    Parameters
    ----------
    log_path : path
        ``mission.jsonl`` of the stopped mission.
    plan : Plan, optional
        Fly with this plan (same vehicles) instead of the log's ``plan`` record.

    Raises
    ------
    ResumeError
        Not a mission log, no plan, or stopped before the takeoff (nothing can be flying).
    """
    from mission.telemetry.mission_log import read_mission_log

    try:
        records = read_mission_log(log_path)
    except (OSError, ValueError) as exc:
        raise ResumeError(f"cannot read {log_path}: {exc}") from None
    plans = [r for r in records if r["type"] == "plan" and not r.get("dry_run")]
    if plan is None:
        if not plans:
            raise ResumeError(f"{log_path}: no plan record (give the plan with --plan)")
        plan = plan_from_json(plans[0]["plan"])
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    last_phase = phases[-1] if phases else ""
    # the seek goes on only when the mission stopped flying it without deciding to end (killed,
    # crashed, a ground station told to just stop); any other ending brings the vehicles home
    ending = classify_ending(records)
    go_on = ending.go_on
    slots, layers, lost, retired, kind, embedded = _formation_from_events(records, plan.formation.type)
    if not slots:
        raise ResumeError(f"{log_path}: stopped before the takeoff (phase {last_phase!r}): no vehicle was "
                          "flown; start the mission again")
    for s in lost:
        slots.pop(s, None)
    for s in retired:
        if s in slots:
            slots[s] = np.zeros(3)  # parked at the centre
    centre, centres, k, flown = _seek_progress(records, plan)
    return ResumeState(plan=plan, iteration=k, centre_enu=centre, centres=centres, slot_offsets=slots,
                       layer_alt_m=layers, formation_kind=kind, lost=lost, distance_flown_m=flown,
                       last_phase=last_phase, embedded=embedded, retired=retired, go_on=go_on,
                       ending=ending.name)


def _formation_from_events(records: list[dict], kind: str):
    """``(slots, layers, lost, retired, kind, embedded)`` from the log's events, in order."""
    slots: dict[int, np.ndarray] = {}
    layers: dict[int, float] = {}
    lost: list[int] = []
    retired: dict[int, dict] = {}
    embedded = None
    for r in records:
        if r["type"] != "event":
            continue
        msg = r.get("message", "")
        if msg.startswith("formation ") and "slots" in r and "layers" in r:
            slots = {int(k): np.asarray(v, dtype=float) for k, v in r["slots"].items()}
            layers = {int(k): float(v) for k, v in r["layers"].items()}
        elif msg.startswith("re-forming for") and "slots" in r:
            slots.update({int(k): np.asarray(v, dtype=float) for k, v in r["slots"].items()})
        elif msg.startswith("vehicle ") and " lost:" in msg and "sysid" in r:
            lost.append(int(r["sysid"]))
        elif msg.startswith("vehicle ") and " re-admitted" in msg and "sysid" in r:
            lost = [s for s in lost if s != int(r["sysid"])]
        elif msg.startswith("formation rotated") and "slots" in r:
            slots.update({int(k): np.asarray(v, dtype=float) for k, v in r["slots"].items()})
        elif msg.startswith("vehicle ") and "'s sensor retired (" in msg and "sysid" in r:
            retired[int(r["sysid"])] = r
        elif "switching to the CVT formation" in msg:
            kind = "cvt"
        elif msg == "embedded mock fleet":
            embedded = r
    return slots, layers, lost, retired, kind, embedded


def _seek_progress(records: list[dict], plan: Plan):
    """``(centre, last centres, iterations done, distance flown)`` from the log's ``iteration`` records."""
    iterations = [r for r in records if r["type"] == "iteration"]
    if not iterations:
        return plan.seeking.start_point(), [], 0, 0.0
    last = iterations[-1]
    window = plan.seeking.convergence_window
    centres = [np.asarray(r["new_centre_enu"], dtype=float) for r in iterations[-window:]]
    return (np.asarray(last["new_centre_enu"], dtype=float), centres, int(last["k"]),
            float(last.get("distance_flown_m") or 0.0))


class Resume:
    """The resumed mission: reconnect, re-engage the vehicles still flying, then seek on
    (``state.go_on``) or bring them home.

    Parameters
    ----------
    plan : Plan
        The origin, the fence.
    state : MissionState
        Set from the log's formation, seek progress and losses.
    fleet : Fleet
    clock : Clock
    events : Events
    waiter : Waiter
    connect : callable
        ``await connect()``: the connect phase (not required: a vehicle that cannot be reached is lost).
    use_envelope : callable
        ``use_envelope(envelope)``: the mission's safety envelope from now on.
    open_setpoints : callable
        ``open_setpoints(vehicles) -> SafetyGate``: the setpoint stream and its safety gate (not started).
    restore_retired : callable
        ``restore_retired(records)``: the retired sensors of the log (:mod:`mission.flight.faults.retire`).
    seek : callable
        ``await seek(start_iteration=k, history=centres) -> (outcome, message)``: the seek phase.
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, clock: Clock, events: Events, waiter: Waiter,
                 connect: Callable[[], Awaitable[None]], use_envelope: Callable[[Any], None],
                 open_setpoints: Callable[[list], SafetyGate], restore_retired: Callable[[dict], None],
                 seek: Callable[..., Awaitable[tuple[str, str]]]) -> None:
        self.plan, self.state, self.fleet, self.clock, self.events, self.waiter = plan, state, fleet, clock, events, waiter
        self.connect, self.use_envelope, self.open_setpoints = connect, use_envelope, open_setpoints
        self.restore_retired, self.seek = restore_retired, seek

    async def run(self, resume: ResumeState) -> tuple[str, str]:
        """Rejoin, then seek on (``resume.go_on``) or bring the vehicles home; ``(outcome, message)``."""
        await self.rejoin(resume)
        if resume.go_on:
            return await self.seek(start_iteration=resume.iteration, history=resume.centres)
        flying = sorted(self.state.airborne)
        if not flying:
            return "recovered", "no vehicle of the stopped mission is flying: nothing to bring home"
        return "recovered", (f"the stopped mission ({resume.ending}, last phase {resume.last_phase!r}) left vehicles "
                             f"{flying} flying: bringing them home")

    async def rejoin(self, resume: ResumeState) -> None:
        """Reconnect and re-engage the vehicles still flying.

        Raises
        ------
        mission.flight.state.MissionError
            Fewer than 4 vehicles can be re-engaged (those that can are still brought home).
        """
        state = self.state
        await self.connect()
        self.use_envelope(build_envelope(self.plan))
        state.resume_seek(resume.iteration, resume.centre_enu, resume.distance_flown_m)
        state.set_formation(resume.slot_offsets, layer_alt_m=resume.layer_alt_m, kind=resume.formation_kind)
        now = self.clock.time()
        for s in resume.lost:
            state.declare_lost(VehicleLoss(s, "link", "lost before the ground station stopped", now, now, "resume"))
        flying = []
        for sysid in sorted(state.slot_offsets):
            reason = await self.why_not_flying(sysid)
            if reason is not None:
                state.declare_lost(VehicleLoss(sysid, "left", reason, now, now, "resume", on_ground=reason == ON_GROUND),
                                   f"lost ({reason})")
                self.events.event(f"vehicle {sysid} lost: {reason}; not re-engaged", level="warning", sysid=sysid)
            else:
                flying.append(sysid)
        await self._reengage(flying)
        self.restore_retired(resume.retired)
        c = state.centre_enu
        self.events.event(("resumed" if resume.go_on else f"taken over to bring the vehicles home (the log ends "
                           f"{resume.ending} in phase {resume.last_phase!r})") + f" at iteration {resume.iteration} "
                          f"from centre ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m with vehicles "
                          f"{flying}", iteration=resume.iteration, centre_enu=c, vehicles=flying,
                          lost=sorted(state.lost), retired=sorted(state.retired))
        sensing = [s for s in flying if s not in state.retired]
        if resume.go_on and len(sensing) < 4:
            raise MissionError(f"only {len(sensing)} sensing vehicles can be re-engaged ({sensing}); a formation "
                               "needs 4: bringing them home")
        await asyncio.sleep(0)

    async def why_not_flying(self, sysid: int) -> str | None:
        """Why a vehicle of the stopped formation cannot be re-engaged (None: it can); records its home."""
        v = self.fleet.vehicles.get(sysid)
        if v is None:
            return "not connected at resume"
        reason = None
        try:
            home = await v.wait_home(10.0)
        except Exception as exc:  # noqa: BLE001 - CommandError: reported as the reason
            home, reason = None, f"no home position at resume ({exc})"
        # its altitude too: a position may come first (real ArduCopter at resume: 4 of 5 hovering
        # vehicles were taken for "not flying" on the altitude of before their first GLOBAL_POSITION_INT)
        await self.waiter.wait_until(lambda: v.state.position_ok and v.state.relative_alt_m is not None, 10.0,
                                     f"vehicle {sysid} position and altitude")
        st = v.state
        if home is not None:
            self.state.set_home(sysid, geodetic_to_enu(home[0], home[1], home[2], self.plan.origin))
        if reason is None and not st.armed:
            reason = ON_GROUND
        elif reason is None and st.mode in LEFT_MODES.get(v.flavour, ()):
            reason = f"in {st.mode} (its autopilot's failsafe while the ground station was away)"
        elif reason is None and (st.relative_alt_m is None or st.relative_alt_m < 1.0):
            reason = "not flying"
        return reason

    async def _reengage(self, flying: list[int]) -> None:
        """Setpoints at each flying vehicle's position first, then OFFBOARD (PX4) or GUIDED (ArduPilot)."""
        vehicles = self.fleet.vehicles
        gate = self.open_setpoints([vehicles[s] for s in flying])
        for s in flying:
            gate.add(s, self.fleet.telemetry_position(s))
            self.state.set_airborne(s, "re-engaging")
        gate.start()  # the safety gate: moves, checks and sends the setpoints
        await self.clock.sleep(0.5)  # setpoints flowing before OFFBOARD (PX4 requires it)
        for s in flying:
            v = vehicles[s]
            want = GUIDED_MODES.get(v.flavour)
            if want is not None and v.state.mode != want:
                await retried(self.events, self.clock, lambda v=v, want=want: v.set_mode(want),
                              f"re-engaging {want} on vehicle {s}")
            self.state.set_status(s, "in formation")
