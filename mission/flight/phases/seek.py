"""The seek phase: move the formation centre up the estimated gradient until it converges.

One iteration (design choice: *move, settle, then estimate*):

1. every vehicle's goal is its slot about the current centre; the ramp moves the setpoints
   there at the speed limit and the loop waits until every vehicle is within ``arrival_tol_m``;
2. it waits (at most ``1 / rate_hz`` per iteration overall) for a reading from every vehicle taken
   after the arrival, then takes the estimation instant ``t = now`` and each vehicle's reading
   nearest ``t`` within ``reading_window_s``, with the position where it was taken;
3. gradient from those actual positions about their centroid (Theorem 2, ``method="cvt"``; or
   eq. 3, or the robust estimator), ``seek_step(eps, gamma)`` from the commanded centre (the
   plan's ``seeker = "gradient"``; ``"newton"``/``"model"``/``"plume"``: the seeker of
   :mod:`estimator.seekers` proposes the next centre from the readings and their positions,
   capped at ``gamma``), the safety envelope's ``clamp_centre``;
4. the convergence monitor sees the new centre and the iteration's signal (the ``plume`` seeker's
   own, else :class:`estimator.seek_signal.ArrivalSignal` on the readings: standing still at the
   background is not arrival); the iteration is logged.

Stop and go is the default because Theorem 2 needs the formation's shape: estimating while the
vehicles fly uses a formation distorted by tracking lag (``cond(M)`` and the noise grow). The
``newton`` and ``model`` seekers fit readings taken anywhere: with ``[seeking] sampling =
"moving"`` steps 1-2 are replaced by :mod:`mission.flight.phases.seek_moving` (re-plan once the move is
partly covered; the seeker gets every reading since the last estimate, where it was taken).
"""
from __future__ import annotations

import asyncio
from typing import Awaitable, Callable

import numpy as np

from estimator.estimate import SourceEstimate
from mission.core.plan_types import Plan
from mission.flight.control import OperatorStop
from mission.flight.fence_reach import source_in_reach
from mission.flight.motion import paced
from mission.flight.result import estimate_fields, geodetic_point, region_text
from mission.flight.phases.seek_moving import moving_sampling, thin_evenly
from mission.flight.seeking import GradientEstimate, make_seeker, ste_options, ste_wind
from mission.flight.sensor_check import make_check
from mission.flight.services import Clock, Fleet, PhaseEvents, SeekFormation, Waiter
from mission.flight.state import MissionError, MissionState
from mission.safety.gate import SafetyGate
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.readings import ReadingStore
from mission.telemetry.status_changes import StatusChanges

__all__ = ["Seek", "scaled_slots", "STE_READINGS_PER_VEHICLE"]

#: With moving sampling the ``ste`` seeker gets at most this many of each vehicle's readings per update
#: (:func:`mission.flight.phases.seek_moving.thin_evenly`); None: every reading, each with its time and vehicle,
#: weighed by the independent evidence it carries (:mod:`estimator.ste_tempering`; docs/seekers.md,
#: "ste in missions"). The thinning (1 before the filter took reading times) stays as an option.
STE_READINGS_PER_VEHICLE = None


def _not_converged(done: int, retried: int) -> str:
    """The ``max_iterations`` message: ``done`` iterations, ``retried`` tries without an estimate."""
    said = f"not converged after {done} iterations"
    return said if not retried else f"{said} ({retried} more tried without an estimate)"


class Seek:
    """The seek phase: the formation centre moved up the estimated gradient until it converges.

    Parameters
    ----------
    plan : Plan
        ``[seeking]``, ``[faults]``, the speed limit, the separation, the radius, the origin.
    state, fleet, gate, clock, events, waiter : MissionState, Fleet, SafetyGate, Clock, PhaseEvents, Waiter
    store : ReadingStore
        The readings.
    envelope : SafetyEnvelope or None
        The centre is clamped inside it.
    log : MissionLog or None
        Each iteration's record.
    formation : SeekFormation
        Losses, re-admission, retirement and the moves.
    checkpoint : callable
        ``await checkpoint()``: an operator's pause holds there, a stop raises (``MissionControl.checkpoint``).
    vehicle_status : callable
        ``vehicle_status() -> list[dict]``: every vehicle's status; the iteration record keeps
        what changed in it (:mod:`mission.telemetry.status_changes`).
    """

    def __init__(self, plan: Plan, state: MissionState, fleet: Fleet, gate: SafetyGate, clock: Clock,
                 events: PhaseEvents, waiter: Waiter, store: ReadingStore, envelope, log: MissionLog | None,
                 formation: SeekFormation, checkpoint: Callable[[], Awaitable[None]],
                 vehicle_status: Callable[[], list]) -> None:
        self.plan, self.state, self.fleet, self.gate, self.clock = plan, state, fleet, gate, clock
        self.events, self.waiter, self.store, self.envelope, self.log = events, waiter, store, envelope, log
        self.formation, self.checkpoint, self.vehicle_status = formation, checkpoint, vehicle_status
        self._status_changes = StatusChanges()  # the iteration records' status: what changed

    async def run(self, start_iteration: int = 0, history=()) -> tuple[str, str]:
        """Run the seek loop; returns ``(outcome, message)``.

        ``start_iteration`` and ``history`` (the last centres, oldest first) resume a stopped seek
        (:mod:`mission.flight.phases.resume`): iterations are numbered on, the convergence monitor is prefilled.
        A try that ends without an ``iteration`` record (a vehicle lost during it, too few aligned
        readings, no gradient) is made again under the same number, so the log's iterations are
        numbered 1, 2, 3, ... without a gap; every try counts towards ``max_iterations``.

        Outcomes: ``converged`` (also with the centre held at the fence shrunk by the radius when the
        source is inside the formation, :mod:`mission.flight.fence_reach`), ``max_iterations``,
        ``stopped_at_fence`` (the centre has been held at the geofence with the source out of the
        formation's reach, at convergence or for a whole convergence window: it is probably outside),
        ``too_few_vehicles`` (vehicles were lost and fewer than 4 are left: the caller brings the
        others home). After a loss the formation is re-formed for the survivors (``formation.reform``:
        :meth:`mission.flight.faults.loss.Reformation.reform`) before the next iteration; a returning
        vehicle is re-admitted (``[faults] readmit = true``, :meth:`mission.flight.faults.rejoin.Rejoin.readmit`);
        every iteration's slots are rotated clear of lost vehicles still flying
        (:meth:`mission.flight.faults.rejoin.Rejoin.clear_goals`). Whatever the seeker, the faulty-sensor
        detector (:mod:`mission.flight.sensor_check`) keeps the readings of the sensors it excludes out
        of the seeker's input, and a sensor it keeps naming is retired (``faulty_sensor = "retire"``,
        the default): its vehicle is parked at the centre, its readings ignored, the others re-formed
        (:mod:`mission.flight.faults.retire`); only sensing vehicles count towards the 4.
        """
        self.events.set_phase("seek")
        self._start(history)
        self.state.begin_seek()
        ended = None
        k = int(start_iteration)  # iterations done (recorded); the next one is k + 1
        tries = range(int(start_iteration), self.plan.seeking.max_iterations)
        for _ in tries:  # every try counts towards max_iterations, as before
            await self.checkpoint()  # an operator's pause holds here, a stop ends the seek
            ended = await self.iteration(k)
            if ended is not None:
                break
            if self.state.iteration == k + 1:  # done and recorded: number on; else the same k again
                k += 1
        self.state.end_seek()  # not on a MissionError: the seek time of an aborted mission runs to its end
        return ended or ("max_iterations", _not_converged(k, len(tries) - (k - int(start_iteration))))

    def _start(self, history=()) -> None:
        """The seek loop's own state (formation members, estimator, monitor, centre)."""
        from estimator.seek_confirm import SeekConvergenceMonitor
        from estimator.seek_signal import ArrivalSignal

        state = self.state
        self.sk = sk = self.plan.seeking
        # the formation's vehicles: those under setpoints, and those lost since their slot was
        # given (the loop re-forms without them first)
        self.sysids = sorted(s for s in state.slot_offsets
                             if (s in self.gate.sysids or s in state.lost) and s not in state.retired)
        flying = [s for s in self.sysids if s not in state.lost]
        if len(flying) < 4:
            raise MissionError(f"seek needs at least 4 vehicles in formation, have {len(flying)}")
        self.est_kind = sk.estimator
        self.estimate = GradientEstimate(self.est_kind, len(self.sysids))
        ste = ste_options(sk, self.plan.geofence) if sk.seeker == "ste" else {}
        wind_from_deg = sk.wind_from_deg
        if sk.seeker == "ste":
            wind_from_deg, ste["wind_std_deg"], said = ste_wind(
                sk, [v.state.snapshot() for v in self.fleet.vehicles.values()], self.clock.time())
            self.events.event(said)
        self.seeker = make_seeker(sk.seeker, wind_from_deg, sk.plume_mode, **ste)
        self.moving = moving_sampling(self.clock, self.store, self.events, sk)
        self.samples = None  # with moving sampling: the readings the seeker gets this iteration
        self.check = make_check(self.plan.faults, self.estimate, self.sysids)
        self.watch = self.formation.make_watch(self.check, self.sysids)
        self.monitor = SeekConvergenceMonitor(window=sk.convergence_window, tol_m=sk.convergence_tol_m,
                                              min_signal_fraction=sk.min_signal_fraction, hold=sk.region_hold)
        self.arrival = ArrivalSignal()  # the convergence test's signal when the seeker has none
        self.centre = np.asarray(state.centre_enu, dtype=float).copy()
        for c in history:
            self.monitor.update(np.asarray(c, dtype=float))
        if not len(history):
            self.monitor.update(self.centre)
        self.period_s = 1.0 / sk.rate_hz
        self.last_estimate_t = -np.inf
        self.failures = 0
        self.at_fence = 0  # consecutive iterations with the centre held at the (shrunk) fence
        self.beyond_reach = 0  # ... of them with the source out of the formation's reach (fence_reach)

    def _new_estimator(self, symmetric_to_cvt: bool = True) -> None:
        """A fresh estimator (and retirement watch) for the current members."""
        if symmetric_to_cvt and self.state.formation_kind == "cvt" and self.est_kind == "symmetric":
            self.est_kind = "cvt"
        self.estimate = GradientEstimate(self.est_kind, len(self.sysids))
        self.check = make_check(self.plan.faults, self.estimate, self.sysids)
        self.watch = self.formation.make_watch(self.check, self.sysids)

    async def iteration(self, k: int) -> tuple[str, str] | None:
        """One iteration: re-form, move, readings, estimate, step; ``(outcome, message)`` when it ends."""
        ended = await self._update_members()
        if ended is not None:
            return ended
        t_arrive = await self._move(k)
        await self._wait_readings(k, t_arrive)
        if any(s in self.state.lost for s in self.sysids):
            return None  # lost during this iteration: re-form first
        found = await self._estimate(k, t_arrive)
        if found is None:
            return None
        ended = await self._step(k, *found)
        if ended is None and found[-1] is not None:
            self.sysids = await self.formation.retire_sensor(self.centre, self.sysids, found[-1])
            self._new_estimator(symmetric_to_cvt=False)
        return ended

    async def _update_members(self) -> tuple[str, str] | None:
        """Re-form without lost vehicles, re-admit returning ones; the end when fewer than 4 are left."""
        if any(s in self.state.lost for s in self.sysids):
            self.sysids = await self.formation.reform(self.centre, self.sysids)
            if len(self.sysids) < 4:
                return "too_few_vehicles", (f"vehicles {sorted(self.state.lost)} lost: {len(self.sysids)} left, a "
                                            "formation needs 4; ending the mission, the others come home")
            self._new_estimator()
        returning = await self.formation.keep_out_retired(self.formation.pending_readmissions())
        if returning:
            self.sysids = await self.formation.readmit(self.centre, self.sysids, returning)
            self._new_estimator()
        return None

    async def _move(self, k: int) -> float:
        """Fly the formation to its slots about the centre and settle; the arrival time (moving
        sampling: set the goals and return once the move is covered enough, :mod:`mission.flight.phases.seek_moving`)."""
        if self.moving is not None:
            return await self.moving.move(self, k)
        sk = self.sk
        before = {s: self.state.slot_offsets[s].copy() for s in self.sysids}
        formation = self.formation
        formation.clear_goals(self.centre, self.sysids)  # a few ms at most: slots clear of lost vehicles still flying
        await formation.fly_rotation(self.centre, self.sysids, before)  # a rotation is flown as a planned transfer
        goals = formation.formation_goals(self.centre, self.sysids)  # parked vehicles (retired sensors) at the centre
        try:
            await formation.move_and_wait(goals, sk.arrival_tol_m,
                                          timeout_s=20.0 + 3.0 * sk.gamma_m / self.plan.max_speed_m_s,
                                          what=f"iteration {k + 1}: the formation to settle")
        except OperatorStop:
            raise
        except MissionError as exc:
            self.events.event(f"{exc}; estimating anyway", level="warning")
        return await paced(self.clock, self.period_s, self.last_estimate_t)

    async def _wait_readings(self, k: int, t_arrive: float) -> None:
        """Wait for a reading taken after the arrival from every vehicle (a warning after a while)."""
        if self.moving is not None:
            return await self.moving.wait_readings(self, k, t_arrive)
        sk = self.sk

        def _fresh():
            return all((r := self.store.latest(s)) is not None and r.time_s >= t_arrive
                       for s in self.sysids if s not in self.state.lost)

        try:
            await self.waiter.wait_until(_fresh, max(5.0, 10 * sk.reading_window_s), "fresh readings", poll_s=0.02)
        except OperatorStop:
            raise
        except MissionError:
            missing = [s for s in self.sysids if (r := self.store.latest(s)) is None or r.time_s < t_arrive]
            self.events.event(f"iteration {k + 1}: no fresh reading from vehicles {missing}", level="warning")

    async def _estimate(self, k: int, t_arrive: float):
        """Aligned readings and the gradient: ``(t_est, aligned, used, centroid, grad, retiring)`` or None."""
        from estimator import GeometryError

        sk = self.sk
        # estimation instant: the oldest of the vehicles' newest readings, so that every vehicle
        # has a reading at or after it (robust to delivery latency, e.g. at a high speed-up)
        latest = [self.store.latest(s) for s in self.sysids]
        fresh = [r.time_s for r in latest if r is not None and r.time_s >= t_arrive]
        t_est = min(fresh) if len(fresh) == len(self.sysids) else self.clock.time()
        self.last_estimate_t = self.clock.time()
        aligned = self.store.aligned(t_est, sk.reading_window_s, self.sysids)
        if not await self._enough(k, aligned):
            return None
        used = sorted(aligned)
        positions = np.array([aligned[s].position_enu_m for s in used])
        values = np.array([aligned[s].value for s in used])
        # the estimate is taken about the centroid of the actual positions, not the commanded
        # centre: with sigma_c = mean of the readings (Theorem 2) or eq. 3, a common offset of the
        # vehicles from their slots (tracking lag) would otherwise bias the gradient by about
        # 3 sigma offset / D^2, enough to make the centre oscillate near the source
        centroid = positions.mean(axis=0)
        try:
            grad = np.asarray(self.estimate(positions, values, centroid), dtype=float)
        except (GeometryError, ValueError) as exc:
            self.failures += 1
            self.events.event(f"iteration {k + 1}: gradient not estimated: {exc}", level="warning")
            if self.failures >= 20:
                raise MissionError(f"no gradient estimate for {self.failures} iterations (last: {exc})") from None
            return None
        self.failures = 0
        grad = self._checked(k, used, positions, values, centroid, grad)
        self.samples = None if self.moving is None else self.moving.collect(used)
        retiring = None if self.watch is None else self.watch.update(self.check, used, k + 1, self.clock.time())
        return t_est, aligned, used, centroid, grad, retiring

    def _checked(self, k: int, used: list[int], positions, values, centroid, grad) -> np.ndarray:
        """Feed the faulty-sensor detector; the gradient without its excluded sensors (the paper's step
        with a non-robust estimator: Theorem 2 on the others), else ``grad``."""
        if self.check is None:
            return grad
        self.check.update(used, positions, values, centroid)
        if self.check.failure and not self.check.shared and len(used) == len(self.check.sysids):
            self.events.event(f"iteration {k + 1}: faulty-sensor check not updated: {self.check.failure}",
                          level="warning")
        if self.check.newly_excluded and self.seeker is not None:
            self.seeker.reset()
            self.events.event(f"iteration {k + 1}: sensors {sorted(self.check.newly_excluded)} excluded as faulty: "
                          f"their readings left out, the {self.sk.seeker} seeker's memory reset", level="warning",
                          sysids=sorted(self.check.newly_excluded))
        alt = self.check.gradient(positions, values, used)
        return grad if alt is None else alt

    async def _enough(self, k: int, aligned: dict) -> bool:
        """At least 4 aligned readings (all of them for the robust estimator); else warn and wait."""
        if len(aligned) < 4:
            self.failures += 1
            self.events.event(f"iteration {k + 1}: only {len(aligned)} aligned readings (need 4); waiting",
                     level="warning", counts=self.store.counts())
            if self.failures >= 20:
                raise MissionError(f"no usable readings for {self.failures} iterations "
                                   f"(rejections: {self.store.counts()['rejected']})")
            await self.clock.sleep(1.0)
            return False
        if self.estimate.needs_all and len(aligned) < len(self.sysids):
            # the robust estimator tracks each sensor by its index: estimate only with all of them
            self.events.event(f"iteration {k + 1}: {len(aligned)} of {len(self.sysids)} readings aligned; the robust "
                     "estimator needs all; waiting", level="warning")
            await self.clock.sleep(0.5)
            return False
        return True

    def _clamped(self, new_centre: np.ndarray) -> np.ndarray:
        """The new centre held inside the safety envelope (counts the iterations at the fence)."""
        if self.envelope is None:
            return new_centre
        clamp = self.envelope.clamp_centre(self.centre, new_centre)
        if not clamp.at_boundary:
            self.at_fence = 0
            return new_centre
        self.at_fence += 1
        if self.at_fence in (1, self.sk.convergence_window):
            self.events.event(clamp.message, level="warning")
        return np.asarray(clamp.centre_enu, dtype=float)

    def _own_estimate(self) -> SourceEstimate | None:
        """The seeker's own estimate of the source (``source_estimate(0)``; for ``ste`` a summary of
        its whole posterior), None without a seeker or without an estimate of its own. Asked once
        per iteration: the estimate reported is the one the fence's reach check judges."""
        return None if self.seeker is None else self.seeker.seeker.source_estimate(0)

    def _in_reach(self, requested, held, own: SourceEstimate | None) -> bool:
        """Whether the source is within reach of the formation held at ``held`` though the seeker
        asked for ``requested``, ``own`` the seeker's own estimate of this iteration
        (:meth:`_own_estimate`; :func:`mission.flight.fence_reach.source_in_reach`)."""
        return source_in_reach(held, requested, None if own is None else own.enu, self.envelope.formation_radius_m,
                               self.sk.convergence_tol_m, self.envelope.fence)

    def _seeker_inputs(self, aligned: dict, used: list[int]) -> tuple[list, list]:
        """This iteration's readings (logged) and where the seeker takes them to be: each vehicle's aligned
        one, or every one since the last estimate (:meth:`~mission.flight.phases.seek_moving.MovingSampling.collect`)."""
        if self.samples is None:
            return [aligned[s] for s in used], [aligned[s].position_enu_m for s in used]
        return self.samples, self.moving.positions_enu

    async def _step(self, k, t_est, aligned, used, centroid, grad, retiring) -> tuple[str, str] | None:
        """Move the centre up the gradient, log the iteration; ``(outcome, message)`` when the seek ends."""
        from estimator import seek_step

        sk = self.sk
        readings, positions = self._seeker_inputs(aligned, used)
        kept, positions = (readings, positions) if self.check is None else self.check.keep(readings, positions)
        if self.seeker is None:  # the paper's step with the plan's estimator (robust included)
            proposed = seek_step(self.centre, grad, sk.eps, sk.gamma_m)
        else:
            if self.samples is not None and self.seeker.converges_itself and STE_READINGS_PER_VEHICLE:
                kept, positions = thin_evenly(kept, positions, STE_READINGS_PER_VEHICLE)  # an option (above)
            proposed = await self._propose(k, positions, [r.value for r in kept], [r.time_s for r in kept],
                                           [r.sysid for r in kept])
        new_centre = self._clamped(proposed)
        step_m = float(np.linalg.norm(new_centre - self.centre))
        arrival = None if self.seeker is None else self.seeker.arrival
        dropped = set() if self.check is None else self.check.dropped
        signal = self.arrival.signal([aligned[s].value for s in used if s not in dropped])
        own = self._own_estimate()  # asked once: the confirmation, the report and the reach check share it
        converged = self.monitor.update(new_centre, signal if arrival is None else arrival,  # estimator.seek_confirm
                                        own, centroid)
        if self.seeker is not None and self.seeker.converges_itself:  # ste: its posterior's region
            converged = bool(arrival)
        # the source estimate with its 95 % region: the seeker's own, else the monitor's mean of the
        # centres (the rule of :func:`estimator.estimate.reported_estimate`)
        source = own if own is not None else self.monitor.source_estimate()
        held = self.at_fence and not self._in_reach(proposed, new_centre, own)
        self.beyond_reach = self.beyond_reach + 1 if held else 0
        self.state.record_iteration(k + 1, grad, step_m, source, self.monitor.spread_m)
        if self.log is not None:
            everyone = self.sysids + self.formation.parked()
            self.log.write("iteration", k=k + 1, t_estimate_s=t_est, centre_enu=self.centre, centroid_enu=centroid,
                         gradient=grad, new_centre_enu=new_centre, step_m=step_m, estimate_enu=self.state.estimate_enu,
                         **estimate_fields(source),
                         estimate_geodetic=geodetic_point(self.plan.origin, self.state.estimate_enu),
                         spread_m=self.state.spread_m, distance_flown_m=self.state.distance_flown_m,
                         converged_by=self.monitor.declared_by,
                         readings=readings,
                         positions_enu={s: self.fleet.telemetry_position(s) for s in everyone},
                         setpoints_enu={s: self.gate.setpoint(s) for s in everyone},
                         suspects=_suspects(self.check or self.estimate, used),
                         status_changes=self._status_changes.changes(self.vehicle_status()))
        self.centre = new_centre
        self.state.move_centre(new_centre)
        self._resize(k)
        return self._ended(k, converged)

    def _resize(self, k: int) -> None:
        """Honour the seeker's ``formation_radius_m`` (``ste``): the sensing vehicles' slots scaled
        about the centre (:func:`scaled_slots`), never wider than the plan's radius nor so tight that
        two slots are closer than 1.2 ``min_separation_m``; the next move flies them there."""
        want = None if self.seeker is None else self.seeker.formation_radius_m
        members = [s for s in self.sysids if s not in self.state.lost and s in self.state.slot_offsets]
        if want is None or len(members) < 2:
            return
        new = scaled_slots({s: self.state.slot_offsets[s] for s in members}, want, self.plan.min_separation_m,
                           self.plan.formation.radius_m)
        if new is not None:
            self.state.update_slots(new)

    async def _propose(self, k: int, positions, values, times_s=None, sysids=None) -> np.ndarray:
        """The seeker's next centre (capped at ``gamma_m``) from the readings ``values`` taken (to be) at
        ``positions``, at ``times_s`` by vehicles ``sysids`` (for a seeker that takes reading times); its
        failure (a hold) and a collapse of its posterior (re-seeded from the prior about the formation)
        are events of the mission log. The ``ste`` seeker's update (tens of ms and more) runs in the
        loop's executor."""
        sk = self.seeker
        if sk.converges_itself:
            proposed = await asyncio.get_running_loop().run_in_executor(
                None, sk.step, self.centre.copy(), positions, values, self.sk.gamma_m, times_s, sysids)
        else:
            proposed = sk.step(self.centre, positions, values, self.sk.gamma_m, times_s, sysids)
        if sk.failure:
            self.events.event(f"iteration {k + 1}: {sk.failure}", level="warning")
        if sk.collapsed:
            self.events.event(f"iteration {k + 1}: the {self.sk.seeker} seeker's posterior collapsed (no particle "
                          f"explained the {len(values)} readings); re-seeded from the prior about the formation "
                          f"(collapse {sk.collapses})", level="warning", collapses=sk.collapses)
        return proposed

    def _ended(self, k: int, converged: bool) -> tuple[str, str] | None:
        """``(outcome, message)`` when the seek ends after iteration ``k``, else None."""
        centre = self.centre
        if converged and self.beyond_reach:
            return "stopped_at_fence", (f"stopped at the geofence after {k + 1} iterations, centre held at "
                                        f"({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}) m: the "
                                        "source is probably outside the fence (shrunk by the radius)")
        if converged:
            e = self.state.estimate_enu
            held = (" (the centre held at the fence shrunk by the formation radius, the source inside the "
                    "formation)") if self.at_fence else ""
            return "converged", (f"converged after {k + 1} iterations: source at ({e[0]:.2f}, {e[1]:.2f}, "
                                 f"{e[2]:.2f}) m, {region_text(self.state.estimate_region95_m)}, spread "
                                 f"{self.state.spread_m:.2f} m{held}")
        if self.beyond_reach >= self.sk.convergence_window:
            return "stopped_at_fence", ("the formation centre has been held at the geofence for "
                                        f"{self.beyond_reach} iterations, the source out of the formation's reach: "
                                        "it is probably outside the fence")
        return None


def scaled_slots(offsets: dict, radius_m: float, min_separation_m: float, max_radius_m: float) -> dict | None:
    """``offsets`` (sysid -> slot offset about the centre, ENU m) scaled about the centre so that
    their mean distance from it is ``radius_m``, clipped so that no slot is farther than
    ``max_radius_m`` from it (the plan's radius: the fence and altitude checks assumed it) and to
    the smallest scale whose closest pair of slots is ``1.2 min_separation_m`` apart; None when the
    scale would change by less than 5 %."""
    keys = sorted(offsets)
    off = np.array([offsets[s] for s in keys], dtype=float)
    norms = np.linalg.norm(off, axis=1)
    mean_r = float(norms.mean())
    d = np.linalg.norm(off[:, None, :] - off[None, :, :], axis=-1)
    closest = float(d[np.triu_indices(len(keys), 1)].min())
    if mean_r <= 0 or closest <= 0:
        return None
    lo = 1.2 * min_separation_m * mean_r / closest
    hi = max_radius_m * mean_r / float(norms.max())
    target = min(max(float(radius_m), lo), max(hi, lo))
    scale = target / mean_r
    if abs(scale - 1.0) < 0.05:
        return None
    return {s: off[i] * scale for i, s in enumerate(keys)}


def _suspects(source, used: list[int]) -> list[dict] | None:
    """The suspect sensors of ``source``, the faulty-sensor detector (a
    :class:`~mission.flight.sensor_check.SensorCheck`, its sensors its ``sysids``) or the seek's
    :class:`GradientEstimate` (its sensors the ``used`` vehicles), as ``{sysid, reason, excluded,
    noise_std}``; None when it has none (not the robust estimator)."""
    order = used if source.sysids is None else source.sysids
    try:
        found = source.suspects()
        if found is None:
            return None
        return [{"sysid": order[s.index], "reason": s.reason, "excluded": bool(s.excluded),
                 "noise_std": float(s.noise_std)} for s in found]
    except (AttributeError, IndexError, ValueError):
        return None
