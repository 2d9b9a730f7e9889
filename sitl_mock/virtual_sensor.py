"""``swarmseek sensor``: a virtual sensor riding on a real (or SITL) autopilot.

Reads the autopilot's GLOBAL_POSITION_INT over MAVLink (any pymavlink connection string: it asks
for the rate it needs with MAV_CMD_SET_MESSAGE_INTERVAL; :mod:`companion.autopilot`, which a real
sensor's publisher uses too), maps each position fix into the field frame (ENU about
``--origin``), samples the simulated field there with the requested noise, and
publishes the reading over zenoh exactly like the mock fleet's sensors (key
``swarmseek/<fleet>/vehicle/<sysid>/sensor``, schema ``swarmseek.sensor.v1``, ``time_s`` = Unix
time). Field teams use it to dry-run the whole mission against ArduPilot or PX4 SITL.

Plain blocking pymavlink in the main thread: this command runs no asyncio loop.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from companion.autopilot import (AutopilotError, PositionStream, close_mavlink, connection_arg, open_mavlink,
                                 sysid_arg, wait_heartbeat)
from companion.sensor_wire import SensorPublisher, sensor_key
from formation.geodesy import geodetic_to_enu
from sitl_mock.cli_args import add_field_arguments, field_from_args, probe_custom_field
from sitl_mock.faults import FaultSet
from sitl_mock.sensor import SignalSensor
from wire.cli_args import fail, nonnegative_float, origin_geodetic, positive_float, source_enu, usage_error
from wire.zenoh_config import zenoh_config
from wire.zenoh_flags import ZenohFlagError, add_endpoint_arguments, plain_network_warning, security_kwargs
from wire.zenoh_flags import add_arguments as _add_zenoh_security_arguments

__all__ = ["VirtualSensorError", "configure", "main", "run"]

_PROG = "swarmseek sensor"


class VirtualSensorError(RuntimeError):
    """The virtual sensor cannot reach zenoh: a clear message (the autopilot's problems are
    :class:`companion.autopilot.AutopilotError`)."""


# ----------------------------------------------------------------------------- argument types
def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def _seed_arg(text: str) -> int:
    if text.strip() == "0":
        return 0
    return _positive_int(text)


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``swarmseek sensor`` arguments to ``parser``."""
    parser.add_argument("--connect", required=True, type=connection_arg, metavar="CONN",
                        help="pymavlink connection to the autopilot, "
                             "e.g. tcp:127.0.0.1:5762 or udpin:0.0.0.0:14550")
    add_field_arguments(parser, "")  # --field or --field-config is required (checked in main)
    parser.add_argument("--source", type=source_enu, default=None, metavar="E,N,U",
                        help="field source (plumes: release point) in the field frame, metres (default: "
                             "the --field-config's, else 0,0,0; write --source=-5,2,10 when it starts with a minus)")
    parser.add_argument("--origin", required=True, type=origin_geodetic, metavar="LAT,LON,ALT",
                        help="geodetic origin of the field frame (degrees, degrees, metres AMSL)")
    parser.add_argument("--noise", type=nonnegative_float, default=0.0, metavar="STD",
                        help="standard deviation of the sensor noise, signal units (default 0)")
    parser.add_argument("--rate", type=positive_float, default=10.0, metavar="HZ",
                        help="readings per second (default 10)")
    parser.add_argument("--fleet", default="swarmseek",  # checked by the one rule, wire.fleet_name
                        help="fleet name in the zenoh key (default swarmseek, like swarmseek mock)")
    parser.add_argument("--sysid", type=sysid_arg, default=None, metavar="N",
                        help="autopilot system id (default: the first autopilot heartbeat's)")
    add_endpoint_arguments(parser, listen_help="zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
                           connect_help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    _add_zenoh_security_arguments(parser)
    parser.add_argument("--count", type=_positive_int, default=None, metavar="N", help="stop after N readings")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S", help="stop after S seconds")
    parser.add_argument("--timeout", type=positive_float, default=30.0, metavar="S",
                        help="how long to wait for the autopilot's heartbeat (default 30)")
    parser.add_argument("--wait-subscriber", type=nonnegative_float, default=2.0, metavar="S",
                        help="before the first reading, wait up to S seconds for a zenoh subscriber (default 2)")
    parser.add_argument("--retries", type=_positive_int, default=3, metavar="N",
                        help="TCP connection attempts (default 3)")
    parser.add_argument("--seed", type=_seed_arg, default=None, help="noise seed, an integer >= 0 (default: random)")
    parser.add_argument("--quiet", action="store_true", help="print only errors")


# ----------------------------------------------------------------------------- main loop
def _open_zenoh(args):
    try:
        import zenoh
    except ImportError as exc:
        raise VirtualSensorError(f"zenoh is not installed: {exc}") from None
    try:
        conf = zenoh_config(listen=args.zenoh_listen or None, connect=args.zenoh_connect or None,
                            **security_kwargs(args))
    except ValueError as exc:  # ZenohFlagError, or a TLS file that vanished
        raise VirtualSensorError(f"bad zenoh settings: {exc}") from None
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError and friends: bad or busy endpoint
        raise VirtualSensorError(f"cannot open the zenoh session: {exc}") from None


def _log(args, text: str) -> None:
    if not args.quiet:
        print(f"swarmseek sensor: {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the virtual sensor until ``--count`` / ``--duration`` (or forever); returns readings sent.

    Raises
    ------
    VirtualSensorError
        When zenoh cannot be reached.
    companion.autopilot.AutopilotError
        When the autopilot cannot be reached or the link is lost.
    """
    _name, field, response = field_from_args(args, args.source)
    conn = open_mavlink(args.connect, args.retries)
    session = publisher = None
    try:
        hb = wait_heartbeat(conn, args.sysid, args.timeout)
        sysid = hb.get_srcSystem()
        session = _open_zenoh(args)
        publisher = SensorPublisher(session, args.fleet, [sysid])
        sensor = SignalSensor(field, args.noise, np.random.default_rng(args.seed), FaultSet(), args.fleet, sysid)
        sensor.set_response(**response)
        _log(args, f"autopilot sysid {sysid} on {args.connect}; publishing {sensor_key(args.fleet, sysid)} "
                   f"at {args.rate:g} Hz")
        stream = PositionStream(conn, sysid, hb.get_srcComponent(), args.rate, lambda text: _log(args, text))
        return _loop(args, stream, publisher, sensor)
    finally:
        if publisher is not None:
            publisher.close()
        if session is not None:
            session.close()
        close_mavlink(conn)


def _loop(args, stream: PositionStream, publisher, sensor) -> int:
    end = None if args.duration is None else time.monotonic() + args.duration
    period_s = 1.0 / args.rate
    waited = False
    last_pub = -math.inf
    sent = 0
    while (args.count is None or sent < args.count) and (end is None or time.monotonic() < end):
        fix = stream.next_fix(0.05)
        if fix is None:
            continue
        if fix.received_s - last_pub < 0.75 * period_s:
            continue  # the autopilot streams faster than asked: keep our rate
        if not waited:
            waited = True
            if not _wait_for_subscriber(publisher, stream.sysid, args.wait_subscriber) and args.wait_subscriber > 0:
                _log(args, f"no zenoh subscriber matched within {args.wait_subscriber:g} s (coordinator not up, "
                           "or its TLS / login refused us?); publishing anyway")
        enu = geodetic_to_enu(fix.lat_deg, fix.lon_deg, fix.alt_m, args.origin)
        publisher.publish(sensor.sample(time.time(), enu, fix.lat_deg, fix.lon_deg, fix.alt_m))
        last_pub = time.monotonic()
        sent += 1
    _log(args, f"published {sent} readings")
    return sent


def _wait_for_subscriber(publisher, sysid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not publisher.has_subscribers(sysid) and time.monotonic() < deadline:
        time.sleep(0.02)
    return publisher.has_subscribers(sysid)


def main(args: argparse.Namespace) -> int:
    """Entry point of ``swarmseek sensor``: 0 on success, 1 with a one-line message on failure,
    2 when no zenoh endpoint was given or the zenoh TLS / login flags do not fit together."""
    if not (args.field or args.field_config or args.field_python or args.field_npz):
        return usage_error(_PROG, "give --field or --field-config (or --field-python, --field-npz)")
    try:
        _name, field, _response = field_from_args(args, args.source)
        probe_custom_field(field, time.time())  # a plug-in's values checked before connecting
    except ValueError as exc:
        return usage_error(_PROG, str(exc))
    if not args.zenoh_listen and not args.zenoh_connect:
        return usage_error(_PROG, "give --zenoh-listen and/or --zenoh-connect, e.g. "
                                  "--zenoh-connect tcp/127.0.0.1:7447 for a coordinator flying the sample plan on "
                                  "this machine (zenoh endpoints are always explicit)")
    try:
        security_kwargs(args)
    except ZenohFlagError as exc:
        return usage_error(_PROG, str(exc))
    warning = plain_network_warning(_PROG, args.zenoh_listen, args.zenoh_connect)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    try:
        run(args)
    except (VirtualSensorError, AutopilotError) as exc:
        return fail(_PROG, f"error: {exc}", 1)
    return 0
