"""The ``swarmseek`` command line: argument parsing only; every command is ``main(args)`` elsewhere.

Each subcommand lives in its own module exposing ``configure(parser)`` (adds its arguments) and
``main(args) -> int`` (does the work). Modules are imported lazily so that one command's heavy
imports never slow down another, and a command whose module fails to import says so clearly.
"""
from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["COMMANDS", "build_parser", "main", "version_text"]

#: the commands that fly a mission: SIGPIPE is blocked before anything starts a thread
#: (:func:`mission.telemetry.terminal.sigpipe_blocked`; docs/faults.md) and their terminal is best
#: effort (they fly on); any other command whose stdout or stderr reader goes away (``| head -1``)
#: ends quietly with status 141 (:func:`mission.telemetry.terminal.silence_broken_pipes`)
FLYING_COMMANDS = ("run", "fly", "resume")

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("mission.cli.cmd_run", "fly the whole source-seeking mission against an embedded mock swarm"),
    "fly": ("mission.cli.cmd_fly", "fly the mission against the vehicles named in a plan file"),
    "dry-run": ("mission.cli.cmd_dryrun", "validate a plan, connect and run preflight checks; arms nothing"),
    "resume": ("mission.cli.cmd_resume", "restart a stopped mission from its mission log"),
    "watch": ("mission.cli.cmd_watch", "the live table of a running mission, over zenoh from anywhere"),
    "ctl": ("mission.cli.cmd_ctl", "command a running mission over zenoh: pause, continue, abort, land, rtl, return"),
    "map": ("mission.cli.cmd_map", "the live map of a running mission in a browser (or --log: a replay)"),
    "plot": ("mission.cli.cmd_plot", "figures of a flown mission from its mission log"),
    "export": ("mission.cli.cmd_export", "a flown mission as KML (Google Earth) or GeoJSON (QGIS): tracks, fence, estimate"),
    "audit": ("mission.cli.cmd_audit", "check from the .tlog files that no setpoint broke the fence, speed or separation"),
    "paper": ("experiments.paper", "regenerate the paper's table and figures from our own geometry"),
    "simulate": ("experiments.cmd_simulate", "offline source-seeking simulation (perfect tracking, no MAVLink)"),
    "sitl": ("mission.cli.cmd_sitl", "start a fleet of real PX4 SIH or ArduCopter SITL autopilots until interrupted"),
    "mock": ("sitl_mock.cli", "run a fleet of mock autopilots until interrupted"),
    "sensor": ("sitl_mock.virtual_sensor", "publish readings for a real autopilot's position over zenoh"),
    "publish": ("companion.cmd_publish", "publish a real sensor's readings (one number a line, serial or stdin) at the autopilot's position over zenoh"),
}


class _Parser(argparse.ArgumentParser):
    """ArgumentParser that exits with status 2 and a one-line error, never a traceback."""


def _load(module_name: str):
    return importlib.import_module(module_name)


def version_text() -> str:
    """``swarmseek X.Y.Z`` from the installed package's metadata (``unknown`` when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"swarmseek {version('swarmseek')}"
    except PackageNotFoundError:
        return "swarmseek (version unknown: the package is not installed)"


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """Build the top-level parser; only the chosen subcommand's module is imported."""
    parser = _Parser(prog="swarmseek", description="Multi-drone 3D source seeking ground station.")
    parser.add_argument("--version", action="version", version=version_text())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = None
    if argv:
        chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            try:
                module = _load(module_name)
            except ImportError as exc:
                parser.error(f"command {name!r} is not available: {exc}")
            module.configure(p)
            # the chosen command's module (its ``main(args)`` runs it) and its own parser (its
            # usage on an error after the command): public names every command may read
            p.set_defaults(command_module=module, command_parser=p)
    return parser


def _check_fleet_argument(args: argparse.Namespace) -> None:
    """Every command's fleet name (``ctl``/``watch`` FLEET, ``--fleet`` of ``sitl``, ``mock`` and
    ``sensor``) through the one rule of :mod:`wire.fleet_name`: a usage error (exit 2)."""
    from wire.fleet_name import check_fleet_name

    fleet = getattr(args, "fleet", None)
    if fleet is not None:
        try:
            check_fleet_name(fleet)
        except ValueError as exc:
            args.command_parser.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``swarmseek`` console command."""
    if argv is None:
        argv = sys.argv[1:]
    if next((a for a in argv if not a.startswith("-")), None) in FLYING_COMMANDS:
        from mission.telemetry.terminal import sigpipe_blocked

        with sigpipe_blocked():  # before numpy, zenoh... start their threads: they all inherit it
            return _main(argv)
    return _main(argv)


def _main(argv: list[str]) -> int:
    """Parse ``argv`` and run the chosen command; its exit status."""
    parser = build_parser(argv)
    args, extra = parser.parse_known_args(argv)
    if extra:  # after the command: the subcommand's usage and error, not the top level's
        after_command = args.command in argv and extra[0] in argv[argv.index(args.command) + 1:]
        (args.command_parser if after_command else parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if args.command is None:
        parser.print_help()
        return 2
    _check_fleet_argument(args)
    try:
        return int(args.command_module.main(args) or 0)
    except KeyboardInterrupt:
        print("swarmseek: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `swarmseek simulate | head -1`: the reader is gone, end quietly
        from mission.telemetry.terminal import SIGPIPE_STATUS, silence_broken_pipes

        if not silence_broken_pipes():
            raise  # not the terminal's pipe: a fault of the command, shown
        return SIGPIPE_STATUS


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
