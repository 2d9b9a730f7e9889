"""``swarmseek sensor``: a virtual sensor riding on a real (or SITL) autopilot.

Reads the autopilot's GLOBAL_POSITION_INT over MAVLink (any pymavlink connection string: it asks
for the rate it needs with MAV_CMD_SET_MESSAGE_INTERVAL), maps each position fix into the field
frame (ENU about ``--origin``), samples the simulated field there with the requested noise, and
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

from formation.geodesy import geodetic_to_enu
from sitl_mock.cli_args import add_field_arguments, field_from_args, probe_custom_field
from sitl_mock.faults import FaultSet
from sitl_mock.sensor import SensorPublisher, SignalSensor, sensor_key
from wire.cli_args import fail, nonnegative_float, origin_geodetic, positive_float, source_enu, usage_error
from wire.zenoh_config import zenoh_config
from wire.zenoh_flags import ZenohFlagError, add_endpoint_arguments, plain_network_warning, security_kwargs
from wire.zenoh_flags import add_arguments as _add_zenoh_security_arguments

__all__ = ["VirtualSensorError", "configure", "main", "run"]

_PROG = "swarmseek sensor"

_MSG_ID_GLOBAL_POSITION_INT = 33
_MAV_CMD_SET_MESSAGE_INTERVAL = 511
_MAV_TYPE_GCS = 6
_MAV_AUTOPILOT_INVALID = 8
_GCS_HEARTBEAT_PERIOD_S = 1.0
_REREQUEST_PERIOD_S = 3.0
_SILENCE_WARN_S = 5.0
_NET_PREFIXES = ("tcp:", "tcpin:", "udp:", "udpin:", "udpout:", "udpbcast:")


class VirtualSensorError(RuntimeError):
    """The virtual sensor cannot run (no link, no heartbeat, zenoh failure): a clear message."""


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


def _sysid_arg(text: str) -> int:
    v = _positive_int(text)
    if v > 255:
        raise argparse.ArgumentTypeError(f"a MAVLink system id is 1..255, got {text!r}")
    return v


def _connection_arg(text: str) -> str:
    for prefix in _NET_PREFIXES:
        if text.startswith(prefix):
            host, sep, port = text[len(prefix):].rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
                raise argparse.ArgumentTypeError(
                    f"bad connection {text!r}: expected {prefix}HOST:PORT, e.g. tcp:127.0.0.1:5762")
            return text
    if not text or text.startswith("-"):
        raise argparse.ArgumentTypeError(f"bad connection {text!r}")
    return text  # serial device or another pymavlink form: pymavlink judges it


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``swarmseek sensor`` arguments to ``parser``."""
    parser.add_argument("--connect", required=True, type=_connection_arg, metavar="CONN",
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
    parser.add_argument("--sysid", type=_sysid_arg, default=None, metavar="N",
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


# ----------------------------------------------------------------------------- MAVLink side
def _open_mavlink(connection: str, retries: int):
    from pymavlink import mavutil

    try:
        return mavutil.mavlink_connection(connection, source_system=255, source_component=158,
                                          autoreconnect=True, retries=retries, reconnect_delay=0.5)
    except (OSError, ValueError, ImportError) as exc:
        raise VirtualSensorError(f"cannot open MAVLink connection {connection!r}: {exc}") from None
    except Exception as exc:  # pymavlink raises assorted errors for odd device strings
        raise VirtualSensorError(
            f"cannot open MAVLink connection {connection!r}: {type(exc).__name__}: {exc}") from None


def _close_mavlink(conn) -> None:
    if getattr(conn, "port", True) is None:
        return  # pymavlink's mavtcp.close() fails after a failed reconnect left no socket
    try:
        conn.close()
    except OSError:
        pass


def _send_gcs_heartbeat(conn) -> None:
    conn.mav.heartbeat_send(_MAV_TYPE_GCS, _MAV_AUTOPILOT_INVALID, 0, 0, 0)


def _recv(conn, types, timeout_s: float):
    try:
        return conn.recv_match(type=types, blocking=True, timeout=timeout_s)
    except OSError as exc:
        raise VirtualSensorError(f"lost the MAVLink connection: {exc}") from None


def _wait_heartbeat(conn, sysid: int | None, timeout_s: float):
    deadline = time.monotonic() + timeout_s
    next_hb = 0.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_hb:
            _send_gcs_heartbeat(conn)  # lets udpout links and PX4 know we are here
            next_hb = time.monotonic() + _GCS_HEARTBEAT_PERIOD_S
        msg = _recv(conn, ["HEARTBEAT"], 0.2)
        if msg is None:
            continue
        if msg.type == _MAV_TYPE_GCS or msg.autopilot == _MAV_AUTOPILOT_INVALID:
            continue  # another ground station, not an autopilot
        if sysid is None or msg.get_srcSystem() == sysid:
            return msg
    who = "an autopilot" if sysid is None else f"autopilot sysid {sysid}"
    raise VirtualSensorError(f"no heartbeat from {who} within {timeout_s:g} s")


def _request_position_rate(conn, sysid: int, compid: int, rate_hz: float) -> None:
    conn.mav.command_long_send(sysid, compid, _MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                               _MSG_ID_GLOBAL_POSITION_INT, 1e6 / rate_hz, 0, 0, 0, 0, 0)


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
        When the autopilot or zenoh cannot be reached or the link is lost.
    """
    _name, field, response = field_from_args(args, args.source)
    conn = _open_mavlink(args.connect, args.retries)
    session = publisher = None
    try:
        hb = _wait_heartbeat(conn, args.sysid, args.timeout)
        sysid, compid = hb.get_srcSystem(), hb.get_srcComponent()
        session = _open_zenoh(args)
        publisher = SensorPublisher(session, args.fleet, [sysid])
        sensor = SignalSensor(field, args.noise, np.random.default_rng(args.seed), FaultSet(), args.fleet, sysid)
        sensor.set_response(**response)
        _log(args, f"autopilot sysid {sysid} on {args.connect}; publishing {sensor_key(args.fleet, sysid)} "
                   f"at {args.rate:g} Hz")
        return _loop(args, conn, publisher, sensor, sysid, compid)
    finally:
        if publisher is not None:
            publisher.close()
        if session is not None:
            session.close()
        _close_mavlink(conn)


def _loop(args, conn, publisher, sensor, sysid, compid) -> int:
    start = time.monotonic()
    end = None if args.duration is None else start + args.duration
    period_s = 1.0 / args.rate
    next_hb = next_request = start
    last_position = start  # monotonic time of the last GLOBAL_POSITION_INT from the autopilot
    got_position = waited = silent = False
    last_pub = -math.inf
    no_fix = sent = 0
    while (args.count is None or sent < args.count) and (end is None or time.monotonic() < end):
        now = time.monotonic()
        if now >= next_hb:
            _send_gcs_heartbeat(conn)
            next_hb = now + _GCS_HEARTBEAT_PERIOD_S
        if now - last_position > _SILENCE_WARN_S and not silent:
            silent, got_position = True, False  # ask again: the autopilot may have rebooted
            _log(args, f"no GLOBAL_POSITION_INT from sysid {sysid} for {_SILENCE_WARN_S:g} s; still trying")
        if now >= next_request and not got_position:  # until positions flow, ask now and then
            _request_position_rate(conn, sysid, compid, args.rate)
            next_request = now + _REREQUEST_PERIOD_S
        msg = _recv(conn, ["GLOBAL_POSITION_INT"], 0.05)
        if msg is None or msg.get_srcSystem() != sysid:
            continue
        got_position, last_position = True, time.monotonic()
        if silent:
            silent = False
            _log(args, "positions flow again")
        if msg.lat == 0 and msg.lon == 0:
            no_fix += 1  # autopilots send zeros before their first GPS fix
            if no_fix == 1:
                _log(args, "autopilot has no position fix yet (lat = lon = 0); waiting")
            continue
        if last_position - last_pub < 0.75 * period_s:
            continue  # the autopilot streams faster than asked: keep our rate
        if not waited:
            waited = True
            if not _wait_for_subscriber(publisher, sysid, args.wait_subscriber) and args.wait_subscriber > 0:
                _log(args, f"no zenoh subscriber matched within {args.wait_subscriber:g} s (coordinator not up, "
                           "or its TLS / login refused us?); publishing anyway")
        lat, lon, alt = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        enu = geodetic_to_enu(lat, lon, alt, args.origin)
        publisher.publish(sensor.sample(time.time(), enu, lat, lon, alt))
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
    except VirtualSensorError as exc:
        return fail(_PROG, f"error: {exc}", 1)
    return 0
