"""What the mission commands (``fly``, ``resume``, ``dry-run``, ``run``) share on the command line:
their common options, loading ``--plan``, and the one-line report of a mission that could not
run.

The one-line error itself (``"swarmseek CMD: ..."`` on stderr, exit 2) is
:func:`wire.cli_args.fail` / :func:`wire.cli_args.usage_error`, shared with the simulator's
commands; the zenoh endpoint and security flags are :mod:`wire.zenoh_flags`.
"""
from __future__ import annotations

import argparse
import sys

from mission.link.forward import out_address
from wire.cli_args import USAGE_STATUS, fail, path_arg
from wire.zenoh_secrets import ZenohSecurityError

__all__ = ["add_plan_argument", "add_mission_outputs", "fence_problem", "load_plan_or_fail", "run_or_fail",
           "security_or_fail"]


def add_plan_argument(parser: argparse.ArgumentParser) -> None:
    """``--plan FILE`` (required): the mission plan of ``fly`` and ``dry-run``."""
    parser.add_argument("--plan", type=path_arg, required=True, help="mission plan (TOML)")


def add_mission_outputs(parser: argparse.ArgumentParser, command: str, *, log_dir: bool = True,
                        forward: bool = True) -> None:
    """``--json``, ``--log-dir`` (default ``./swarmseek-logs/COMMAND-TIME``; not with
    ``log_dir=False``), ``--no-tlog`` and ``--out`` (not with ``forward=False``), in that order."""
    parser.add_argument("--json", action="store_true", help="print a JSON summary at the end (no live display)")
    if log_dir:
        parser.add_argument("--log-dir", type=path_arg, default=None,
                            help=f"mission log and tlogs go here (default ./swarmseek-logs/{command}-TIME)")
    parser.add_argument("--no-tlog", action="store_true", help="do not write .tlog files")
    if forward:
        parser.add_argument("--out", type=out_address, action="append", default=[], metavar="udp:HOST:PORT",
                            help="forward every vehicle's MAVLink to this client, e.g. QGroundControl on "
                                 "udp:127.0.0.1:14550 (repeatable; read-only unless [forward] allow_commands)")


def load_plan_or_fail(path, prog: str):
    """``(plan, None)``, or ``(None, 2)`` once the plan's problems are printed (one problem: one
    line, ``"{prog}: invalid plan in FILE: KEY: WHY"``; several: a line each,
    :class:`~mission.core.plan_types.PlanError`).

    The fence is also built as the safety envelope will build it
    (:class:`mission.safety.fence.Geofence`): a self-intersecting polygon (drawn in the plan or
    in its ``[geofence] file``) is an invalid plan here, before anything is contacted.
    """
    from mission.core.plan import load_plan
    from mission.core.plan_security import PlanSecurityError
    from mission.core.plan_types import PlanError

    try:
        plan = load_plan(path)
    except PlanError as exc:
        if len(exc.problems) == 1 and not isinstance(exc, PlanSecurityError):  # one problem, one line
            key, why = exc.problems[0]
            return None, fail(prog, f"invalid plan in {path}: {key}: {why}")
        return None, fail(prog, str(exc))
    problem = fence_problem(plan.geofence)
    if problem is not None:
        return None, fail(prog, f"invalid plan in {path}: {problem}")
    return plan, None


def fence_problem(geofence) -> str | None:
    """Why the safety envelope cannot hold the plan's ``[geofence]`` (a
    :class:`~mission.core.plan_types.GeofencePlan`), in one line, or None."""
    from mission.safety.fence import Geofence
    from mission.safety.report import SafetyError

    if not geofence.polygon_en_m:
        return None
    try:
        Geofence(geofence.polygon_en_m, geofence.min_alt_m, geofence.max_alt_m)
    except SafetyError as exc:
        where = f"geofence.file ({geofence.source})" if geofence.source else "geofence"
        return f"{where}: {exc}"
    return None


def run_or_fail(prog: str, run, zenoh_message):
    """``(run(), None)``, or ``(None, exit status)`` once why the mission could not run is printed
    as one line: zenoh refused the session (``zenoh_message(exc)``, 1), the mission log could not be
    written (1), the zenoh security settings became unusable since the plan loaded (2)."""
    import zenoh

    try:
        return run(), None
    except zenoh.ZError as exc:
        return None, fail(prog, zenoh_message(exc), 1)
    except OSError as exc:
        return None, fail(prog, f"cannot write the mission log: {exc}", 1)
    except ZenohSecurityError as exc:  # e.g. the password file became unreadable since the plan loaded
        return None, fail(prog, f"zenoh security settings: {exc}", USAGE_STATUS)


def security_or_fail(plan, prog: str, *, stream=None) -> int | None:
    """Run the plan's security check (:func:`mission.core.plan_security.check_security`) as a
    mission starts: None once every warning and info is printed (``"{prog}: security LEVEL: KEY:
    TEXT"``, one line each, on ``stream``, default stderr), or 2 once the refusals are printed (a
    plan that did not come through :func:`load_plan_or_fail`: ``resume``'s log, ``--out``)."""
    from mission.core.plan_security import PlanSecurityError, check_security, refusals

    findings = check_security(plan)
    refused = refusals(findings)
    if refused:
        return fail(prog, str(PlanSecurityError(refused)))
    for finding in findings:
        print(f"{prog}: security {finding.level}: {finding.key}: {finding.text}",
              file=stream if stream is not None else sys.stderr, flush=True)
    return None
