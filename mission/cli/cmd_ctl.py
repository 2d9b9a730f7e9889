"""``swarmseek ctl FLEET COMMAND``: command a running mission over zenoh.

Commands: ``pause`` (the formation holds), ``continue``, ``abort`` (end now, the plan's return),
``return`` (end the seek, the mission's return), ``land`` (every vehicle LANDs where it is),
``rtl`` (every vehicle to the autopilot's RTL). One zenoh query on
``swarmseek/<fleet>/mission/control``; the coordinator's acknowledgement is printed. Exit status:
0 accepted, 1 rejected (the reason is printed), 2 invalid options, 3 no coordinator answered.
"""
from __future__ import annotations

import argparse
import json
import sys

from mission.cli.cmd_watch import add_zenoh_options, open_zenoh
from wire.cli_args import fail, positive_float

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``ctl`` options."""
    from mission.flight.control import COMMANDS

    parser.add_argument("fleet", help="the mission's fleet name (the plan's fleet; 'swarmseek' for run)")
    parser.add_argument("command", choices=COMMANDS, help="what the mission should do")
    parser.add_argument("--sender", default=None, metavar="ID",
                        help="who sends it, for the mission log (default USER@HOST)")
    parser.add_argument("--timeout-s", type=positive_float, default=5.0, metavar="S",
                        help="wait this long for the coordinator's answer (default 5)")
    parser.add_argument("--json", action="store_true", help="print the acknowledgement as JSON")
    add_zenoh_options(parser)


def main(args) -> int:
    """Send the command; 0 accepted, 1 rejected, 2 bad options, 3 no answer."""
    from mission.flight.control import check_sender
    from mission.telemetry.watch import CommandTimeout, default_sender, send_command

    sender = args.sender if args.sender is not None else default_sender()
    problem = check_sender(sender)
    if problem:
        return fail("swarmseek ctl", f"--sender: {problem}")
    session, problem, status = open_zenoh(args, "swarmseek ctl", args.timeout_s)
    if session is None:
        print(problem, file=sys.stderr)
        return status
    try:
        ack = send_command(session, args.fleet, args.command, sender, args.timeout_s)
    except CommandTimeout as exc:
        print(f"swarmseek ctl: {exc}", file=sys.stderr)
        return 3
    finally:
        session.close()
    if args.json:
        print(json.dumps(ack))
    else:
        verdict = "accepted" if ack.get("accepted") else "REJECTED"
        print(f"{args.command} {verdict} by fleet {ack.get('fleet')} (phase {ack.get('phase')}): {ack.get('reason')}")
    return 0 if ack.get("accepted") else 1
