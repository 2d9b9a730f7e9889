"""``swarmseek publish``: a real sensor's readings, one number a line, published over zenoh.

Reads lines from a serial device (``--serial``, pyserial) or standard input, turns each into a
number and gives it to :class:`companion.publisher.Publisher`, which places it where the
autopilot (``--connect``, MAVLink) says the drone is and puts it on
``swarmseek/<fleet>/vehicle/<sysid>/sensor``. A line that is not one finite number (empty, text,
NaN, too long) is counted by reason and the first of each reason is shown; a reading before the
first position fix (or when the fixes stopped) is counted as held. The counts are printed every
``--report-every`` seconds and at the end. Plain blocking code in the main thread (the MAVLink
link is read by a background thread); no asyncio loop. See docs/real-sensor.md.
"""
from __future__ import annotations

import argparse
import sys
import time

from companion.autopilot import AutopilotError, connection_arg, sysid_arg
from companion.line_input import (BAD_LINE_REASONS, InputError, LineSplitter, SerialSource, StdinSource,
                                  parse_reading_line)
from companion.publisher import DEFAULT_MAX_FIX_AGE_S, Publisher, PublisherError
from wire.cli_args import fail, int_in_range, nonnegative_float, positive_float, usage_error
from wire.zenoh_flags import ZenohFlagError, add_endpoint_arguments, security_kwargs
from wire.zenoh_flags import add_arguments as _add_zenoh_security_arguments

__all__ = ["configure", "main", "run"]

_PROG = "swarmseek publish"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``swarmseek publish`` arguments to ``parser``."""
    parser.add_argument("--connect", required=True, type=connection_arg, metavar="CONN",
                        help="pymavlink connection to the autopilot, e.g. /dev/ttyAMA0,921600, "
                             "udpin:0.0.0.0:14550 or tcp:127.0.0.1:5760")
    parser.add_argument("--serial", default=None, metavar="DEVICE",
                        help="read the sensor's lines from this serial device, e.g. /dev/ttyUSB0 "
                             "(default: standard input)")
    parser.add_argument("--baud", type=int_in_range(1, 10_000_000, "a baud rate"), default=9600,
                        help="baud rate of --serial (default 9600)")
    parser.add_argument("--fleet", default="swarmseek",  # checked by the one rule, wire.fleet_name
                        help="fleet name, the plan's fleet (default swarmseek)")
    parser.add_argument("--sysid", type=sysid_arg, default=None, metavar="N",
                        help="autopilot system id, the plan's sysid of this vehicle "
                             "(default: the first autopilot heartbeat's)")
    add_endpoint_arguments(parser, listen_help="zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7448 (repeatable)",
                           connect_help="zenoh endpoint to connect to: the ground station's, "
                                        "e.g. tcp/192.168.1.10:7447 (repeatable)")
    _add_zenoh_security_arguments(parser)
    parser.add_argument("--rate", type=positive_float, default=10.0, metavar="HZ",
                        help="GLOBAL_POSITION_INT rate asked of the autopilot (default 10)")
    parser.add_argument("--max-fix-age", type=positive_float, default=DEFAULT_MAX_FIX_AGE_S, metavar="S",
                        help="hold a reading when the latest position fix is older than S seconds "
                             f"(default {DEFAULT_MAX_FIX_AGE_S:g})")
    parser.add_argument("--count", type=int_in_range(1, None, "--count"), default=None, metavar="N",
                        help="stop after N readings published")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S", help="stop after S seconds")
    parser.add_argument("--timeout", type=positive_float, default=30.0, metavar="S",
                        help="how long to wait for the autopilot's heartbeat (default 30)")
    parser.add_argument("--wait-subscriber", type=nonnegative_float, default=2.0, metavar="S",
                        help="before reading, wait up to S seconds for a zenoh subscriber (default 2)")
    parser.add_argument("--retries", type=int_in_range(1, None, "--retries"), default=3, metavar="N",
                        help="TCP connection attempts to the autopilot (default 3)")
    parser.add_argument("--report-every", type=nonnegative_float, default=10.0, metavar="S",
                        help="print the counts every S seconds when they changed (default 10; 0: only at the end)")
    parser.add_argument("--quiet", action="store_true", help="print only errors and the final counts")


def _log(args, text: str) -> None:
    if not args.quiet:
        print(f"{_PROG}: {text}", file=sys.stderr, flush=True)


class _Tally:
    """What became of the lines read: the publisher's counts plus the bad lines by reason."""

    def __init__(self, args, publisher: Publisher):
        self.args, self.publisher = args, publisher
        self.bad = dict.fromkeys(BAD_LINE_REASONS, 0)
        self._told: set[str] = set()

    def line(self, line: bytes | None) -> None:
        """Parse one line (None: too long) and put its value, counting what is not published."""
        value, reason = (None, "too_long") if line is None else parse_reading_line(line)
        if reason is not None:
            self.bad[reason] += 1
            shown = "" if line is None else f": {line[:60]!r}"
            self._first(reason, f"bad line ({reason.replace('_', ' ')}){shown}; counted, not published")
        elif not self.publisher.put(value):
            self._first(self.publisher.last_reason, f"reading held: {self.publisher.last_problem}")

    def _first(self, kind: str, text: str) -> None:
        if kind not in self._told:
            self._told.add(kind)
            _log(self.args, f"{text} (shown once; the rest are only counted)")

    def summary(self) -> str:
        """One line: published, held by reason, bad lines by reason."""
        c = self.publisher.counts
        held = c["no_position"] + c["stale_position"]
        bad = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in self.bad.items())
        return (f"published {c['published']}; held {held} (no position yet {c['no_position']}, stale position "
                f"{c['stale_position']}); bad lines {sum(self.bad.values())} ({bad})")


def _pump(args, source, tally: _Tally) -> None:
    """Read and publish until --count, --duration, the end of the input or a lost link."""
    publisher, splitter = tally.publisher, LineSplitter()
    start = time.monotonic()
    end = None if args.duration is None else start + args.duration
    next_report, last_report = start + args.report_every, None
    while args.count is None or publisher.counts["published"] < args.count:
        now = time.monotonic()
        if end is not None and now >= end:
            return
        if publisher.telemetry.error is not None:
            raise AutopilotError(publisher.telemetry.error)
        if args.report_every > 0 and now >= next_report:
            next_report = now + args.report_every
            if tally.summary() != last_report:
                last_report = tally.summary()
                _log(args, last_report)
        chunk = source.read()
        for line in splitter.finish() if chunk is None else splitter.feed(chunk):
            if args.count is not None and publisher.counts["published"] >= args.count:
                return
            tally.line(line)
        if chunk is None:
            _log(args, f"end of {source.name}")
            return


def run(args: argparse.Namespace, source, security: dict) -> dict:
    """Publish the lines of ``source`` (a :class:`SerialSource` or :class:`StdinSource`); the counts.

    Returns
    -------
    dict
        The publisher's counts and ``bad_lines`` (by reason).

    Raises
    ------
    companion.autopilot.AutopilotError
        The autopilot cannot be reached or the link is lost.
    companion.publisher.PublisherError
        zenoh cannot be reached.
    companion.line_input.InputError
        The input failed.
    """
    publisher = Publisher(args.fleet, args.sysid, mavlink=args.connect, zenoh_listen=args.zenoh_listen,
                          zenoh_connect=args.zenoh_connect, zenoh_security=security, position_rate_hz=args.rate,
                          max_fix_age_s=args.max_fix_age, heartbeat_timeout_s=args.timeout, retries=args.retries,
                          log=lambda text: _log(args, text))
    with publisher:
        tally = _Tally(args, publisher)
        _log(args, f"autopilot sysid {publisher.sysid} on {args.connect}; publishing {publisher.key} "
                   f"from {source.name}")
        if args.wait_subscriber > 0 and not publisher.wait_for_subscriber(args.wait_subscriber):
            _log(args, f"no zenoh subscriber matched within {args.wait_subscriber:g} s (ground station not up, "
                       "or its TLS / login refused us?); publishing anyway")
        try:
            _pump(args, source, tally)
        finally:  # also on Ctrl-C and on a lost link: the counts are always told
            print(f"{_PROG}: {tally.summary()}", file=sys.stderr, flush=True)
        return {**publisher.counts, "bad_lines": dict(tally.bad)}


def open_input(args: argparse.Namespace):
    """The input of ``--serial`` (pyserial) or standard input.

    Raises
    ------
    companion.line_input.InputError
        The serial device cannot be opened.
    """
    return SerialSource(args.serial, args.baud) if args.serial else StdinSource()


def main(args: argparse.Namespace) -> int:
    """Entry point of ``swarmseek publish``: 0 at the end of the input, ``--count`` or
    ``--duration``; 1 with a one-line message when the input, the autopilot or zenoh fails; 2
    when no zenoh endpoint was given or the zenoh TLS / login flags do not fit together."""
    if not args.zenoh_listen and not args.zenoh_connect:
        return usage_error(_PROG, "give --zenoh-connect (the ground station's endpoint, e.g. "
                                  "--zenoh-connect tcp/192.168.1.10:7447) and/or --zenoh-listen "
                                  "(zenoh endpoints are always explicit)")
    try:
        security = security_kwargs(args)
    except ZenohFlagError as exc:
        return usage_error(_PROG, str(exc))
    try:
        source = open_input(args)
    except InputError as exc:
        return fail(_PROG, f"error: {exc}", 1)
    try:
        run(args, source, security)
    except (AutopilotError, PublisherError, InputError) as exc:
        return fail(_PROG, f"error: {exc}", 1)
    finally:
        source.close()
    return 0
