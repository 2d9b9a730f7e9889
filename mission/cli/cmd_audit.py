"""``swarmseek audit LOG_DIR``: check from the ``.tlog`` files that no setpoint broke the fence,
the speed limit or the separation (see :mod:`mission.safety.audit`).

Exit status: 0 clean and complete; 1 with violations; 2 bad input or options (missing directory,
no tlogs, unreadable mission log or tlog, ``--gcs-sysid`` out of 1..255), with a one-line message;
3 incomplete, no violation among what was checked but the audit cannot vouch for the whole
mission (no setpoint checked, a planned vehicle's tlog missing or empty, the log's plan and the
tlogs disagree: each reason listed). A closed standard output (``swarmseek audit DIR --json |
head``) ends the output quietly, with the same status.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from wire.cli_args import fail, int_in_range

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``audit`` arguments."""
    from wire.cli_args import path_arg  # a path that cannot even be asked about: a usage error

    parser.add_argument("log_dir", type=path_arg, metavar="LOG_DIR", help="a mission's --log-dir (mission.jsonl and tlogs/)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--gcs-sysid", type=int_in_range(1, 255, "--gcs-sysid"), default=255,
                        help="system id of the ground station, 1..255 (255)")


def _emit(text: str) -> None:
    """Print ``text`` on stdout; a reader that went away (``| head``) ends the output quietly."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        # nothing more can be shown; point stdout at /dev/null so the exit's flush cannot fail again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def main(args: argparse.Namespace) -> int:
    """Audit ``args.log_dir``; 0 clean, 1 violations, 2 bad input, 3 incomplete."""
    from mission.safety.audit_read import AuditError
    from mission.safety.audit import audit_mission

    try:
        report = audit_mission(args.log_dir, gcs_sysid=args.gcs_sysid)
    except AuditError as exc:
        return fail("swarmseek audit", str(exc))
    _emit(json.dumps(report.to_dict(), indent=2, allow_nan=False) if args.json else report.format_text())
    return report.exit_status
