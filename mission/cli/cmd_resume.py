"""``swarmseek resume LOG``: restart a stopped mission's coordinator from its mission log.

The plan comes from the log (its ``plan`` record) or from ``--plan`` (same vehicles). The
resumed coordinator reconnects, re-engages the vehicles still flying (no new takeoff) and goes on
seeking from the last centre and iteration, appending to the same log (see
:mod:`mission.flight.resume`). The mission clock is the wall clock: a ``swarmseek run`` log is
resumable only while its mock fleet still runs, i.e. in-process (the tests do that with
:func:`resume`). A log that ends after the seek (``return``, ``finish``, ``done``, a summary)
is taken over to bring the vehicles still flying home (outcome ``recovered``). Exit status: 0
converged, or recovered with every vehicle down or landing; 1 not converged / aborted / a
vehicle left airborne; 2 the log or plan cannot be resumed; 129 / 130 / 141 / 143 stopped by
SIGHUP / SIGINT / SIGPIPE / SIGTERM, 74 the mission log could not be written (as ``fly``: the
same stop handlers, :mod:`mission.flight.operator_stop`, and a best-effort terminal).
"""
from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from mission.core.zenoh_security import ZenohSecurityError

__all__ = ["configure", "main", "resume"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``resume`` options."""
    parser.add_argument("log", type=Path, help="mission.jsonl of the stopped mission")
    parser.add_argument("--plan", type=Path, default=None,
                        help="plan file (default: the plan recorded in the log)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end (no live display)")
    parser.add_argument("--no-tlog", action="store_true", help="do not write .tlog files")


async def resume(log_path: Path, *, plan=None, clock=None, display=None, tlog: bool = True, terminal=None):
    """Resume the mission of ``log_path``; returns the MissionResult.

    Parameters
    ----------
    log_path : path
        The stopped mission's log (appended to).
    plan : mission.core.plan.Plan, optional
        Instead of the log's plan record.
    clock : optional
        Mission clock (default: wall clock).
    display : mission.telemetry.display.Display, optional
    tlog : bool
        Write ``.tlog`` files next to the log (``tlogs/``, appended).
    terminal : mission.telemetry.terminal.Terminal, optional
        Its losses are told to the mission log.

    Raises
    ------
    mission.flight.resume.ResumeError
        The log cannot be resumed.
    """
    import zenoh

    from mission.core.clock import WallClock
    from mission.flight.coordinator import Coordinator
    from mission.flight.operator_stop import run_until_stopped
    from mission.link.forward import forwarding
    from mission.telemetry.watch_keys import with_keys
    from mission.telemetry.mission_log import MissionLog
    from mission.telemetry.terminal import told_to
    from mission.flight.resume import load_resume_state

    log_path = Path(log_path)
    state = load_resume_state(log_path, plan)
    clock = clock or WallClock()
    log = MissionLog(log_path, clock)
    session = None
    try:
        with told_to(terminal, log):
            session = zenoh.open(state.plan.zenoh.to_config())
            co = Coordinator(state.plan, clock=clock, zenoh_session=session, log=log, display=display,
                             tlog_dir=log_path.parent / "tlogs" if tlog else None)
            return await forwarding(co, with_keys(co, display, run_until_stopped(co, state)))  # as fly
    finally:
        log.close()
        if session is not None:
            session.close()


def main(args) -> int:
    """Resume the mission of ``args.log`` (the terminal best effort: :mod:`mission.telemetry.terminal`)."""
    from mission.telemetry.terminal import best_effort_terminal

    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result
    from mission.core.plan import PlanError, load_plan
    from mission.flight.resume import ResumeError

    from mission.cli.paths import writable_file_problem

    problem = writable_file_problem(args.log, "mission log")
    if problem:
        print(f"swarmseek resume: error: {problem}", file=sys.stderr)
        return 2
    plan = None
    if args.plan is not None:
        try:
            plan = load_plan(args.plan)
        except PlanError as exc:
            print(f"swarmseek resume: {exc}", file=sys.stderr)
            return 2
    import zenoh

    display = Display(quiet=args.json)
    try:
        result = asyncio.run(resume(args.log, plan=plan, display=display, tlog=not args.no_tlog,
                                    terminal=terminal))
    except ResumeError as exc:
        print(f"swarmseek resume: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:
        from mission.core.zenoh_errors import clean_zenoh_error

        print(f"swarmseek resume: cannot open the zenoh session: {clean_zenoh_error(exc)}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"swarmseek resume: cannot write the mission log: {exc}", file=sys.stderr)
        return 1
    except ZenohSecurityError as exc:  # e.g. the password file became unreadable since the plan loaded
        print(f"swarmseek resume: zenoh security settings: {exc}", file=sys.stderr)
        return 2
    from mission.flight.operator_stop import exit_status

    status = report_result(result, display, args.json)
    if result.outcome == "recovered" and not result.airborne_left:
        status = 0
    return exit_status(result, status)
