"""``swarmseek fly --plan plan.toml``: fly the mission against the vehicles named in a plan.

Readings come over zenoh (e.g. one ``swarmseek sensor`` per vehicle) on the plan's endpoints;
the mission clock is the wall clock. Exit status: 0 converged, 1 not converged or aborted
(also: not ready to seek, nothing armed), 2 invalid plan or options, 129 / 130 / 141 / 143
stopped by SIGHUP / SIGINT / SIGPIPE sent by another process / SIGTERM (the first brings the
vehicles home, a second lands them where they are), 74 the mission log could not be written (the
vehicles were brought home). The terminal is best effort (:mod:`mission.telemetry.terminal`): a
closed stdout or stderr never stops the mission. See docs/faults.md, "The ground station's own faults".
"""
from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from wire.zenoh_secrets import ZenohSecurityError
# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/test_loop_debug.py)
from mission.core.clock import WallClock
from mission.core.zenoh_open import open_session
from mission.flight.coordinator import Coordinator
from mission.flight.operator_stop import run_until_stopped
from mission.link.forward import ForwardAddressError, forwarding, out_address, plan_with_outs, resolve_outs
from mission.telemetry.mission_log import MissionLog
from mission.telemetry.terminal import best_effort_terminal, told_to
from mission.telemetry.watch_keys import with_keys
from wire.cli_args import path_arg

__all__ = ["configure", "main", "fly"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``fly`` options."""
    parser.add_argument("--plan", type=path_arg, required=True, help="mission plan (TOML)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end (no live display)")
    parser.add_argument("--log-dir", type=path_arg, default=None,
                        help="mission log and tlogs go here (default ./swarmseek-logs/fly-TIME)")
    parser.add_argument("--no-tlog", action="store_true", help="do not write .tlog files")
    parser.add_argument("--out", type=out_address, action="append", default=[], metavar="udp:HOST:PORT",
                        help="forward every vehicle's MAVLink to this client, e.g. QGroundControl on "
                             "udp:127.0.0.1:14550 (repeatable; read-only unless [forward] allow_commands)")


async def fly(plan, *, clock=None, log_dir: Path, display=None, tlog: bool = True, forward_addresses=None,
              terminal=None):
    """Open the plan's zenoh session, fly the mission, close; returns the MissionResult.

    ``forward_addresses``: the plan's ``[forward] out`` resolved before the loop started
    (:func:`mission.link.forward.resolve_outs`; any missing are resolved before connecting).
    ``terminal``: the :class:`~mission.telemetry.terminal.Terminal` whose losses the mission log tells.
    """
    clock = clock or WallClock()
    log = MissionLog(Path(log_dir) / "mission.jsonl", clock)
    session = None
    try:
        with told_to(terminal, log):
            session = await open_session(plan.zenoh)  # off the loop
            co = Coordinator(plan, clock=clock, zenoh_session=session, log=log, display=display,
                             tlog_dir=Path(log_dir) / "tlogs" if tlog else None)
            return await forwarding(co, with_keys(co, display, run_until_stopped(co)),  # --out; keys on a terminal
                                    forward_addresses)
    finally:
        log.close()
        if session is not None:
            session.close()


def main(args) -> int:
    """Load the plan and fly it (the terminal best effort: :mod:`mission.telemetry.terminal`)."""
    with best_effort_terminal() as terminal:
        return _main(args, terminal)


def _main(args, terminal) -> int:
    from mission.telemetry.display import Display, report_result
    from mission.core.plan_types import PlanError
    from mission.core.plan import load_plan

    try:
        plan = load_plan(args.plan)
    except PlanError as exc:
        print(f"swarmseek fly: {exc}", file=sys.stderr)
        return 2
    plan = plan_with_outs(plan, args.out)
    if not plan.zenoh.listen and not plan.zenoh.connect:
        print("swarmseek fly: the plan's [zenoh] section has no listen or connect endpoint: "
              "no reading could arrive (multicast scouting is off)", file=sys.stderr)
        return 2
    from mission.cli.paths import announce_log, mission_log_dir, summary_log_line

    try:
        addresses = resolve_outs(plan.forward.out)  # once, before any vehicle is contacted
    except ForwardAddressError as exc:
        print(f"swarmseek fly: error: {exc}; nothing armed", file=sys.stderr)
        return 2
    log_dir, problem = mission_log_dir(args.log_dir, "fly")
    if problem:
        print(f"swarmseek fly: error: {problem}", file=sys.stderr)
        return 2
    import zenoh

    announce_log("fly", log_dir / "mission.jsonl", args.json)
    display = Display(quiet=args.json)
    try:
        result = asyncio.run(fly(plan, log_dir=log_dir, display=display, tlog=not args.no_tlog,
                                 forward_addresses=addresses, terminal=terminal))
    except zenoh.ZError as exc:
        from mission.core.zenoh_errors import zenoh_open_message

        print(f"swarmseek fly: {zenoh_open_message(exc, plan.zenoh)}; nothing armed", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"swarmseek fly: cannot write the mission log: {exc}", file=sys.stderr)
        return 1
    except ZenohSecurityError as exc:  # e.g. the password file became unreadable since the plan loaded
        print(f"swarmseek fly: zenoh security settings: {exc}", file=sys.stderr)
        return 2
    from mission.flight.operator_stop import exit_status

    status = exit_status(result, report_result(result, display, args.json))
    summary_log_line(log_dir / "mission.jsonl", args.json)
    return status
