"""``swarmseek watch FLEET``: the live table of a running mission, from another terminal or machine.

Subscribes to ``swarmseek/<fleet>/mission/state`` (the coordinator's state publication) and draws
the same table as ``run`` / ``fly`` (:mod:`mission.telemetry.display`); plain lines when piped,
one JSON snapshot per line with ``--json``. When the mission ends (phase ``done``) it exits with
the mission's own exit status (its last snapshot's ``ending``: 0 converged with every vehicle home,
1 goal not reached, 4 a vehicle lost, 5 a vehicle left airborne or armed, a signal's 129-143;
docs/mission.md), 0 when a ground station too old to say it ended; 0 on Ctrl-C, 3 when no state
arrived within ``--wait-s``, 2 for invalid options.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from wire.cli_args import positive_float

__all__ = ["configure", "main", "add_zenoh_options", "open_zenoh"]


def add_zenoh_options(parser: argparse.ArgumentParser) -> None:
    """``--zenoh-listen`` / ``--zenoh-connect`` (repeatable) and the TLS / login flags."""
    from wire.zenoh_flags import add_arguments, add_endpoint_arguments

    add_endpoint_arguments(parser, connect_first=True,
                           connect_help="zenoh endpoint to connect to: the coordinator's listen endpoint or a zenoh "
                                        "router, e.g. tcp/192.168.1.10:7447 (repeatable)",
                           listen_help="zenoh endpoint to listen on (the coordinator connects here; repeatable)")
    add_arguments(parser)


def open_zenoh(args, prog: str, wait_s: float | None = None):
    """``(session, None, 0)`` for ``args``' endpoints and security flags, or ``(None, message,
    exit status)``: 2 for invalid options, 3 when no endpoint could be reached within ``wait_s``
    wall seconds (None: keep trying), 1 when zenoh refuses the configuration.

    With only ``--zenoh-connect`` the session is a zenoh client (of the ground station or of a
    router); a client cannot open before it reaches one, so opening is tried again every 0.5 s."""
    import zenoh

    from wire.zenoh_config import zenoh_config
    from wire.zenoh_flags import ZenohFlagError, plain_network_warning, security_kwargs

    if not args.zenoh_connect and not args.zenoh_listen:
        return None, f"{prog}: give --zenoh-connect (the coordinator's or a router's endpoint) and/or --zenoh-listen", 2
    try:
        conf = zenoh_config(listen=args.zenoh_listen, connect=args.zenoh_connect, **security_kwargs(args))
    except (ZenohFlagError, ValueError) as exc:
        return None, f"{prog}: {exc}", 2
    warning = plain_network_warning(prog, args.zenoh_listen, args.zenoh_connect)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    if not args.zenoh_listen:  # a monitor is a zenoh client of the ground station or the router
        conf.insert_json5("mode", json.dumps("client"))
    deadline = None if wait_s is None else time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(conf), None, 0
        except zenoh.ZError as exc:
            why = str(exc).split(" at /")[0].splitlines()[0][:200]
            if args.zenoh_listen or "Unable to connect" not in why:
                return None, f"{prog}: cannot open the zenoh session: {why}", 1
            if deadline is not None and time.monotonic() > deadline:
                return None, (f"{prog}: cannot reach {', '.join(args.zenoh_connect)} within {wait_s:g} s "
                              "(is the ground station or the zenoh router up?)"), 3
        time.sleep(0.5)


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``watch`` options."""
    parser.add_argument("fleet", help="the mission's fleet name (the plan's fleet; 'swarmseek' for run)")
    add_zenoh_options(parser)
    parser.add_argument("--json", action="store_true", help="print every snapshot as one JSON line")
    parser.add_argument("--wait-s", type=positive_float, default=None, metavar="S",
                        help="give up (status 3) when no state arrives within S wall seconds (default: wait)")


def _watch(watcher, display, as_json: bool, wait_s: float | None) -> int:
    start = time.monotonic()
    heard = False
    while True:
        state = watcher.get(0.5)
        if state is None:
            if not heard and wait_s is not None and time.monotonic() - start > wait_s:
                print(f"swarmseek watch: no state of fleet {watcher.fleet!r} within {wait_s:g} s (is the "
                      "mission running, this session on its zenoh network, and allowed to watch?)",
                      file=sys.stderr)
                return 3
            continue
        if not heard:
            _security_warnings(watcher.fleet, state)
        heard = True
        if as_json:
            print(json.dumps(state), flush=True)
        else:
            display.update(state)
        if state.get("phase") == "done" or state.get("final"):
            return _ended(watcher.fleet, state, as_json)


def _ended(fleet: str, state: dict, as_json: bool) -> int:
    """The mission's exit status from its last snapshot's ``ending`` (0 without one), said on a terminal."""
    ending = state.get("ending") if isinstance(state.get("ending"), dict) else {}
    status = ending.get("exit_status")
    status = status if isinstance(status, int) and not isinstance(status, bool) and 0 <= status <= 255 else 0
    if not as_json:
        how = f": {str(ending.get('outcome'))[:40]}, exit status {status}" if ending.get("outcome") else ""
        print(f"swarmseek watch: the mission of fleet {fleet!r} ended{how}", flush=True)
    return status


def _security_warnings(fleet: str, state: dict) -> None:
    """The mission's security warnings (its plan's, :mod:`mission.core.plan_security`), on stderr
    when the first state arrives: e.g. an open command channel the plan allowed."""
    for finding in state.get("security_warnings") or ():
        if isinstance(finding, dict):
            print(f"swarmseek watch: warning: fleet {fleet!r}: {str(finding.get('key'))[:80]}: "
                  f"{str(finding.get('text'))[:600]}", file=sys.stderr, flush=True)


def main(args) -> int:
    """Watch the fleet's state until the mission ends or Ctrl-C."""
    from mission.telemetry.display import Display
    from mission.telemetry.watch import StateWatcher

    session, problem, status = open_zenoh(args, "swarmseek watch", args.wait_s)
    if session is None:
        print(problem, file=sys.stderr)
        return status
    watcher = StateWatcher(session, args.fleet)
    try:
        return _watch(watcher, Display(), args.json, args.wait_s)
    except KeyboardInterrupt:
        print("\nswarmseek watch: stopped (the mission goes on)", file=sys.stderr)
        return 0
    except BrokenPipeError:  # e.g. piped into head: the reader is gone
        sys.stderr.close()
        return 0
    finally:
        watcher.close()
        session.close()
