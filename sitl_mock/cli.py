"""``swarmseek mock``: run a fleet of mock autopilots until interrupted (or for ``--duration``).

Prints one line per vehicle with its system id and ports. Bad flags are argparse errors
(exit 2); a port already in use is a one-line error (exit 1).
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

from sitl_mock.cli_args import add_field_arguments, field_from_args, probe_custom_field
from wire.cli_args import (fail, int_in_range, nonnegative_float, origin_geodetic, path_arg, positive_float,
                           source_enu, usage_error)

__all__ = ["configure", "main"]

_PROG = "swarmseek mock"


_vehicles = int_in_range(1, 255, "--vehicles")
_port = int_in_range(0, 65535, "port (0 disables)")


def _fault(text: str):
    from sitl_mock.faults import FaultSet, parse_fault
    try:
        sysid, name, value = parse_fault(text)
        FaultSet().set(name, value)  # check the value now, not in the running fleet
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return sysid, name, value


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``mock`` command's arguments to ``parser``."""
    from sitl_mock.ap_modes import PERSONALITY_NAMES
    from wire.zenoh_flags import add_arguments as add_zenoh_security_arguments
    from wire.zenoh_flags import add_endpoint_arguments

    parser.add_argument("--vehicles", type=_vehicles, default=4, help="number of vehicles (sysid 1..N)")
    parser.add_argument("--personality", choices=PERSONALITY_NAMES, default="px4")
    add_field_arguments(parser, "sigma2")
    parser.add_argument("--source", type=source_enu, default=None, metavar="E,N,U",
                        help="field source (plumes: release point) in the mission frame, ENU m "
                             "(default: the --field-config's, else 0,0,0)")
    parser.add_argument("--origin", type=origin_geodetic, default=None, metavar="LAT,LON,ALT",
                        help="fleet / mission origin")
    parser.add_argument("--speedup", type=positive_float, default=1.0, help="simulated seconds per wall second")
    parser.add_argument("--seed", type=int_in_range(0, None, "--seed"), default=0,
                        help="seed of the fleet's noise and faults, an integer >= 0 (default 0)")
    parser.add_argument("--udp-base-port", type=_port, default=14540,
                        help="vehicle i streams to 127.0.0.1:BASE+i (0 disables UDP)")
    parser.add_argument("--udp-bind-base-port", type=_port, default=None,
                        help="vehicle i listens on 127.0.0.1:BASE+i (default 14580, or right after the "
                             "send range when N vehicles from --udp-base-port would reach it)")
    parser.add_argument("--tcp-base-port", type=_port, default=5760,
                        help="vehicle i serves TCP on 127.0.0.1:BASE+10*i (0 disables TCP)")
    parser.add_argument("--fleet", default="swarmseek", help="fleet name (zenoh keys)")
    add_endpoint_arguments(parser, listen_help="zenoh listen endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)",
                           connect_help="zenoh connect endpoint (repeatable)")
    add_zenoh_security_arguments(parser)
    parser.add_argument("--noise", type=nonnegative_float, default=0.0, help="sensor noise standard deviation")
    parser.add_argument("--fault", type=_fault, action="append", default=[], metavar="SYSID:NAME=VALUE",
                        help="inject a fault, e.g. 2:loss_uplink=0.2 (repeatable)")
    parser.add_argument("--signing-key-file", type=path_arg, default=None, metavar="PATH",
                        help="MAVLink 2 signing key file (64 hex characters, 32 raw bytes or a "
                             "one-line passphrase, not world-readable): every vehicle signs and "
                             "rejects unsigned or replayed commands")
    parser.add_argument("--duration", type=positive_float, default=None, metavar="S",
                        help="stop after S wall seconds (default: until Ctrl-C)")


def main(args: argparse.Namespace) -> int:
    """Run the fleet; returns the exit status."""
    from wire.signing import SigningError, load_key_file
    from sitl_mock.fleet import DEFAULT_ORIGIN, MockFleet
    from sitl_mock.sensor_response import set_fleet_response
    from sitl_mock.transport import PortInUseError
    from wire.zenoh_flags import ZenohFlagError, plain_network_warning, security_kwargs

    for sysid, _name, _value in args.fault:
        if sysid > args.vehicles:
            return usage_error(_PROG, f"--fault for sysid {sysid} but only {args.vehicles} vehicles")
    try:
        field_name, field, response = field_from_args(args, args.source)
        probe_custom_field(field, time.time())  # a plug-in's values checked before any socket opens
    except ValueError as exc:
        return usage_error(_PROG, str(exc))
    try:
        zenoh_security = security_kwargs(args)
    except ZenohFlagError as exc:
        return usage_error(_PROG, str(exc))
    warning = plain_network_warning(_PROG, args.zenoh_listen, args.zenoh_connect)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    signing_key = None
    if args.signing_key_file is not None:
        try:
            signing_key = load_key_file(args.signing_key_file)
        except SigningError as exc:
            return usage_error(_PROG, str(exc))
    try:
        fleet = MockFleet(
            n=args.vehicles, personality=args.personality, field=field,
            origin=args.origin or DEFAULT_ORIGIN, speedup=args.speedup, seed=args.seed,
            udp_base_port=args.udp_base_port, udp_bind_base_port=args.udp_bind_base_port,
            tcp_base_port=args.tcp_base_port, fleet_name=args.fleet, sensor_noise_std=args.noise,
            zenoh_listen=args.zenoh_listen or None, zenoh_connect=args.zenoh_connect or None,
            signing_key=signing_key, zenoh_security=zenoh_security)
        set_fleet_response(fleet, **response)
        for sysid, name, value in args.fault:
            fleet.set_fault(sysid, name, value)
    except ValueError as exc:
        return usage_error(_PROG, str(exc))
    try:
        fleet.start()
    except PortInUseError as exc:
        return fail(_PROG, f"error: {exc.strerror}", 1)
    except Exception as exc:  # OSError from sockets, zenoh.ZError from the zenoh session
        return fail(_PROG, f"error: cannot open the fleet's sockets or zenoh session: {exc}", 1)
    try:
        print(f"mock fleet {args.fleet!r}: {args.vehicles} x {args.personality}, "
              f"speedup {args.speedup:g}, origin {fleet.origin}, field {field_name}, "
              f"signing {'on' if signing_key is not None else 'off'}, "
              f"zenoh tls {'on' if 'tls' in zenoh_security else 'off'}, "
              f"zenoh login {'on' if 'username' in zenoh_security else 'off'}", flush=True)
        for v in fleet.vehicles:
            udp = (f"udp listen 127.0.0.1:{v.udp_bind_port} -> 127.0.0.1:{v.udp_send_port}"
                   if v.udp_bind_port else "udp off")
            tcp = f"tcp 127.0.0.1:{v.tcp_port}" if v.tcp_port else "tcp off"
            print(f"vehicle sysid={v.sysid} {v.autopilot.personality.name} {udp} {tcp}", flush=True)
        threading.Event().wait(args.duration)  # None: until KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    finally:
        fleet.stop()
    if fleet.errors:
        print(f"swarmseek mock: {len(fleet.errors)} internal error(s); first:\n{fleet.errors[0]}",
              file=sys.stderr)
        return 1
    return 0
