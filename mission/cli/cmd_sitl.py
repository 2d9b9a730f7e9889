"""``swarmseek sitl``: start a fleet of real SITL autopilots for a dry run, until interrupted.

Starts N PX4 SIH or ArduCopter SITL instances (:mod:`mission.sim.sitl_fleet`), waits until each
is ready, writes a ready-to-fly plan, prints the connection strings and the exact ``swarmseek
sensor`` / ``fly`` / ``audit`` commands, then stays up until Ctrl-C or SIGTERM and stops every
instance (no orphan processes, no lock files left). The SITL folder comes from
``SWARMSEEK_PX4_SITL`` / ``SWARMSEEK_ARDUPILOT_SITL`` or ``--sitl-dir`` (docs/sitl.md).

Exit status: 0 after a clean stop, 1 when an instance fails to start or dies, 2 for invalid
options or a missing/wrong SITL setting (one-line message).
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from estimator.seekers import SEEKERS
from mission.sim.sitl_plan import seeker_settings
from wire.cli_args import fail, int_in_range, origin_geodetic, path_arg, positive_float, source_enu, usage_error

__all__ = ["configure", "main"]

_PROG = "swarmseek sitl"

#: a formation (hence a plan) needs at least this many vehicles
_MIN_MISSION_VEHICLES = 4


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not name.replace("_", "").isalnum():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (a parameter name and a number), got {text!r}")
    try:
        number = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"parameter {name!r}: {value!r} is not a number") from None
    return name.strip().upper(), int(number) if number.is_integer() else number


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``sitl`` arguments."""
    parser.add_argument("--flavour", required=True, choices=("px4", "ardupilot"), help="PX4 SIH or ArduCopter SITL")
    parser.add_argument("--n", type=int_in_range(1, 254, "--n"), default=4, help="number of vehicles (default 4)")
    parser.add_argument("--sitl-dir", type=path_arg, default=None, metavar="DIR",
                        help="SITL folder (default: $SWARMSEEK_PX4_SITL or $SWARMSEEK_ARDUPILOT_SITL)")
    parser.add_argument("--plan-out", type=path_arg, default=Path("sitl-plan.toml"), metavar="FILE",
                        help="where to write the ready-to-fly plan (default sitl-plan.toml)")
    parser.add_argument("--first-instance", type=int_in_range(0, 250, "--first-instance"), default=None,
                        help="instance number of the first vehicle (system id = instance + 1)")
    parser.add_argument("--port-offset", type=int_in_range(0, 45000, "--port-offset"), default=None,
                        help="PX4: PX4_PORT_OFFSET; ArduPilot: base port 5760 + offset (default 0)")
    parser.add_argument("--free-layout", action="store_true",
                        help="pick free instance numbers and a free port offset (not with the two options above)")
    parser.add_argument("--spacing", type=positive_float, default=4.0, metavar="M", help="homes M metres apart (east)")
    parser.add_argument("--home", type=origin_geodetic, default=None, metavar="LAT,LON,ALT",
                        help="home of the first vehicle (default: the flavour's usual SITL home)")
    parser.add_argument("--speedup", type=positive_float, default=1.0, help="simulation speed-up (default 1)")
    parser.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                        help="extra autopilot parameter (repeatable)")
    parser.add_argument("--seeker", choices=SEEKERS, default="model",
                        help="the written plan's [seeking] seeker (default model, gamma_m 20 m, sampling while moving; "
                             "gradient = the paper's method, gamma_m 1 m); measured on real PX4 and "
                             "ArduCopter SITL in docs/sitl.md")
    parser.add_argument("--run-dir", type=path_arg, default=None, metavar="DIR",
                        help="keep the instances' working dirs here (default: a temporary dir, deleted)")
    parser.add_argument("--ready-timeout", type=positive_float, default=120.0, metavar="S",
                        help="seconds to wait until every instance is ready (default 120)")
    parser.add_argument("--zenoh-port", type=int_in_range(1, 65535, "--zenoh-port"), default=7447,
                        help="the plan's coordinator listens on tcp/127.0.0.1:PORT (default 7447)")
    parser.add_argument("--fleet", default="sitl", help="zenoh fleet name of the plan and the sensors")
    parser.add_argument("--source", type=source_enu, default=(10.0, 30.0, 14.0), metavar="E,N,U",
                        help="source position for the printed sensor commands (default 10,30,14)")


def _config(args: argparse.Namespace):
    from mission.sim.sitl_fleet import SitlFleetConfig

    cfg = SitlFleetConfig(flavour=args.flavour, n=args.n, sitl_dir=args.sitl_dir,
                          first_instance=args.first_instance or 0, port_offset=args.port_offset or 0,
                          spacing_m=args.spacing, home=args.home, speedup=args.speedup,
                          params=dict(args.param), run_dir=args.run_dir, ready_timeout_s=args.ready_timeout)
    return cfg.free() if args.free_layout else cfg


def _commands(fleet, args, plan: Path) -> list[str]:
    src = ",".join(f"{x:g}" for x in args.source)
    origin = ",".join(f"{x:.7f}" if i < 2 else f"{x:g}" for i, x in enumerate(fleet.origin))
    lines = [f"swarmseek sensor --connect {v.sensor_connection} --sysid {v.sysid} --fleet {args.fleet} "
             f"--field sigma2 --source={src} --origin={origin} --zenoh-connect tcp/127.0.0.1:{args.zenoh_port} &"
             for v in fleet.vehicles]
    lines += [f"swarmseek dry-run --plan {plan}",
              f"swarmseek fly --plan {plan} --log-dir sitl-logs",
              "swarmseek audit sitl-logs"]
    return lines


def _report(fleet, args, plan: Path | None) -> None:
    print(f"{len(fleet.vehicles)} {args.flavour} SITL instances (run dir {fleet.run_dir}):")
    for v in fleet.vehicles:
        print(f"  sysid {v.sysid:3d}  instance {v.instance:3d}  pid {v.pid:7d}  ground station {v.connection}"
              f"  sensor {v.sensor_connection}  home {v.home[0]:.7f},{v.home[1]:.7f},{v.home[2]:g}")
    if plan is None:
        print(f"no plan written: a mission needs at least {_MIN_MISSION_VEHICLES} vehicles")
    else:
        print(f"plan: {plan}")
    print("run, in other terminals:")
    for line in _commands(fleet, args, plan or args.plan_out):
        print(f"  {line}")
    print(f"ready: {len(fleet.vehicles)} vehicles up; Ctrl-C or SIGTERM stops them", flush=True)


def _serve(fleet) -> int:
    """Wait until interrupted (KeyboardInterrupt) or until an instance dies (exit 1)."""
    from mission.sim.sitl_settings import SitlSetupError

    idle = threading.Event()
    while True:
        try:
            fleet.check_alive()
        except SitlSetupError as exc:
            return fail(_PROG, str(exc), 1)
        idle.wait(1.0)


def main(args: argparse.Namespace) -> int:
    """Start the fleet, print how to fly it, serve until Ctrl-C/SIGTERM, stop everything."""
    from mission.sim.sitl_fleet import SitlFleet, sigterm_as_interrupt
    from mission.sim.sitl_settings import SitlSetupError

    if args.free_layout and (args.first_instance is not None or args.port_offset is not None):
        return usage_error(_PROG, "--free-layout picks the instance numbers and the port offset itself: "
                                  "give it or --first-instance/--port-offset, not both")
    with sigterm_as_interrupt():
        try:
            cfg = _config(args)
            fleet = SitlFleet(cfg)
        except SitlSetupError as exc:
            return usage_error(_PROG, str(exc))
        print(f"starting {cfg.n} {cfg.flavour} SITL instances from {fleet.sitl_dir} ...", flush=True)
        try:
            with fleet:
                plan = None
                if cfg.n >= _MIN_MISSION_VEHICLES:
                    plan = fleet.write_plan(args.plan_out, fleet=args.fleet,
                                            zenoh_endpoint=f"tcp/127.0.0.1:{args.zenoh_port}",
                                            overrides={"seeking": seeker_settings(args.seeker)}).resolve()
                _report(fleet, args, plan)
                try:
                    status = _serve(fleet)
                except KeyboardInterrupt:
                    status = 0
                finally:
                    _ignore_signals()  # a second Ctrl-C must not cut the stop short
            print("swarmseek sitl: stopped every instance", file=sys.stderr)
            return status
        except KeyboardInterrupt:
            print("swarmseek sitl: interrupted while starting; stopped every instance", file=sys.stderr)
            return 0
        except (SitlSetupError, OSError, ValueError) as exc:
            return fail(_PROG, str(exc), 1)


def _ignore_signals() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
