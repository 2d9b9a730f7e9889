"""``swarmseek audit LOG_DIR``: check from the ``.tlog`` files that no setpoint broke the fence,
the speed limit or the separation (see :mod:`mission.safety.audit`).

Exit status: 0 clean, 1 with violations, 2 bad input (missing directory, no tlogs, unreadable
mission log or tlog), with a one-line message.
"""
from __future__ import annotations

import argparse
import json
import sys

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``audit`` arguments."""
    from sitl_mock.cli_args import path_arg  # a path that cannot even be asked about: a usage error

    parser.add_argument("log_dir", type=path_arg, metavar="LOG_DIR", help="a mission's --log-dir (mission.jsonl and tlogs/)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--gcs-sysid", type=int, default=255, help="system id of the ground station (255)")


def main(args: argparse.Namespace) -> int:
    """Audit ``args.log_dir``; 0 clean, 1 violations, 2 bad input."""
    from mission.safety.audit import AuditError, audit_mission

    try:
        report = audit_mission(args.log_dir, gcs_sysid=args.gcs_sysid)
    except AuditError as exc:
        print(f"swarmseek audit: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report.to_dict(), indent=2, allow_nan=False))
    else:
        print(report.format_text())
    return 0 if report.ok else 1
