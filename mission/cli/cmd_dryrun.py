"""``swarmseek dry-run --plan plan.toml``: validate, connect, run preflight checks; arm nothing.

Prints each mission-wide check (zenoh session, a reading from every sensor, start point and
formation paths inside the geofence: :mod:`mission.flight.readiness_mission`) and each vehicle's
readiness (every check and why it failed). Exit status: 0 ready to seek, 1 a check failed (a
vehicle not ready or unreachable, no readings, zenoh unreachable, start or path outside the
fence), 2 invalid plan (also: a ``[forward] out`` host name that does not resolve, as ``fly``; a plan
the security check refuses, :mod:`mission.core.plan_security`). The security check's warnings and
infos come first, one ``security LEVEL KEY: TEXT`` line each (``--json``: the ``security`` list).
"""
from __future__ import annotations

import argparse
import asyncio
import json

import zenoh

# the mission's modules are imported with the command, before any event loop starts: a first import
# inside the loop is one callback of 0.3 s (tests/mission/sim/test_loop_debug.py)
from mission.core.clock import WallClock
from mission.core.zenoh_errors import zenoh_open_message
from mission.core.zenoh_open import open_session
from mission.flight.coordinator import Coordinator
from mission.cli.common import add_plan_argument, load_plan_or_fail
from mission.core.plan_security import check_security
from wire.cli_args import nonnegative_float, positive_float, usage_error

__all__ = ["configure", "main", "dry_run", "format_readiness", "geofence_conversion", "format_geofence_conversion"]

_PROG = "swarmseek dry-run"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``dry-run`` options."""
    add_plan_argument(parser)
    parser.add_argument("--json", action="store_true", help="print the readiness report as JSON")
    parser.add_argument("--verbose", action="store_true", help="show phases and events as they happen")
    parser.add_argument("--timeout", type=positive_float, default=15.0,
                        help="seconds to wait for each vehicle's heartbeat (default 15)")
    parser.add_argument("--ready-timeout", type=nonnegative_float, default=None, metavar="S",
                        help="seconds to wait for the autopilots' own pre-arm readiness (default: the "
                             "plan's [preflight] autopilot_ready_timeout_s)")


async def dry_run(plan, *, clock=None, display=None, zenoh_session=None):
    """Connect and run preflight; returns the MissionResult (``ready`` / ``not_ready``).

    The plan's zenoh session is opened as ``fly`` opens it (readings from every sensor are a
    readiness check), unless ``zenoh_session`` is given (then it is used and not closed); one
    that cannot be opened fails the ``zenoh`` check with the reason in plain words.
    """
    session, problem, own = zenoh_session, None, zenoh_session is None
    if own:
        try:
            session = await open_session(plan.zenoh)  # off the loop
        except zenoh.ZError as exc:
            problem = zenoh_open_message(exc, plan.zenoh)
    try:
        co = Coordinator(plan, clock=clock or WallClock(), zenoh_session=session, display=display,
                         zenoh_problem=problem)
        return await co.dry_run()
    finally:
        if own and session is not None:
            session.close()


def geofence_conversion(plan) -> dict | None:
    """The conversion of a ``[geofence] file`` into the mission frame: its source, the origin (and
    whether it is the file's home), each vertex as written in the file (``lat_deg``, ``lon_deg``)
    and in the mission frame (``north_m``, ``east_m`` about the origin), the altitude band; None
    when the plan gives its polygon itself."""
    gf = plan.geofence
    if not gf.source:
        return None
    vertices = [{"lat_deg": lat, "lon_deg": lon, "north_m": round(n, 3) + 0.0, "east_m": round(e, 3) + 0.0}
                for (lat, lon), (e, n) in zip(gf.source_latlon_deg, gf.polygon_en_m)]
    return {"source": gf.source, "origin": list(plan.origin), "origin_from_file": gf.origin_from_file,
            "vertices": vertices, "min_alt_m": gf.min_alt_m, "max_alt_m": gf.max_alt_m}


def format_geofence_conversion(conv: dict) -> list[str]:
    """The lines of :func:`geofence_conversion` (one per vertex)."""
    lat0, lon0, alt0 = conv["origin"]
    whence = "the file's home" if conv["origin_from_file"] else "the plan's [origin]"
    lines = [f"geofence from {conv['source']}",
             f"  mission frame about {lat0:.7f}, {lon0:.7f}, {alt0:.1f} m AMSL ({whence})",
             f"  {'vertex':>6}  {'lat_deg':>12} {'lon_deg':>13}  ->  {'north_m':>9} {'east_m':>9}"]
    lines += [f"  {j:>6}  {v['lat_deg']:>12.7f} {v['lon_deg']:>13.7f}  ->  {v['north_m']:>9.2f} {v['east_m']:>9.2f}"
              for j, v in enumerate(conv["vertices"])]
    lines.append(f"  altitude band {conv['min_alt_m']:g} .. {conv['max_alt_m']:g} m up "
                 "(the plan's min_alt_m, max_alt_m)")
    return lines


def format_readiness(result) -> list[str]:
    """One line per vehicle: READY / NOT READY, the checks and the problems."""
    lines = [f"check {c['name']:<15} {'ok  ' if c['ok'] else 'FAIL'} {c['detail']}"
             for c in result.mission_checks]
    for r in result.readiness:
        checks = " ".join(f"{k}={'ok' if v else 'FAIL'}" for k, v in r.get("checks", {}).items())
        state = "READY    " if r.get("ready") else "NOT READY"
        why = "" if r.get("ready") else "  <- " + "; ".join(r.get("problems", []))
        lines.append(f"vehicle {r['sysid']:>3} {r.get('id', ''):<10} {r.get('connection', ''):<28} "
                     f"{state} {checks}{why}")
        lines.extend(f"    warning: {w}" for w in r.get("warnings", []))
    lines.append(f"{result.outcome}: {result.message}")
    return lines


def main(args) -> int:
    """Validate the plan, connect, check, report."""
    import dataclasses

    from mission.telemetry.display import Display

    plan, status = load_plan_or_fail(args.plan, _PROG)
    if plan is None:
        return status
    from mission.link.forward import ForwardAddressError, resolve_outs

    try:  # fly resolves these once before connecting and refuses to start when one fails: so does dry-run
        resolve_outs(plan.forward.out)
    except ForwardAddressError as exc:
        return usage_error(_PROG, f"{exc} (fly would refuse to start)")
    plan = dataclasses.replace(plan, heartbeat_timeout_s=args.timeout)
    if args.ready_timeout is not None:  # the argument types refuse negative, NaN and infinite values
        plan = dataclasses.replace(plan, preflight=dataclasses.replace(
            plan.preflight, autopilot_ready_timeout_s=args.ready_timeout))
    findings = check_security(plan)  # refusals came with the plan; warnings and infos here, first
    if not args.json:
        for finding in findings:
            print(f"security {finding.line()}", flush=True)
    display = Display(quiet=args.json, tty=False, min_interval_s=float("inf")) if args.verbose else None
    conversion = geofence_conversion(plan)
    if conversion is not None and not args.json:
        print("\n".join(format_geofence_conversion(conversion)), flush=True)
    result = asyncio.run(dry_run(plan, display=display))
    if args.json:
        report = {**result.to_json(), "security": [f.to_json() for f in findings]}
        if conversion is not None:
            report["geofence_conversion"] = conversion
        print(json.dumps(report, indent=2))
    else:
        for line in format_readiness(result):
            print(line)
    return 0 if result.outcome == "ready" else 1
