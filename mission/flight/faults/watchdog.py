"""The coordinator's watchdog: odometry, event-loop lag, status records, and re-engaging after a failsafe."""
from __future__ import annotations

import asyncio

from mission.core.tasks import spawn
from mission.flight.modes import GUIDED_MODES, LEFT_MODES
from mission.telemetry.link_report import format_rejections, rejection_increase

__all__ = ["watchdog"]


async def watchdog(co, period_s: float = 0.1) -> None:
    """Odometry, event-loop lag, and re-engaging OFFBOARD/GUIDED after a setpoint-loss failsafe.

    A vehicle under the mission's setpoints (takeoff done, not returning) found in another
    mode is switched back (PX4 falls back to hold when setpoints pause for COM_OF_LOSS_T;
    the stream resumes at once, so re-engaging is safe); each time is logged and counted.
    """
    loop = asyncio.get_running_loop()
    next_status_s = co.clock.time()
    rejections = _RejectionReport(co)
    while True:
        t0 = loop.time()
        await asyncio.sleep(period_s)
        co.state.note_loop_lag(loop.time() - t0 - period_s)
        co.update_odometry()
        rejections.check()
        if co.log is not None and co.vehicles and co.clock.time() >= next_status_s:
            next_status_s = co.clock.time() + co.status_period_s
            co.log.write("status", phase=co.state.phase, centre_enu=co.state.centre_enu, vehicles=co.vehicle_status(),
                         link_rejections=co.link_rejections(), unknown_sysids=co.unknown_sysids())
        if co.state.phase not in ("assemble", "seek", "finish", "return") or co.gate is None:
            continue
        for sysid in co.gate.sysids:
            v = co.vehicles.get(sysid)
            want = GUIDED_MODES.get(getattr(v, "flavour", None))
            if (v is None or want is None or sysid in co.state.reengaging or sysid in co.state.released
                    or sysid in co.state.lost or v.state.mode == want):
                continue
            if v.state.mode in LEFT_MODES.get(v.flavour, ()) or v.link_age_s() > co.plan.faults.link_timeout_s:
                continue  # left the mission or silent: mission.flight.faults.loss decides, never re-engaged
            if not v.state.armed:
                continue
            co.state.begin_reengaging(sysid)
            spawn(_reengage(co, sysid, v, want), f"re-engaging vehicle {sysid}", co.task_failed)


class _RejectionReport:
    """A warning event when the links refuse frames: at once for the first, then at most once a
    status period (``co.status_period_s``), with the increase by kind and the totals.

    Steady refused traffic of kinds already reported (e.g. a companion computer's system id 255
    that the autopilot forwards, every second) is reported at doubling intervals, up to
    :attr:`MAX_PERIOD_S`; a new kind, or a new unknown system id, resets the interval. The totals
    are always in the live display, the state publication and the summary.
    """

    MAX_PERIOD_S = 60.0

    def __init__(self, co) -> None:
        self.co = co
        self.reported: dict[str, int] = {}
        self.unknown: list[int] = []
        self.next_s = co.clock.time()
        self.period_s = float(co.status_period_s)

    def check(self) -> None:
        """Report what grew since the last report, if a report is due."""
        co = self.co
        now, unknown = co.link_rejections(), co.unknown_sysids()
        grew = rejection_increase(self.reported, now)
        new_ids = [s for s in unknown if s not in self.unknown]
        new_kinds = [k for k in grew if not self.reported.get(k)]
        if not (new_kinds or new_ids) and (not grew or co.clock.time() < self.next_s):
            return
        self.period_s = (float(co.status_period_s) if new_kinds or new_ids
                         else min(self.period_s * 2.0, max(self.MAX_PERIOD_S, float(co.status_period_s))))
        self.reported, self.unknown = now, unknown
        self.next_s = co.clock.time() + self.period_s
        if grew:
            co.event(f"MAVLink frames rejected: {format_rejections(grew)} (totals {format_rejections(now)})",
                     level="warning", link_rejections=now, increase=grew)
        if new_ids:
            co.event(f"MAVLink system id(s) {new_ids} heard, not in the plan: ignored", level="warning",
                     unknown_sysids=unknown)


async def _reengage(co, sysid: int, v, want: str) -> None:
    """Switch ``v`` back to ``want``; counted when it worked, reported (and retried later) when not."""
    done = False
    try:
        co.event(f"vehicle {sysid} left {want} (now {v.state.mode}); re-engaging", level="warning",
                 sysid=sysid)
        await v.set_mode(want)
        done = True
    except Exception as exc:  # noqa: BLE001 - CommandError: reported, retried next tick
        co.event(f"vehicle {sysid}: could not re-engage {want}: {exc}", level="error", sysid=sysid)
        await co.clock.sleep(1.0)
    finally:
        co.state.end_reengaging(sysid, succeeded=done)
