"""The coordinator's watchdog: odometry, event-loop lag, status records, and re-engaging after a failsafe."""
from __future__ import annotations

import asyncio
from typing import Callable, Protocol

from mission.core.plan_types import FaultsPlan
from mission.core.tasks import spawn
from mission.flight.faults.loss import autopilot_failsafe, data_link_acts, offboard_loss_mode, own_stream_gap_s
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.flight.services import Clock, Events, Fleet
from mission.flight.state import MissionState
from mission.safety.gate import SafetyGate
from mission.telemetry.link_report import format_rejections, rejection_increase
from mission.telemetry.mission_log import MissionLog

__all__ = ["LinkHealth", "MissionStatus", "REENGAGED_PHASES", "RejectionReport", "Watchdog"]

#: the phases in which a vehicle under the mission's setpoints that fell out of its mission mode is
#: re-engaged; the takeoff too: the vehicles already climbing or holding at their layer while another
#: one's arming is retried (up to ``[preflight] autopilot_ready_timeout_s``) are watched like later
REENGAGED_PHASES = ("takeoff", "assemble", "seek", "finish", "return")


class LinkHealth(Protocol):
    """What the mission's MAVLink links refused so far."""

    def link_rejections(self) -> dict[str, int]:
        """Frames refused by the mission's endpoints, by kind (non-zero only)."""

    def unknown_sysids(self) -> list[int]:
        """System ids heard on the links that are no vehicle of the plan."""


class MissionStatus(LinkHealth, Protocol):
    """:class:`LinkHealth`, the vehicles' status and their odometry (the ``status`` records)."""

    def update_odometry(self) -> None:
        """Accumulate each vehicle's flown distance from telemetry."""

    def vehicle_status(self) -> list[dict]:
        """Per-vehicle status dicts."""


class Watchdog:
    """Odometry, event-loop lag, status records, and re-engaging OFFBOARD/GUIDED after a failsafe.

    Parameters
    ----------
    state : MissionState
        The phase, who is released, lost or being re-engaged; the loop lag is noted there.
    fleet : Fleet
        The connected vehicles.
    gate : callable
        ``gate()``: the safety gate now (None before the setpoints stream); the watchdog runs
        from before the connection to the end.
    clock : Clock
        The mission clock.
    faults : FaultsPlan
        The plan's ``[faults]`` (``link_timeout_s``: a silent vehicle is never re-engaged).
    status : MissionStatus
        The vehicles' status, odometry and the links' refusals.
    log : MissionLog or None
        Where the ``status`` records go.
    status_period_s : float
        A ``status`` record this often (mission clock); refused frames are reported at most as often.
    events : Events
        Re-engagements and refused frames told to the operator.
    report : callable
        ``report(message)``: a failed background re-engagement (:func:`mission.core.tasks.spawn`).
    """

    def __init__(self, state: MissionState, fleet: Fleet, gate: Callable[[], SafetyGate | None], clock: Clock,
                 faults: FaultsPlan, status: MissionStatus, log: MissionLog | None, status_period_s: float,
                 events: Events, report: Callable[[str], None]) -> None:
        self.state, self.fleet, self.gate, self.clock, self.faults = state, fleet, gate, clock, faults
        self.status, self.log, self.status_period_s = status, log, float(status_period_s)
        self.events, self.report = events, report

    async def run(self, period_s: float = 0.1) -> None:
        """Every ``period_s`` (event-loop time), until cancelled.

        A vehicle under the mission's setpoints (from its takeoff, also while another vehicle's
        arming is still retried, until the return; :data:`REENGAGED_PHASES`) found in another
        mode is switched back (PX4 falls back to hold when setpoints pause for COM_OF_LOSS_T;
        the stream resumes at once, so re-engaging is safe); each time is logged and counted.
        Never one whose autopilot took over for a failsafe of its own (RTL/LAND, or its heartbeat
        in a failsafe state while the setpoints never paused:
        :func:`mission.flight.faults.loss.autopilot_failsafe`): it is handed to that failsafe.
        """
        loop = asyncio.get_running_loop()
        next_status_s = self.clock.time()
        rejections = RejectionReport(self.status, self.clock, self.events, self.status_period_s)
        while True:
            t0 = loop.time()
            await asyncio.sleep(period_s)
            self.state.note_loop_lag(loop.time() - t0 - period_s)
            self.status.update_odometry()
            rejections.check()
            if self.log is not None and self.fleet.vehicles and self.clock.time() >= next_status_s:
                next_status_s = self.clock.time() + self.status_period_s
                self.log.write("status", phase=self.state.phase, centre_enu=self.state.centre_enu,
                               vehicles=self.status.vehicle_status(),
                               link_rejections=self.status.link_rejections(),
                               unknown_sysids=self.status.unknown_sysids())
            gate = self.gate()
            if self.state.phase in REENGAGED_PHASES and gate is not None:
                self._reengage_fallen(gate)

    def _reengage_fallen(self, gate: SafetyGate) -> None:
        """Start re-engaging each vehicle under setpoints found armed, heard, in neither its
        mission mode nor a mode that left the mission (:mod:`mission.flight.faults.loss` decides those)."""
        state = self.state
        for sysid in gate.sysids:
            v = self.fleet.vehicles.get(sysid)
            want = None if v is None else GUIDED_MODES.get(v.flavour)
            if (v is None or want is None or sysid in state.reengaging or sysid in state.released
                    or sysid in state.lost or v.state.mode == want):
                continue
            if v.state.mode in LEFT_MODES.get(v.flavour, ()) or v.link_age_s() > self.faults.link_timeout_s:
                continue  # left the mission or silent: mission.flight.faults.loss decides, never re-engaged
            if not v.state.armed:
                continue
            loss_mode = offboard_loss_mode(state, sysid, v.flavour)
            dll = data_link_acts(state, sysid, v.flavour)
            if autopilot_failsafe(v, own_stream_gap_s(gate, sysid, v), loss_mode, dll) is not None:
                continue  # its autopilot's own failsafe (not our pause): handed to it; loss declares it left
            state.begin_reengaging(sysid)
            spawn(self._reengage(sysid, v, want), f"re-engaging vehicle {sysid}", self.report)

    async def _reengage(self, sysid: int, v, want: str) -> None:
        """Switch ``v`` back to ``want``; counted when it worked, reported (and retried later) when not."""
        done = False
        try:
            self.events.event(f"vehicle {sysid} left {want} (now {v.state.mode}); re-engaging", level="warning",
                              sysid=sysid)
            await v.set_mode(want)
            done = True
        except Exception as exc:  # noqa: BLE001 - CommandError: reported, retried next tick
            self.events.event(f"vehicle {sysid}: could not re-engage {want}: {exc}", level="error", sysid=sysid)
            await self.clock.sleep(1.0)
        finally:
            self.state.end_reengaging(sysid, succeeded=done)


class RejectionReport:
    """A warning event when the links refuse frames: at once for the first, then at most once a
    status period, with the increase by kind and the totals.

    Steady refused traffic of kinds already reported (e.g. a companion computer's system id 255
    that the autopilot forwards, every second) is reported at doubling intervals, up to
    :attr:`MAX_PERIOD_S`; a new kind, or a new unknown system id, resets the interval. The totals
    are always in the live display, the state publication and the summary.

    Parameters
    ----------
    links : LinkHealth
        The links' refusals so far.
    clock : Clock
        The mission clock.
    events : Events
        Where the warnings go.
    status_period_s : float
        The shortest interval between two reports.
    """

    MAX_PERIOD_S = 60.0

    def __init__(self, links: LinkHealth, clock: Clock, events: Events, status_period_s: float) -> None:
        self.links, self.clock, self.events = links, clock, events
        self.status_period_s = float(status_period_s)
        self.reported: dict[str, int] = {}
        self.unknown: list[int] = []
        self.next_s = clock.time()
        self.period_s = self.status_period_s

    def check(self) -> None:
        """Report what grew since the last report, if a report is due."""
        now, unknown = self.links.link_rejections(), self.links.unknown_sysids()
        grew = rejection_increase(self.reported, now)
        new_ids = [s for s in unknown if s not in self.unknown]
        new_kinds = [k for k in grew if not self.reported.get(k)]
        if not (new_kinds or new_ids) and (not grew or self.clock.time() < self.next_s):
            return
        base = self.status_period_s
        self.period_s = base if new_kinds or new_ids else min(self.period_s * 2.0, max(self.MAX_PERIOD_S, base))
        self.reported, self.unknown = now, unknown
        self.next_s = self.clock.time() + self.period_s
        if grew:
            self.events.event(f"MAVLink frames rejected: {format_rejections(grew)} (totals {format_rejections(now)})",
                              level="warning", link_rejections=now, increase=grew)
        if new_ids:
            self.events.event(f"MAVLink system id(s) {new_ids} heard, not in the plan: ignored", level="warning",
                              unknown_sysids=unknown)
