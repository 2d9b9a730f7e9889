"""The mission coordinator: connect, preflight, take off, assemble, seek, finish, return.

One asyncio task drives the phases (``mission.flight.phases`` and ``mission.flight.seek`` hold their code);
the mission clock is injected (``WallClock`` against real vehicles, the mock fleet's
``SimClock`` when embedded). Around it run: the :class:`~mission.vehicle.streamer.SetpointStreamer`
(steady setpoint stream to every vehicle), the :class:`~mission.flight.targets.TargetRamp`
(speed-limited, safety-checked setpoints), the zenoh readings subscription
(:mod:`mission.telemetry.readings`) and the state publisher (:mod:`mission.telemetry.state_pub`, which also feeds the
display). Every phase change, event and seeking iteration goes to the mission log.
"""
from __future__ import annotations

import asyncio
from dataclasses import asdict

import numpy as np

from mission.core.clock import cancel_and_wait
from mission.core.plan import Plan
from mission.flight import connect as connect_phase
from mission.flight import phases, seek
from mission.flight.loss import watch_losses
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.result import MissionResult
from mission.flight.resume import rejoin
from mission.flight.state import PHASES, MissionError, VehicleReadiness
from mission.telemetry.mission_log import MissionLog, to_jsonable
from mission.telemetry.readings import ReadingStore, ReadingSubscriber

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
    """

    def __init__(self, plan: Plan, *, clock, zenoh_session=None, log: MissionLog | None = None,
                 display=None, tlog_dir=None, state_rate_hz: float = 2.0, status_period_s: float = 1.0):
        self.plan = plan
        self.clock = clock
        self.session = zenoh_session
        self.log = log
        self.display = display
        self.tlog_dir = tlog_dir
        self.state_rate_hz = state_rate_hz
        self.status_period_s = float(status_period_s)
        self.phase = "idle"
        self.endpoints: dict[str, object] = {}
        self.poller = None  # mission.link.poller.UdpPoller when many UDP endpoints (phases.connect)
        self.vehicles: dict[int, object] = {}
        self.ids = {v.sysid: v.id for v in plan.vehicles}
        self.streamer = None
        self.ramp = None
        self.envelope = None
        self.store = ReadingStore(
            plan.fleet, [v.sysid for v in plan.vehicles], plan.origin, clock,
            telemetry_position=self._telemetry_position,
            max_age_s=plan.seeking.max_reading_age_s,
            max_position_error_m=plan.seeking.max_position_error_m)
        self._subscriber: ReadingSubscriber | None = None
        self._state_pub = None
        self.iteration = 0
        self.centre_enu: np.ndarray | None = None
        self.gradient: np.ndarray | None = None
        self.estimate_enu: np.ndarray | None = None
        self.spread_m: float | None = None
        self.distance_flown_m = 0.0
        self.vehicle_distance_m: dict[int, float] = {}
        self._last_pos: dict[int, np.ndarray] = {}
        self.slot_offsets: dict[int, np.ndarray] = {}
        self.layer_alt_m: dict[int, float] = {}
        self.home_enu: dict[int, np.ndarray] = {}
        self.readiness: dict[int, VehicleReadiness] = {}
        self.status: dict[int, str] = {v.sysid: "pending" for v in plan.vehicles}
        self.airborne: set[int] = set()
        self._t_start = clock.time()
        self._t_seek_start: float | None = None
        self._t_seek_end: float | None = None
        self._watchdog_task: asyncio.Task | None = None
        self._reengaging: set[int] = set()
        self.released: set[int] = set()
        self.reengaged: dict[int, int] = {}
        self.max_loop_lag_s = 0.0
        self.lost: dict = {}
        self.readmitted: list = []  # mission.flight.rejoin.readmit
        self.retired: dict = {}  # sysid -> mission.flight.retire.RetiredSensor (parked at the centre)
        self.return_on_interrupt = True
        self.formation_kind = plan.formation.type
        self._loss_task: asyncio.Task | None = None

    # ----------------------------------------------------------------- helpers used by phases
    def plan_vehicle(self, sysid: int):
        """The plan's entry of a vehicle."""
        return next(v for v in self.plan.vehicles if v.sysid == sysid)

    def _telemetry_position(self, sysid: int):
        v = self.vehicles.get(sysid)
        if v is None:
            return None
        try:
            return v.position_enu_m()
        except Exception:  # noqa: BLE001 - no telemetry yet
            return None

    def set_phase(self, name: str, **fields) -> None:
        """Enter a phase: log it, show it."""
        if name not in PHASES:
            raise ValueError(f"unknown phase {name!r}; phases: {', '.join(PHASES)}")
        self.phase = name
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

    def say(self, text: str) -> None:
        """Show a line above the live display."""
        if self.display is not None:
            self.display.message(text)

    def update_odometry(self) -> None:
        """Accumulate each vehicle's flown distance from telemetry."""
        for sysid, v in self.vehicles.items():
            p = self._telemetry_position(sysid)
            if p is None:
                continue
            p = np.asarray(p, dtype=float)
            last = self._last_pos.get(sysid)
            if last is not None and sysid in self.airborne:
                step = float(np.linalg.norm(p - last))
                if step < 50.0:
                    self.vehicle_distance_m[sysid] = self.vehicle_distance_m.get(sysid, 0.0) + step
            self._last_pos[sysid] = p

    def vehicle_status(self) -> list[dict]:
        """Per-vehicle status dicts (display, state, log)."""
        out = []
        for vp in self.plan.vehicles:
            v = self.vehicles.get(vp.sysid)
            d = {"sysid": vp.sysid, "id": vp.id, "status": self.status.get(vp.sysid, ""),
                 "sensor_retired": vp.sysid in self.retired}
            if v is not None:
                st = v.state
                pos = self._telemetry_position(vp.sysid)
                d.update(flavour=v.flavour, mode=st.mode, armed=bool(st.armed),
                         relative_alt_m=st.relative_alt_m, battery_pct=st.battery_remaining_pct,
                         link_age_s=round(float(v.link_age_s()), 3),
                         position_enu=None if pos is None else np.round(np.asarray(pos, float), 3))
                if self.streamer is not None and self.ramp is not None and vp.sysid in self.ramp.sysids:
                    try:
                        d["setpoint_rate_hz"] = self.streamer.stats(vp.sysid).get("rate_hz")
                    except Exception:  # noqa: BLE001 - no stats yet
                        d["setpoint_rate_hz"] = None
                    d["setpoint_enu"] = np.round(self.ramp.setpoint(vp.sysid), 3)
            out.append(d)
        return out

    def snapshot(self) -> dict:
        """The current state (published on ``swarmseek/<fleet>/mission/state``)."""
        g = self.gradient
        return {
            "fleet": self.plan.fleet, "phase": self.phase, "t_s": self.clock.time(),
            "elapsed_s": self.clock.time() - self._t_start, "iteration": self.iteration,
            "centre_enu": self.centre_enu, "gradient": g,
            "gradient_norm": None if g is None else float(np.linalg.norm(g)),
            "estimate_enu": self.estimate_enu, "spread_m": self.spread_m,
            "distance_flown_m": self.distance_flown_m, "vehicles": self.vehicle_status(),
            "readings": self.store.counts(),
        }

    async def wait_until(self, predicate, timeout_s: float, what: str, poll_s: float = 0.1) -> None:
        """Poll ``predicate()`` on the mission clock until true; MissionError after ``timeout_s``."""
        deadline = self.clock.time() + timeout_s
        while not predicate():
            if self.clock.time() > deadline:
                raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await self.clock.sleep(poll_s)

    # ----------------------------------------------------------------- mission entry points
    async def _watchdog(self, period_s: float = 0.1) -> None:
        """Odometry, event-loop lag, and re-engaging OFFBOARD/GUIDED after a setpoint-loss failsafe.

        A vehicle under the mission's setpoints (takeoff done, not returning) found in another
        mode is switched back (PX4 falls back to hold when setpoints pause for COM_OF_LOSS_T;
        the stream resumes at once, so re-engaging is safe); each time is logged and counted.
        """
        loop = asyncio.get_running_loop()
        next_status_s = self.clock.time()
        while True:
            t0 = loop.time()
            await asyncio.sleep(period_s)
            self.max_loop_lag_s = max(self.max_loop_lag_s, loop.time() - t0 - period_s)
            self.update_odometry()
            if self.log is not None and self.vehicles and self.clock.time() >= next_status_s:
                next_status_s = self.clock.time() + self.status_period_s
                self.log.write("status", phase=self.phase, centre_enu=self.centre_enu,
                               vehicles=self.vehicle_status())
            if self.phase not in ("assemble", "seek", "finish", "return") or self.ramp is None:
                continue
            for sysid in self.ramp.sysids:
                v = self.vehicles.get(sysid)
                want = GUIDED_MODES.get(getattr(v, "flavour", None))
                if (v is None or want is None or sysid in self._reengaging or sysid in self.released
                        or sysid in self.lost or v.state.mode == want):
                    continue
                if v.state.mode in LEFT_MODES.get(v.flavour, ()) or v.link_age_s() > self.plan.faults.link_timeout_s:
                    continue  # left the mission or silent: mission.flight.loss decides, never re-engaged
                if not v.state.armed:
                    continue
                self._reengaging.add(sysid)
                loop.create_task(self._reengage(sysid, v, want))

    async def _reengage(self, sysid: int, v, want: str) -> None:
        try:
            self.event(f"vehicle {sysid} left {want} (now {v.state.mode}); re-engaging", level="warning",
                       sysid=sysid)
            await v.set_mode(want)
            self.reengaged[sysid] = self.reengaged.get(sysid, 0) + 1
        except Exception as exc:  # noqa: BLE001 - CommandError: reported, retried next tick
            self.event(f"vehicle {sysid}: could not re-engage {want}: {exc}", level="error", sysid=sysid)
            await self.clock.sleep(1.0)
        finally:
            self._reengaging.discard(sysid)

    def _start_background(self) -> None:
        from mission.telemetry.state_pub import StatePublisher

        if self._watchdog_task is None:
            self._watchdog_task = asyncio.get_running_loop().create_task(self._watchdog())
        if self._loss_task is None:
            self._loss_task = asyncio.get_running_loop().create_task(watch_losses(self))

        if self.session is not None and self._subscriber is None:
            self._subscriber = ReadingSubscriber(self.session, self.store)
        if self._state_pub is None:
            self._state_pub = StatePublisher(
                self.session, self.plan.fleet, self.snapshot, rate_hz=self.state_rate_hz,
                on_snapshot=self.display.update if self.display is not None else None)
            self._state_pub.start()

    async def _stop_background(self) -> None:
        for name in ("_watchdog_task", "_loss_task"):
            await cancel_and_wait(getattr(self, name))
            setattr(self, name, None)
        if self.ramp is not None:
            await self.ramp.stop()
        if self.streamer is not None:
            try:
                await self.streamer.stop()
            except Exception:  # noqa: BLE001
                pass
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
            self.log.write("plan", plan=_plan_json(self.plan), dry_run=True)
        self._start_background()
        try:
            await connect_phase.connect(self, required=False)
            await connect_phase.preflight(self)
        except MissionError as exc:
            self.event(str(exc), level="error")
        finally:
            await self._stop_background()
        ready = [r for r in self.readiness.values()]
        all_ready = len(ready) == len(self.plan.vehicles) and all(r.ready for r in ready)
        missing = [vp for vp in self.plan.vehicles if vp.sysid not in self.readiness]
        readiness = [asdict(r) | {"ready": r.ready} for r in ready] + [
            {"sysid": vp.sysid, "id": vp.id, "connection": vp.connection, "ready": False,
             "checks": {"connected": False}, "problems": ["not connected"]} for vp in missing]
        result = MissionResult(outcome="ready" if all_ready else "not_ready",
                               message="every vehicle is ready" if all_ready else
                               f"{sum(not r['ready'] for r in readiness)} vehicle(s) not ready",
                               readiness=readiness, readings=self.store.counts(),
                               mission_time_s=self.clock.time() - self._t_start)
        if self.log is not None:
            self.log.write("summary", sync=True, **result.to_json())
        return result

    async def run(self, resume_state=None) -> MissionResult:
        """Fly the whole mission and return its result (never raises for mission failures).

        Parameters
        ----------
        resume_state : mission.flight.resume.ResumeState, optional
            Go on with a stopped mission: reconnect, re-engage the vehicles still flying (no
            preflight, no takeoff), seek from the state's centre and iteration.

        Cancelling the task brings the vehicles home first, unless ``return_on_interrupt`` is
        False (a ground station that just stops: the vehicles do what their autopilot does).
        """
        if self.log is not None:
            self.log.write("plan", plan=_plan_json(self.plan), resumed=resume_state is not None)
        self._start_background()
        outcome, message = "aborted", ""
        try:
            if resume_state is None:
                await connect_phase.connect(self, required=True)
                await connect_phase.preflight(self)
                not_ready = [r for r in self.readiness.values() if not r.ready]
                if not_ready:
                    raise MissionError("preflight failed: " + "; ".join(
                        f"vehicle {r.sysid}: {', '.join(r.problems)}" for r in not_ready))
                await phases.takeoff(self)
                await phases.assemble(self)
                outcome, message = await seek.seek(self)
            else:
                await rejoin(self, resume_state)
                outcome, message = await seek.seek(self, start_iteration=resume_state.iteration,
                                                   history=resume_state.centres)
            self.set_phase("finish", outcome=outcome)
            self.event(message)
        except MissionError as exc:
            outcome, message = "aborted", str(exc)
            self.set_phase("aborted", reason=message)
            self.event(message, level="error")
        except Exception as exc:  # noqa: BLE001 - anything unexpected: still bring the vehicles home
            import traceback

            outcome, message = "aborted", f"unexpected error in phase {self.phase}: {type(exc).__name__}: {exc}"
            self.set_phase("aborted", reason=message)
            self.event(message, level="error", traceback=traceback.format_exc())
        except asyncio.CancelledError:
            outcome, message = "aborted", "interrupted"
            self.event("mission interrupted", level="error")
            if self.return_on_interrupt:
                await self._return_safely()
            await self._stop_background()
            raise
        try:
            await self._return_safely()
        finally:
            await self._stop_background()
        result = self.result(outcome, message)
        self.set_phase("done")
        if self.log is not None:
            self.log.write("summary", sync=True, **result.to_json())
        return result

    async def _return_safely(self) -> None:
        if not self.airborne:
            return
        try:
            await phases.return_home(self)
        except Exception as exc:  # noqa: BLE001 - last resort: land everyone where they are
            self.event(f"return failed ({exc}); landing every vehicle where it is", level="error")
            await phases.land_all_now(self)

    def result(self, outcome: str, message: str) -> MissionResult:
        """The :class:`MissionResult` of the mission so far."""
        t_end = self._t_seek_end or self.clock.time()
        return MissionResult(
            outcome=outcome, message=message,
            estimate_enu=None if self.estimate_enu is None else [float(x) for x in self.estimate_enu],
            spread_m=self.spread_m, iterations=self.iteration,
            mission_time_s=self.clock.time() - self._t_start,
            seek_time_s=0.0 if self._t_seek_start is None else t_end - self._t_seek_start,
            distance_flown_m=self.distance_flown_m,
            vehicle_distance_m={int(k): round(v, 2) for k, v in self.vehicle_distance_m.items()},
            readings=self.store.counts() | {"last_errors": self.store.last_errors()},
            readiness=[asdict(r) | {"ready": r.ready} for r in self.readiness.values()],
            log_path=None if self.log is None else str(self.log.path),
            reengaged=dict(self.reengaged), max_loop_lag_s=round(self.max_loop_lag_s, 4),
            lost=[{"sysid": x.sysid, "reason": x.reason, "detail": x.detail, "phase": x.phase,
                   "latency_s": round(x.latency_s, 3), "came_back_s": x.came_back_s}
                  for x in self.lost.values()], readmitted=list(self.readmitted),
            retired=[dict(asdict(x), ratio=round(x.ratio, 3)) for x in self.retired.values()])


def _plan_json(plan: Plan) -> dict:
    return to_jsonable(asdict(plan))
