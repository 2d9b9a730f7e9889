"""``swarmseek resume LOG``: restart a stopped mission's coordinator from its mission log.

The plan comes from the log (its ``plan`` record) or from ``--plan`` (same vehicles). The
resumed coordinator reconnects, re-engages the vehicles still flying (no new takeoff) and goes on
seeking from the last centre and iteration, appending to the same log (see
:mod:`mission.flight.resume`). The mission clock is the wall clock: a ``swarmseek run`` log is
resumable only while its mock fleet still runs, i.e. in-process (the tests do that with
:func:`resume`). Only a log cut in the takeoff, assembly or seek (or stopped there by a ground station told to
just stop) seeks on; every other ending (finished, returning, aborted, interrupted with the
return: :mod:`mission.flight.resume_endings`) is taken over to bring the vehicles still flying home
(outcome ``recovered``). Exit status: 0 converged, or recovered with every vehicle down or landing
and none left armed; 1 not converged / aborted / a
vehicle left airborne; 2 the log or plan cannot be resumed; 129 / 130 / 141 / 143 stopped by
SIGHUP / SIGINT / SIGPIPE / SIGTERM, 74 the mission log could not be written (as ``fly``: the
same stop handlers, :mod:`mission.flight.operator_stop`, and a best-effort terminal).
"""
from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from mission.link.forward import ForwardAddressError, forwarding
from wire.zenoh_secrets import ZenohSecurityError
# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/test_loop_debug.py)
from mission.core.clock import WallClock
from mission.core.zenoh_open import open_session
from mission.flight.coordinator import Coordinator
from mission.flight.operator_stop import run_until_stopped
from mission.flight.resume import load_resume_state
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import best_effort_terminal, told_to
from mission.telemetry.watch_keys import with_keys
from wire.cli_args import path_arg

__all__ = ["configure", "main", "resume"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``resume`` options."""
    parser.add_argument("log", type=path_arg, help="mission.jsonl of the stopped mission")
    parser.add_argument("--plan", type=path_arg, default=None,
                        help="plan file (default: the plan recorded in the log)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end (no live display)")
    parser.add_argument("--no-tlog", action="store_true", help="do not write .tlog files")


async def resume(log_path: Path, *, plan=None, clock=None, display=None, tlog: bool = True,
                 forward_addresses=None, terminal=None):
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
    forward_addresses : dict, optional
        The plan's ``[forward] out`` resolved before the loop started
        (:func:`mission.link.forward.resolve_outs`; any missing are resolved before connecting).
    terminal : mission.telemetry.terminal.Terminal, optional
        Its losses are told to the mission log.

    Raises
    ------
    mission.flight.resume.ResumeError
        The log cannot be resumed.
    """
    log_path = Path(log_path)
    # reading a whole mission log is file I/O of any size: off the loop (in the executor)
    state = await asyncio.get_running_loop().run_in_executor(None, load_resume_state, log_path, plan)
    clock = clock or WallClock()
    log = MissionLog(log_path, clock)
    session = None
    try:
        with told_to(terminal, log):
            session = await open_session(state.plan.zenoh)  # off the loop
            co = Coordinator(state.plan, clock=clock, zenoh_session=session, log=log, display=display,
                             tlog_dir=log_path.parent / "tlogs" if tlog else None)
            return await forwarding(co, with_keys(co, display, run_until_stopped(co, state)),  # as fly
                                    forward_addresses)
    finally:
        log.close()
        if session is not None:
            session.close()


def main(args) -> int:
    """Resume the mission of ``args.log`` (the terminal best effort: :mod:`mission.telemetry.terminal`)."""
    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result
    from mission.core.plan_types import PlanError
    from mission.core.plan import load_plan
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
    try:
        addresses = _forward_addresses(args.log, plan)
    except ResumeError as exc:
        print(f"swarmseek resume: {exc}", file=sys.stderr)
        return 2
    except ForwardAddressError as exc:
        print(f"swarmseek resume: error: {exc}; nothing re-engaged", file=sys.stderr)
        return 2
    import zenoh

    from mission.cli.paths import announce_log, summary_log_line

    announce_log("resume", args.log, args.json)
    display = Display(quiet=args.json)
    try:
        result = asyncio.run(resume(args.log, plan=plan, display=display, tlog=not args.no_tlog,
                                    forward_addresses=addresses, terminal=terminal))
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
    if result.outcome == "recovered" and not result.airborne_left and not result.still_armed:
        status = 0
    summary_log_line(args.log, args.json)
    return exit_status(result, status)


def _forward_addresses(log_path: Path, plan) -> dict:
    """The ``[forward] out`` of the plan the resumed mission flies (``plan``, else the log's), each
    host resolved once, before the event loop starts (a log without a plan record: none here,
    :func:`resume` then says why it cannot be resumed).

    Raises
    ------
    mission.flight.resume.ResumeError
        The log cannot be read, or its plan record is malformed.
    mission.link.forward.ForwardAddressError
        An address that is invalid or does not resolve.
    """
    from mission.flight.resume import ResumeError, plan_from_json
    from mission.link.forward import resolve_outs
    from mission.telemetry.mission_log import iter_mission_log

    if plan is None:
        try:
            record = next((r for r in iter_mission_log(log_path)
                           if r.get("type") == "plan" and not r.get("dry_run")), None)
        except (OSError, ValueError) as exc:
            raise ResumeError(f"cannot read {log_path}: {exc}") from None
        if record is None:
            return {}
        plan = plan_from_json(record.get("plan") or {})
    return resolve_outs(plan.forward.out)
