"""``swarmseek resume LOG``: restart a stopped mission's coordinator from its mission log.

The plan comes from the log (its ``plan`` record) or from ``--plan`` (same vehicles). The
resumed coordinator reconnects, re-engages the vehicles still flying (no new takeoff) and goes on
seeking from the last centre and iteration, appending to the same log (see
:mod:`mission.flight.phases.resume`). The mission clock is the wall clock: a ``swarmseek run`` log is
resumable only while its mock fleet still runs, i.e. in-process (the tests do that with
:func:`resume`). Only a log cut in the takeoff, assembly or seek (or stopped there by a ground station told to
just stop) seeks on; every other ending (finished, returning, aborted, interrupted with the
return: :mod:`mission.flight.phases.resume_endings`) is taken over to bring the vehicles still flying home
(outcome ``recovered``). Exit status: 0 converged, or recovered with every vehicle down or landing
and none left armed; 1 not converged / aborted / a
vehicle left airborne; 2 the log or plan cannot be resumed; 129 / 130 / 141 / 143 stopped by
SIGHUP / SIGINT / SIGPIPE / SIGTERM, 74 the mission log could not be written (as ``fly``: the
same stop handlers, :mod:`mission.flight.operator_stop`, and a best-effort terminal).
"""
from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from mission.cli.cmd_fly import fly_logged
from mission.cli.cmd_map import add_map_option, start_map_thread
from mission.cli.common import add_mission_outputs, load_plan_or_fail, run_or_fail, security_or_fail
from mission.link.forward import ForwardAddressError, resolve_outs
# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/mission/sim/test_loop_debug.py)
from mission.core.clock import WallClock
from mission.flight.phases.resume import load_resume_state
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import best_effort_terminal
from wire.cli_args import fail, path_arg, usage_error

__all__ = ["configure", "main", "resume"]

_PROG = "swarmseek resume"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``resume`` options."""
    parser.add_argument("log", type=path_arg, help="mission.jsonl of the stopped mission")
    parser.add_argument("--plan", type=path_arg, default=None,
                        help="plan file (default: the plan recorded in the log)")
    add_mission_outputs(parser, "resume", log_dir=False, forward=False)
    add_map_option(parser)


async def resume(log_path: Path, *, plan=None, clock=None, display=None, tlog: bool = True,
                 forward_addresses=None, terminal=None, map_thread=None, world=None):
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
    map_thread : mission.telemetry.map_live.MapThread, optional
        ``--map``'s server, fed through the mission's session (:func:`mission.cli.cmd_fly.fly_logged`).
    world : mission.sim.embedded_world.EmbeddedWorld, optional
        A lock-step run's world (``clock`` its VirtualClock): it waits for the resumed mission's
        readings (:func:`mission.cli.cmd_fly.fly_logged`).

    Raises
    ------
    mission.flight.phases.resume.ResumeError
        The log cannot be resumed.
    """
    log_path = Path(log_path)
    # reading a whole mission log is file I/O of any size: off the loop (in the executor)
    state = await asyncio.get_running_loop().run_in_executor(None, load_resume_state, log_path, plan)
    clock = clock or WallClock()
    return await fly_logged(state.plan, MissionLog(log_path, clock), clock=clock, display=display,
                            tlog_dir=log_path.parent / "tlogs" if tlog else None,
                            forward_addresses=forward_addresses, terminal=terminal, resume_state=state,
                            map_thread=map_thread, world=world)


def main(args) -> int:
    """Resume the mission of ``args.log`` (the terminal best effort: :mod:`mission.telemetry.terminal`)."""
    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result
    from mission.flight.phases.resume import ResumeError

    from mission.cli.paths import writable_file_problem

    problem = writable_file_problem(args.log, "mission log")
    if problem:
        return usage_error(_PROG, problem)
    plan = None
    if args.plan is not None:
        plan, status = load_plan_or_fail(args.plan, _PROG)
        if plan is None:
            return status
    try:
        flown = _flown_plan(args.log, plan)
        addresses = resolve_outs(flown.forward.out) if flown is not None else {}
    except ResumeError as exc:
        return fail(_PROG, str(exc))
    except ForwardAddressError as exc:
        return usage_error(_PROG, f"{exc}; nothing re-engaged")
    status = security_or_fail(flown, _PROG) if flown is not None else None
    if status is not None:  # e.g. an insecure plan in a log written before the check existed
        return status
    from mission.cli.paths import announce_log, summary_log_line
    from mission.core.zenoh_errors import clean_zenoh_error

    map_thread = None
    if flown is not None:  # (without a plan record resume says why it cannot go on)
        map_thread, status = start_map_thread(args, flown.fleet, _PROG)  # a port in use: nothing re-engaged
        if status is not None:
            return status
    announce_log("resume", args.log, args.json)
    display = Display(quiet=args.json)
    try:
        result, status = run_or_fail(
            _PROG, lambda: asyncio.run(resume(args.log, plan=plan, display=display, tlog=not args.no_tlog,
                                              forward_addresses=addresses, terminal=terminal, map_thread=map_thread)),
            lambda exc: f"cannot open the zenoh session: {clean_zenoh_error(exc)}")
    except ResumeError as exc:
        return fail(_PROG, str(exc))
    finally:
        if map_thread is not None:
            map_thread.stop()
    if result is None:
        return status
    status = report_result(result, display, args.json)
    summary_log_line(args.log, args.json)
    return status


def _flown_plan(log_path: Path, plan):
    """The plan the resumed mission flies: ``plan``, else the log's (None for a log without a plan
    record: :func:`resume` then says why it cannot be resumed). Its ``[forward] out`` hosts are
    resolved and its security checked before the event loop starts.

    Raises
    ------
    mission.flight.phases.resume.ResumeError
        The log cannot be read, or its plan record is malformed.
    """
    from mission.flight.phases.resume import ResumeError, plan_from_json
    from mission.telemetry.mission_log import iter_mission_log

    if plan is not None:
        return plan
    try:
        record = next((r for r in iter_mission_log(log_path)
                       if r.get("type") == "plan" and not r.get("dry_run")), None)
    except (OSError, ValueError) as exc:
        raise ResumeError(f"cannot read {log_path}: {exc}") from None
    return None if record is None else plan_from_json(record.get("plan") or {})
