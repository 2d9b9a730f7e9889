"""``swarmseek map FLEET --zenoh-connect EP``: the operator's live map in a browser; ``--log`` replays.

Serves the page (:mod:`mission.telemetry.map_server`) on ``--bind`` (default 127.0.0.1:8470), fed
by the mission state publication that ``swarmseek watch`` reads; its command buttons go the way
of ``swarmseek ctl``. Bound to any address other than loopback the page is read-only unless
``--password-file`` names the operator password. ``--log mission.jsonl`` replays a flown mission
(``--speed``, a slider on the page; always read-only). Runs until Ctrl-C (status 0). Exit status:
2 invalid options (a bad ``--bind``, ``--tile-url``, password file), 1 the address cannot be
served (e.g. the port is in use) or the log cannot be read, 3 the zenoh endpoint was not
reached within ``--wait-s``.

``run``, ``fly`` and ``resume --map [HOST:]PORT`` start the same server beside the mission, fed
through the mission's own zenoh session (:func:`start_map_thread`).
"""
from __future__ import annotations

import argparse
import asyncio
import signal
import socket
import sys
from pathlib import Path

from mission.cli.cmd_watch import add_zenoh_options, open_zenoh
from wire.cli_args import fail, path_arg, positive_float

__all__ = ["DEFAULT_PORT", "bind_address", "tile_url", "configure", "main", "add_map_option", "map_access",
           "start_map_thread", "free_local_port"]

DEFAULT_PORT = 8470
_PROG = "swarmseek map"


def bind_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` (``[v6]:PORT`` for IPv6) as ``(host, port)``; host defaults to 127.0.0.1.

    Raises
    ------
    argparse.ArgumentTypeError
        Not a port in 0..65535, or an empty host.
    """
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535 or not host:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT with a port in 0..65535, got {text!r}")
    return host, number


def tile_url(text: str) -> str:
    """A tile URL template: ``http(s)://...`` with ``{z}``, ``{x}`` and ``{y}``."""
    if not text.startswith(("http://", "https://")) or any(k not in text for k in ("{z}", "{x}", "{y}")):
        raise argparse.ArgumentTypeError(
            f"a tile URL template is http(s)://HOST/.../{{z}}/{{x}}/{{y}}.png (a local tile server), got {text[:120]!r}")
    if any(ch in text for ch in "\"'<> \n"):
        raise argparse.ArgumentTypeError("the tile URL template has a quote, bracket or space")
    return text


def add_map_option(parser: argparse.ArgumentParser) -> None:
    """``--map [HOST:]PORT`` and its ``--map-password-file`` / ``--map-tile-url`` (``run``, ``fly``, ``resume``)."""
    parser.add_argument("--map", type=bind_address, default=None, metavar="[HOST:]PORT",
                        help="serve the live map on this address (127.0.0.1 unless HOST; port 0: any free port; "
                             "the URL is printed; docs/operator.md)")
    parser.add_argument("--map-password-file", type=path_arg, default=None, metavar="FILE",
                        help="with --map on a non-loopback address: the operator password that allows commands")
    parser.add_argument("--map-tile-url", type=tile_url, default=None, metavar="TEMPLATE",
                        help="base map tiles for --map, e.g. http://127.0.0.1:8080/{z}/{x}/{y}.png")


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``map`` options."""
    parser.add_argument("fleet", nargs="?", default=None,
                        help="the mission's fleet name (the plan's fleet; 'swarmseek' for run); not with --log")
    add_zenoh_options(parser)
    parser.add_argument("--bind", type=bind_address, default=("127.0.0.1", DEFAULT_PORT), metavar="HOST:PORT",
                        help=f"serve the page here (default 127.0.0.1:{DEFAULT_PORT}; port 0: any free port)")
    parser.add_argument("--password-file", type=path_arg, default=None, metavar="FILE",
                        help="the operator password (first line): bound to a non-loopback address, commands need it")
    parser.add_argument("--read-only", action="store_true", help="offer no commands")
    parser.add_argument("--tile-url", type=tile_url, default=None, metavar="TEMPLATE",
                        help="base map tiles from a local tile server, e.g. http://127.0.0.1:8080/{z}/{x}/{y}.png")
    parser.add_argument("--sender", default=None, metavar="ID",
                        help="who the page's commands are from, for the mission log (default map:USER@HOST)")
    parser.add_argument("--wait-s", type=positive_float, default=10.0, metavar="S",
                        help="give up (status 3) when the zenoh endpoint is not reached within S s (default 10)")
    parser.add_argument("--log", type=path_arg, default=None, metavar="MISSION.jsonl",
                        help="replay this mission log instead of a live mission")
    parser.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                        help="replay speed (mission seconds per wall second; default 1)")


def read_password(path: Path | None) -> tuple[bytes | None, str | None]:
    """The password (first line of ``path``) or the reason it cannot be used."""
    if path is None:
        return None, None
    try:
        line = Path(path).read_bytes()[:4096].splitlines()[:1]
    except OSError as exc:
        return None, f"cannot read the password file {path}: {exc.strerror or exc}"
    if not line or not line[0].strip():
        return None, f"the password file {path} is empty"
    return line[0].strip(), None


def map_access(host: str, password_file, read_only_reason: str | None = None):
    """``(MapAccess, None)`` or ``(None, problem)`` for the password file."""
    from mission.telemetry.map_server import MapAccess

    password, problem = read_password(password_file)
    if problem:
        return None, problem
    return MapAccess(host, password=password, read_only_reason=read_only_reason), None


def _sender(args) -> tuple[str | None, str | None]:
    from mission.flight.control import check_sender
    from mission.telemetry.watch import default_sender

    sender = args.sender if args.sender is not None else f"map:{default_sender()}"[:64]
    return sender, check_sender(sender)


def main(args) -> int:
    """Serve the map until Ctrl-C; 0 then (see the module for the other statuses)."""
    if args.log is not None:
        return _replay(args)
    if args.fleet is None:
        return fail(_PROG, "give the FLEET to watch (or --log MISSION.jsonl to replay one)")
    problem = None
    sender, sender_problem = _sender(args)
    access, access_problem = map_access(args.bind[0], args.password_file,
                                        "--read-only" if args.read_only else None)
    if sender_problem:
        problem = f"--sender: {sender_problem}"
    if problem or access_problem:
        return fail(_PROG, problem or access_problem)
    session, problem, status = open_zenoh(args, _PROG, args.wait_s)
    if session is None:
        print(problem, file=sys.stderr)
        return status
    from mission.telemetry.map_live import serve_live

    config = {"tile_url": args.tile_url, "truth_enu": None, "replay": None}
    return _serve(lambda stop: serve_live(lambda: session, args.fleet, *args.bind, access=access, sender=sender,
                                          config=config, ready=_announce, stop=stop))


def _announce(server) -> None:
    print(f"swarmseek map: serving {server.url} (Ctrl-C stops)", file=sys.stderr, flush=True)


def _serve(make) -> int:
    """Run ``make(stop_event)`` until Ctrl-C / SIGTERM; 0, or 1 with one line when it cannot bind."""
    async def body() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await make(stop)

    try:
        asyncio.run(body())
    except OSError as exc:
        return fail(_PROG, f"cannot serve the map: {exc.strerror or exc}", 1)
    print("swarmseek map: stopped", file=sys.stderr)
    return 0


def _replay(args) -> int:
    from mission.telemetry.map_replay import MissionLogReplay, ReplayError, serve_replay

    if args.fleet is not None or args.zenoh_connect or args.zenoh_listen:
        return fail(_PROG, "--log replays a mission log: give no FLEET and no zenoh endpoint with it")
    access, problem = map_access(args.bind[0], None, "a replay of a mission log: nothing to command")
    try:
        replay = MissionLogReplay.load(args.log)
    except ReplayError as exc:
        return fail(_PROG, str(exc), 1)
    config = {"tile_url": args.tile_url}
    return _serve(lambda stop: serve_replay(replay, *args.bind, access=access, config=config, speed=args.speed,
                                            ready=_announce, stop=stop))


# ----------------------------------------------------------------------------- run --map
def free_local_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_map_thread(args, fleet: str, prog: str, truth_enu=None):
    """Start ``--map``'s server (``run``, ``fly``, ``resume``): ``(MapThread, None)``, ``(None, None)``
    without ``--map``, or ``(None, exit status)`` once the problem is printed as one line.

    The server is bound here, before anything flies (a port in use is refused with nothing
    armed); it reads the state and sends the page's commands through the mission's own zenoh
    session, which the mission hands over once open (:meth:`MapThread.attach`): no endpoint is
    added to the plan and no credential is read (docs/operator.md, "The live map")."""
    if args.map is None:
        return None, None
    from mission.telemetry.map_live import MapThread

    host, port = args.map
    access, problem = map_access(host, args.map_password_file)
    sender, sender_problem = _sender(argparse.Namespace(sender=None))
    if problem or sender_problem:
        return None, fail(prog, f"--map-password-file: {problem}" if problem else sender_problem)
    config = {"tile_url": args.map_tile_url, "replay": None,
              "truth_enu": None if truth_enu is None else [float(x) for x in truth_enu]}
    thread = MapThread(fleet, host, port, access=access, sender=sender, config=config)
    try:
        url = thread.start()
    except OSError as exc:
        return None, fail(prog, f"--map: cannot serve the map on {host}:{port}: {exc.strerror or exc}", 1)
    print(f"{prog}: live map at {url}", file=sys.stderr, flush=True)
    return thread, None
