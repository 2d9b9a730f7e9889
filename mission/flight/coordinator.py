"""The mission coordinator: connect, preflight, take off, assemble, seek, finish, return.

One asyncio task drives the phases (the package ``mission.flight.phases``, one module per phase);
the mission clock is injected (``WallClock`` against real vehicles, the mock fleet's
``SimClock`` when embedded). Around it run: the safety gate (:class:`~mission.safety.gate.SafetyGate`,
``co.gate``: speed-limited, safety-checked setpoints, sent every tick through the
:class:`~mission.vehicle.streamer.SetpointStreamer`), the zenoh readings subscription
(:mod:`mission.telemetry.readings`) and the state publisher (:mod:`mission.telemetry.state_pub`, which also feeds the
display). Every phase change, event and seeking iteration goes to the mission log.
"""
from __future__ import annotations

import asyncio
import numpy as np

from mission.core.tasks import spawn, stop_watched
from mission.core.plan_security import check_security
from mission.core.plan_types import Plan
from mission.flight.phases.connect import Connect, Preflight
from mission.flight.phases.assemble import Assemble
from mission.flight.phases.return_home import ReturnHome
from mission.flight.phases.takeoff import Takeoff
from mission.flight.phases.seek import Seek
from mission.flight.phases.mission_end import MissionEnd, interrupted_message
from mission.flight.control import MissionControl, open_control_channel, operator_command
from mission.flight.faults.landing_guard import LandingGuard
from mission.flight.faults.loss import LossMonitor, Reformation
from mission.flight.faults.responses import FaultResponses
from mission.flight.faults.rejoin import Rejoin
from mission.flight.faults.retire import Retirement, restore_retired
from mission.flight.motion import GateMotion, setpoint_stream
from mission.flight.readiness_autopilot import arm_and_takeoff
from mission.flight.services import Fleet
from mission.flight.return_clear import ReturnClear
from mission.flight.result import MissionResult, geodetic_point, mission_result, readiness_result
from mission.flight.readiness_mission import MissionChecks, not_ready_message
from mission.flight.phases.resume import Resume
from mission.flight.state import MissionError, MissionState
from mission.flight.faults.takeoff_loss import TakeoffLoss
from mission.safety.gate import SafetyGate
from mission.flight.faults.watchdog import Watchdog
from mission.telemetry.link_report import link_rejections, unknown_sysids
from mission.telemetry.mission_log import MissionLog, to_jsonable
from mission.telemetry.readings import ReadingStore, ReadingSubscriber

#: Readings kept per vehicle with the ``ste`` seeker: it is given every reading since takeoff once
#: (sampling while moving), so the store holds 5 minutes at 10 Hz (the other seekers: 200).
_STE_HISTORY = 3000

__all__ = ["Coordinator"]


class Coordinator:
    """Flies one mission described by a :class:`~mission.core.plan.Plan`.

    Parameters
    ----------
    plan : Plan
    clock
        Mission clock (``time()``, ``async sleep``, ``speedup``).
    zenoh_session : zenoh.Session, optional
        For readings and the state publication; None: no readings (only ``dry_run`` works).
    log : MissionLog, optional
        Mission log (JSON lines).
    display : mission.telemetry.display.Display, optional
    tlog_dir : path, optional
        Where LINKS writes one ``.tlog`` per vehicle.
    state_rate_hz : float
        State publication / display rate (wall clock).
    status_period_s : float
        A ``status`` record (every vehicle's state) goes to the mission log this often (mission clock).
    zenoh_problem : str, optional
        Why the plan's zenoh session could not be opened (the dry run's ``zenoh`` check says it).
    simulated_fleet : bool
        The vehicles are ``swarmseek run``'s embedded mock fleet, which ends with the ground
        station: the preflight says once that its autopilots have no ground-station-loss
        failsafe configured, instead of warning about each as about a real vehicle.

    Notes
    -----
    All the mission's mutable state is :attr:`state` (:class:`~mission.flight.state.MissionState`:
    phase, statuses, losses, the seek's progress, interrupts, mission checks, the landing guard's
    commands, the final result); read it there (``co.state.phase``), change it through its
    methods. The links,
    vehicles, setpoint stream and envelope are set by the phases through :meth:`add_endpoint`,
    :meth:`add_vehicle`, :meth:`use_poller`, :meth:`use_envelope` and :meth:`use_setpoints`.
    """


    def __init__(self, plan: Plan, *, clock, zenoh_session=None, log: MissionLog | None = None,
                 display=None, tlog_dir=None, state_rate_hz: float = 2.0, status_period_s: float = 1.0,
                 zenoh_problem: str | None = None, simulated_fleet: bool = False):
        self.plan = plan
        self.simulated_fleet = bool(simulated_fleet)
        #: the plan's security findings (:mod:`mission.core.plan_security`): the log's plan record
        #: (``security_check``), and the warnings in every state publication (``watch`` prints them)
        self.security = check_security(plan)
        self.clock = clock
        self.session = zenoh_session
        self.log = log
        self.display = display
        self.tlog_dir = tlog_dir
        self.state_rate_hz = state_rate_hz
        self.status_period_s = float(status_period_s)
        self.state = MissionState([v.sysid for v in plan.vehicles], clock=clock, log=log,
                                  formation_kind=plan.formation.type)
        self.endpoints: dict[str, object] = {}
        self._endpoint_watchers: list = []  # callables told of each endpoint (watch_endpoints)
        self.poller = None  # mission.link.poller.UdpPoller when many UDP endpoints (connect)
        self.fleet = Fleet({v.sysid: v.id for v in plan.vehicles})
        self.vehicles = self.fleet.vehicles  # the fleet's dict (by sysid), not a copy
        self.ids = self.fleet.ids
        self.streamer = None
        self.gate: SafetyGate | None = None
        self.envelope = None
        self.store = ReadingStore(
            plan.fleet, [v.sysid for v in plan.vehicles], plan.origin, clock,
            telemetry_position=self.telemetry_position,
            max_age_s=plan.seeking.max_reading_age_s,
            max_position_error_m=plan.seeking.max_position_error_m,
            history=_STE_HISTORY if plan.seeking.seeker == "ste" else 200)
        self._subscriber: ReadingSubscriber | None = None
        self._state_pub = None
        self._watchdog_task: asyncio.Task | None = None
        self._loss_task: asyncio.Task | None = None
        self.return_on_interrupt = True
        self.zenoh_problem = zenoh_problem
        self.control = MissionControl(clock, log)  # operator commands (mission.flight.control)
        self._control_channel = None

    # ----------------------------------------------------------------- resources set by the phases
    def add_endpoint(self, uri: str, endpoint) -> None:
        """A MAVLink endpoint opened for ``uri`` (closed at the end); told to every endpoint watcher."""
        self.endpoints[uri] = endpoint
        for watcher in self._endpoint_watchers:
            watcher(endpoint)

    def watch_endpoints(self, watcher) -> None:
        """Call ``watcher(endpoint)`` for every MAVLink endpoint open now and each one opened later.

        The ``--out`` forwarder attaches itself this way: at once, without polling, so that it
        schedules nothing on the mission's clock (a lock-step mission is the same with it).
        """
        self._endpoint_watchers.append(watcher)
        for endpoint in list(self.endpoints.values()):
            watcher(endpoint)

    def add_vehicle(self, vehicle) -> None:
        """A vehicle link attached (by its ``sysid``; closed at the end)."""
        self.fleet.add(vehicle)

    def use_poller(self, poller) -> None:
        """The UDP poller reading every UDP endpoint (closed at the end)."""
        self.poller = poller

    def use_envelope(self, envelope) -> None:
        """The safety envelope every setpoint batch is checked against (None: no fence)."""
        self.envelope = envelope

    def use_setpoints(self, streamer, gate: SafetyGate) -> None:
        """The setpoint streamer and the safety gate feeding it (stopped at the end)."""
        self.streamer, self.gate = streamer, gate

    def open_setpoints(self, vehicles: list) -> SafetyGate:
        """A setpoint stream for ``vehicles`` and its safety gate (:func:`mission.flight.motion.setpoint_stream`),
        used from now on; the gate (not started)."""
        self.use_setpoints(*setpoint_stream(vehicles, self.plan, self.clock, self.envelope, self))
        return self.gate

    @property
    def readings_subscribed(self) -> bool:
        """The zenoh readings subscription is running (False in a dry run without a session)."""
        return self._subscriber is not None

    # ----------------------------------------------------------------- helpers used by phases
    def plan_vehicle(self, sysid: int):
        """The plan's entry of a vehicle."""
        return next(v for v in self.plan.vehicles if v.sysid == sysid)

    def telemetry_position(self, sysid: int):
        """The vehicle's telemetry position (mission ENU m), or None (unknown vehicle, no telemetry yet)."""
        return self.fleet.telemetry_position(sysid)

    def set_phase(self, name: str, **fields) -> None:
        """Enter a phase: log it, show it."""
        self.state.set_phase(name)
        if self.log is not None:
            self.log.phase(name, **fields)
        self.say(f"phase {name}" + (f" ({', '.join(f'{k}={v}' for k, v in fields.items())})" if fields else ""))
        if self._state_pub is not None:
            self._state_pub.publish_now()

    def event(self, message: str, level: str = "info", **fields) -> None:
        """Log and show an event."""
        if self.log is not None:
            self.log.event(message, level=level, **fields)
        self.say(("" if level == "info" else f"{level.upper()}: ") + message)

    def task_failed(self, message: str) -> None:
        """A background task failed (:func:`mission.core.tasks.watch_task`): an error event."""
        self.event(message, level="error")

    def say(self, text: str) -> None:
        """Show a line above the live display; a display that fails is turned off (told in the log)."""
        if self.display is None:
            return
        try:
            self.display.message(text)
        except Exception as exc:  # noqa: BLE001 - the mission never stops for its display
            self.display = None
            self.event(f"the live display failed ({type(exc).__name__}: {exc}): it is off for the rest of "
                       "the mission (this log has everything)", level="error")

    def update_odometry(self) -> None:
        """Accumulate each vehicle's flown distance from telemetry."""
        self.state.add_positions({s: self.telemetry_position(s) for s in self.vehicles})

    def vehicle_status(self) -> list[dict]:
        """Per-vehicle status dicts (display, state, log)."""
        out = []
        for vp in self.plan.vehicles:
            v = self.vehicles.get(vp.sysid)
            d = {"sysid": vp.sysid, "id": vp.id, "status": self.state.status.get(vp.sysid, ""),
                 "sensor_retired": vp.sysid in self.state.retired, "flight_state": self.flight_state(vp.sysid)}
            if v is not None:
                st = v.state
                pos = self.telemetry_position(vp.sysid)
                d.update(flavour=v.flavour, mode=st.mode, armed=bool(st.armed),
                         relative_alt_m=st.relative_alt_m, battery_pct=st.battery_remaining_pct,
                         link_age_s=round(float(v.link_age_s()), 3),
                         position_enu=None if pos is None else np.round(np.asarray(pos, float), 3))
                if self.streamer is not None and self.gate is not None and vp.sysid in self.gate.sysids:
                    d["setpoint_rate_hz"] = self.streamer.measured_rate_hz(vp.sysid)
                    d["setpoint_enu"] = np.round(self.gate.setpoint(vp.sysid), 3)
            out.append(d)
        return out

    def flight_state(self, sysid: int) -> str:
        """One word for the map's colour: ``lost``, ``retired``, ``holding`` (paused, or its status
        says it holds), ``flying`` (airborne) or ``landed`` (on the ground, also before takeoff)."""
        if sysid in self.state.lost:
            return "lost"
        if sysid in self.state.retired:
            return "retired"
        if sysid in self.state.airborne:
            holding = self.control.paused or "holding" in self.state.status.get(sysid, "")
            return "holding" if holding else "flying"
        return "landed"

    def map_geometry(self) -> dict:
        """What the live map draws besides the vehicles: origin, geofence, altitude band and the
        formation's slots (ENU m, by sysid; empty before the assembly)."""
        fence, centre = self.plan.geofence, self.state.centre_enu
        slots = {} if centre is None else {
            str(s): np.round(np.asarray(centre, float) + off, 3) for s, off in self.state.slot_offsets.items()}
        return {"origin": list(self.plan.origin), "fence_en_m": [list(p) for p in fence.polygon_en_m],
                "min_alt_m": fence.min_alt_m, "max_alt_m": fence.max_alt_m, "slots_enu": slots}

    def _estimate_map(self) -> dict | None:
        """The estimate's plan-view posterior (the ``ste`` seeker's, 24 x 24 cells), None without one."""
        est = self.state.estimate
        return None if est is None or est.plan_map is None else est.plan_map.to_json()

    def link_rejections(self) -> dict[str, int]:
        """Frames the mission's MAVLink endpoints refused so far, by kind (non-zero only;
        :func:`mission.telemetry.link_report.link_rejections`)."""
        return link_rejections(self.endpoints.values())

    def unknown_sysids(self) -> list[int]:
        """System ids heard on the mission's links that are no vehicle of the plan."""
        return unknown_sysids(self.endpoints.values(), self.ids)

    def snapshot(self) -> dict:
        """The current state (published on ``swarmseek/<fleet>/mission/state``)."""
        g = self.state.gradient
        return {
            "fleet": self.plan.fleet, "phase": self.state.phase, "t_s": self.clock.time(),
            "elapsed_s": self.clock.time() - self.state.t_start_s, "iteration": self.state.iteration,
            "centre_enu": self.state.centre_enu, "gradient": g,
            "gradient_norm": None if g is None else float(np.linalg.norm(g)),
            "estimate_enu": self.state.estimate_enu, "spread_m": self.state.spread_m,
            "estimate_region95_m": self.state.estimate_region95_m, "estimate_basis": self.state.estimate_basis,
            "estimate_geodetic": geodetic_point(self.plan.origin, self.state.estimate_enu),
            "distance_flown_m": self.state.distance_flown_m, "vehicles": self.vehicle_status(),
            "readings": self.store.counts(), "link_rejections": self.link_rejections(),
            "unknown_sysids": self.unknown_sysids(), "control": self.control.snapshot(),
            "security_warnings": [f.to_json() for f in self.security if f.level != "info"],
            "geometry": self.map_geometry(), "ending": self.state.ending, "estimate_map": self._estimate_map(),
            "events": [] if self.log is None else list(self.log.recent),
        }

    def _security_json(self) -> list[dict]:
        """Every security finding of the plan, for the mission log's ``plan`` record."""
        return [f.to_json() for f in self.security]

    def landing_guard(self) -> LandingGuard:
        """The never-abandon check (:class:`mission.flight.faults.landing_guard.LandingGuard`) over the
        vehicles, the gate and the log of this mission now."""
        return LandingGuard(self.state, self.fleet, self.gate, self.clock, self.plan.faults, self.log, self)

    def readiness_checks(self) -> MissionChecks:
        """The mission-wide preflight checks (:class:`mission.flight.readiness_mission.MissionChecks`)
        over this mission's vehicles, readings and zenoh session now."""
        return MissionChecks(self.state, self.fleet, self.plan, self.clock, self.store, self.session,
                             self.zenoh_problem, self.readings_subscribed, self)

    def takeoff_loss(self) -> TakeoffLoss:
        """The takeoff's and the assembly's losses (:class:`mission.flight.faults.takeoff_loss.TakeoffLoss`)
        over this mission's vehicles and gate now."""
        return TakeoffLoss(self.state, self.fleet, self.gate, self.clock, self, self.task_failed)

    def motion(self) -> GateMotion:
        """The formation's moves (:class:`mission.flight.motion.GateMotion`) flown on this mission's gate
        (the gate and the fence read at each move: both are set after the loss monitor is built)."""
        plan = self.plan
        return GateMotion(self.state, self.fleet, lambda: self.gate,
                          lambda: None if self.envelope is None else self.envelope.fence, self.clock, self, self,
                          return_behaviour=plan.return_behaviour, min_separation_m=plan.min_separation_m,
                          max_speed_m_s=plan.max_speed_m_s, arrival_tol_m=plan.seeking.arrival_tol_m)

    def fault_responses(self) -> FaultResponses:
        """The seek's fault responses and moves (:class:`mission.flight.faults.responses.FaultResponses`)
        over this mission's vehicles and gate now."""
        return FaultResponses(self.state, self.plan.faults, self.reformation(), self.rejoin(), self.retirement(),
                              self.motion())

    def reformation(self) -> Reformation:
        """The formation re-formed for the vehicles left (:class:`mission.flight.faults.loss.Reformation`)
        over this mission's vehicles and gate now."""
        plan = self.plan
        return Reformation(self.state, self.fleet, self.gate, self.clock, plan.formation, plan.min_separation_m,
                           self.motion(), self)

    def rejoin(self) -> Rejoin:
        """Lost vehicles kept clear of, returning ones re-admitted (:class:`mission.flight.faults.rejoin.Rejoin`)
        over this mission's vehicles and gate now."""
        plan = self.plan
        return Rejoin(self.state, self.fleet, self.gate, self.clock, plan.faults, plan.formation,
                      plan.min_separation_m, self.motion(), self, self)

    def retirement(self) -> Retirement:
        """Faulty sensors retired, their vehicles parked (:class:`mission.flight.faults.retire.Retirement`)
        over this mission's vehicles and gate now."""
        return Retirement(self.state, self.fleet, self.gate, self.plan.faults, self.reformation(), self.motion(), self)

    def return_clear(self) -> ReturnClear:
        """The return and the assembly's legs clear of lost vehicles still flying
        (:class:`mission.flight.return_clear.ReturnClear`) over this mission's vehicles and gate now."""
        plan = self.plan
        return ReturnClear(self.state, self.fleet, self.gate, self.clock, plan.min_separation_m,
                           plan.seeking.arrival_tol_m, plan.geofence.max_alt_m, plan.return_behaviour,
                           None if self.envelope is None else self.envelope.fence, self.motion(), self)

    # ----------------------------------------------------------------- the phases, built
    def connect_phase(self) -> Connect:
        """The connect phase (:class:`mission.flight.phases.connect.Connect`) of this mission's plan."""
        return Connect(self.plan, self.state, self.fleet, self, self.clock, self, self.tlog_dir)

    def preflight_phase(self) -> Preflight:
        """The preflight (:class:`mission.flight.phases.connect.Preflight`) of the connected vehicles."""
        return Preflight(self.plan, self.state, self.fleet, self.clock, self, self.readiness_checks,
                         self.simulated_fleet)

    def takeoff_phase(self) -> Takeoff:
        """The takeoff (:class:`mission.flight.phases.takeoff.Takeoff`) of this mission's vehicles."""
        def arm(sysid, v, rel_alt_m, before_takeoff, pause):
            return arm_and_takeoff(sysid, v, rel_alt_m, self.clock, self,
                                   self.plan.preflight.autopilot_ready_timeout_s, before_takeoff=before_takeoff,
                                   pause=pause)

        return Takeoff(self.plan, self.state, self.fleet, self.clock, self, self, self.open_setpoints,
                              arm, self.takeoff_loss)

    def assemble_phase(self) -> Assemble:
        """The assembly (:class:`mission.flight.phases.assemble.Assemble`) of the vehicles under the gate now."""
        return Assemble(self.plan.seeking, self.state, self.gate, self, self.return_clear().fly_clear,
                               self.takeoff_loss())

    def return_phase(self) -> ReturnHome:
        """The return (:class:`mission.flight.phases.return_home.ReturnHome`) of the vehicles airborne now."""
        return ReturnHome(self.plan, self.state, self.fleet, self.gate, self.clock, self, self,
                                 self.control, self.return_clear().fly_return)

    def resume_phase(self) -> Resume:
        """The resumed mission (:class:`mission.flight.phases.resume.Resume`): rejoin, then seek on or come home."""
        async def reconnect():
            await self.connect_phase().run(required=False)

        async def seek_on(**resumed):
            return await self.seek_phase().run(**resumed)

        return Resume(self.plan, self.state, self.fleet, self.clock, self, self, reconnect, self.use_envelope,
                      self.open_setpoints, lambda records: restore_retired(self.state, records), seek_on)

    def seek_phase(self) -> Seek:
        """The seek (:class:`mission.flight.phases.seek.Seek`) of the formation under the gate now."""
        return Seek(self.plan, self.state, self.fleet, self.gate, self.clock, self, self, self.store, self.envelope,
                    self.log, self.fault_responses(),
                    lambda: self.control.checkpoint(self.state, self.gate, self, self.clock, self), self.vehicle_status)

    def mission_end(self) -> MissionEnd:
        """The mission's end (:class:`mission.flight.phases.mission_end.MissionEnd`): return, secure, stop, summarise."""
        return MissionEnd(self.state, self, self.return_safely, self.landing_guard, self.stop_background,
                          self.result, self.log, self.return_on_interrupt)

    async def wait_until(self, predicate, timeout_s: float, what: str, poll_s: float = 0.1) -> None:
        """Poll ``predicate()`` on the mission clock until true; MissionError after ``timeout_s``."""
        deadline = self.clock.time() + timeout_s
        while not predicate():
            self.control.check(self.state.phase)  # an operator's stop ends the phase here
            if self.clock.time() > deadline:
                raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await self.clock.sleep(poll_s)

    def command(self, command: str, sender: str) -> dict:
        """An operator command (zenoh, terminal key): :func:`mission.flight.control.operator_command`."""
        return operator_command(self.control, self.state.phase, self, command, sender, self._state_pub)

    # ----------------------------------------------------------------- mission entry points
    def _start_background(self) -> None:
        from mission.telemetry.state_pub import StatePublisher

        if self._watchdog_task is None:
            watchdog = Watchdog(self.state, self.fleet, lambda: self.gate, self.clock, self.plan.faults, self, self.log,
                                self.status_period_s, self, self.task_failed)
            self._watchdog_task = spawn(watchdog.run(), "the watchdog", self.task_failed)
        if self._loss_task is None:
            monitor = LossMonitor(self.state, self.fleet, lambda: self.gate, self.clock, self.plan.faults,
                                  self.plan.return_behaviour, self.motion(), self, self.task_failed)
            self._loss_task = spawn(monitor.run(), "the loss detection", self.task_failed)

        if self.session is not None and self._subscriber is None:
            self._subscriber = ReadingSubscriber(self.session, self.store)
        if self._state_pub is None:
            self._state_pub = StatePublisher(
                self.session, self.plan.fleet, self.snapshot, rate_hz=self.state_rate_hz,
                on_snapshot=self.display.update if self.display is not None else None,
                report=self.task_failed)
            self._state_pub.start()
        if self._control_channel is None:
            self._control_channel = open_control_channel(self.session, self.plan.control, self.plan.fleet,
                                                         self.command, self.task_failed)

    async def stop_background(self) -> None:
        """Stop what runs beside the phases: watchdog, loss monitor, ramp, streamer, control
        channel, state publisher, reading subscriber, then close vehicles, links and poller."""
        await stop_watched(self._watchdog_task)  # a failure was told when it happened
        self._watchdog_task = None
        await stop_watched(self._loss_task)
        self._loss_task = None
        if self.gate is not None:
            await self.gate.stop()
        if self.streamer is not None:
            try:
                await self.streamer.stop()
            except Exception as exc:  # noqa: BLE001 - stopping must go on; say what failed
                self.event(f"stopping the setpoint streamer failed: {exc!r}", level="warning")
        if self._control_channel is not None:
            try:
                await self._control_channel.stop()
            except Exception as exc:  # noqa: BLE001 - e.g. the zenoh session is gone; stopping goes on
                self.event(f"closing the operator's control channel failed: {exc!r}", level="warning")
            self._control_channel = None
        if self._state_pub is not None:
            await self._state_pub.stop()
            self._state_pub = None
        if self._subscriber is not None:
            self._subscriber.close()
            self._subscriber = None
        for what, closable in ([(f"vehicle {s}", v) for s, v in self.vehicles.items()]
                               + [(f"link {u}", ep) for u, ep in self.endpoints.items()]
                               + ([("UDP poller", self.poller)] if self.poller is not None else [])):
            try:
                await closable.close()
            except Exception as exc:  # noqa: BLE001 - closing must go on; say what failed
                self.event(f"closing {what} failed: {exc!r}", level="warning")
        self.poller = None

    async def dry_run(self) -> MissionResult:
        """Connect and run the preflight checks; arms nothing. Outcome ``ready`` or ``not_ready``."""
        if self.log is not None:
            self.log.write("plan", plan=_plan_json(self.plan), dry_run=True, security_check=self._security_json())
        self._start_background()
        try:
            await self.connect_phase().run(required=False)
            self.use_envelope(await self.preflight_phase().run())
        except MissionError as exc:
            self.event(str(exc), level="error")
        finally:
            await self.stop_background()
        result = readiness_result(self.state, self.plan.vehicles, self.store.counts(),
                                  self.clock.time() - self.state.t_start_s,
                                  mission_checks=self.state.mission_checks)
        result.link_rejections, result.unknown_sysids = self.link_rejections(), self.unknown_sysids()
        if self.log is not None:
            self.log.write("summary", sync=True, **result.to_json())
        return result

    async def run(self, resume_state=None) -> MissionResult:
        """Fly the whole mission and return its result (never raises for mission failures).

        Parameters
        ----------
        resume_state : mission.flight.phases.resume.ResumeState, optional
            Go on with a stopped mission: reconnect, re-engage the vehicles still flying (no
            preflight, no takeoff), seek from the state's centre and iteration.

        Cancelling the task brings the vehicles home first, unless ``return_on_interrupt`` is
        False (a ground station that just stops: the vehicles do what their autopilot does); a
        second cancellation lands them where they are (:class:`mission.flight.phases.mission_end.MissionEnd`). Every
        path ends with the never-abandon check (:mod:`mission.flight.faults.landing_guard`) and a
        ``summary`` record; a cancelled run then raises CancelledError (``state.final_result``
        holds its result).
        """
        if self.log is not None:
            self.log.write("plan", plan=_plan_json(self.plan), resumed=resume_state is not None,
                           security_check=self._security_json())
        self._start_background()
        outcome, message = "aborted", ""
        try:
            if resume_state is None:
                await self.connect_phase().run(required=True)
                self.use_envelope(await self.preflight_phase().run())
                problem = not_ready_message(self.state)
                if problem:
                    raise MissionError(f"preflight failed: {problem}")
                await self.takeoff_phase().run()
                await self.assemble_phase().run()
                outcome, message = await self.seek_phase().run()
            else:
                outcome, message = await self.resume_phase().run(resume_state)
            self.set_phase("finish", outcome=outcome)
            self.event(message)
        except MissionError as exc:
            outcome, message = "aborted", str(exc)
            self._aborting(message)
        except Exception as exc:  # noqa: BLE001 - anything unexpected: still bring the vehicles home
            import traceback

            outcome, message = "aborted", f"unexpected error in phase {self.state.phase}: {type(exc).__name__}: {exc}"
            self._aborting(message, traceback=traceback.format_exc())
        except asyncio.CancelledError:  # Ctrl-C, SIGTERM, a cancelled task: mission_end counts them
            return await self.mission_end().run("interrupted", interrupted_message(self.state.interrupts),
                                                interrupted=True)
        return await self.mission_end().run(outcome, message)

    def _aborting(self, message: str, **fields) -> None:
        """Enter the ``aborted`` phase and say why; whatever fails in saying it, the mission's end
        (return, landing, summary: :meth:`mission.flight.phases.mission_end.MissionEnd.run`) still follows."""
        try:
            self.set_phase("aborted", reason=message)
            self.event(message, level="error", **fields)
        except Exception as exc:  # noqa: BLE001 - the vehicles come home first; told on stderr
            from mission.telemetry.terminal import alert

            alert(f"swarmseek: mission aborted ({message}); telling it failed too "
                  f"({type(exc).__name__}: {exc}); the vehicles are brought home")

    async def return_safely(self) -> None:
        """Fly every airborne vehicle home; if the return fails, land every vehicle where it is."""
        if not self.state.airborne:
            return
        try:
            await self.return_phase().run()
        except Exception as exc:  # noqa: BLE001 - last resort: land everyone where they are
            self.event(f"return failed ({exc}); landing every vehicle where it is", level="error")
            await self.return_phase().land_all_now()

    def result(self, outcome: str, message: str) -> MissionResult:
        """The :class:`~mission.flight.result.MissionResult` of the mission so far."""
        result = mission_result(self.state, outcome, message, now_s=self.clock.time(),
                                readings=self.store.counts() | {"last_errors": self.store.last_errors()},
                                log_path=None if self.log is None else str(self.log.path),
                                separation_interventions=0 if self.gate is None else self.gate.separation_interventions,
                                origin=self.plan.origin)
        result.link_rejections = self.link_rejections()
        result.unknown_sysids = self.unknown_sysids()
        return result


def _plan_json(plan: Plan) -> dict:
    """The plan for the log's ``plan`` record: secrets redacted (signing: its key's fingerprint)."""
    return to_jsonable(plan)
