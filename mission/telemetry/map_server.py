"""The operator's live map: a web server (aiohttp) pushing the mission state to a page (server-sent events).

The page (``map_static/``: HTML, script and styles shipped in the package, no CDN) is served at
``/``; ``/events`` streams the state as server-sent events (:class:`mission.telemetry.map_feed.MapFeed`:
each snapshot of the state publication as it arrives, no polling by the page); ``/api/command``
sends an operator command through the same path as ``swarmseek ctl``
(:func:`mission.telemetry.watch.send_command`: a zenoh query, the coordinator's acknowledgement,
the sender recorded in the mission log).

Access (:class:`MapAccess`): bound to a loopback address the page may command; bound to any
other address it is read-only unless an operator password file is given, and then a command
needs a session cookie from ``/api/login`` (password checked with :func:`hmac.compare_digest`).
Every command also needs the page's CSRF token (header ``X-CSRF-Token``) and a same-origin
``Origin`` header. A replay is always read-only.
"""
from __future__ import annotations

import asyncio
import hmac
import ipaddress
import secrets
from importlib import resources
from typing import Callable

from aiohttp import web

from mission.telemetry.map_feed import MapFeed

__all__ = ["COMMANDS", "DESTRUCTIVE", "FEED", "ACCESS", "SEND", "PLAYER", "MapAccess", "is_loopback", "make_app",
           "MapServer"]

#: Commands the page offers (as ``swarmseek ctl``'s) and those it confirms first
COMMANDS = ("pause", "continue", "abort", "return", "land", "rtl")
DESTRUCTIVE = ("abort", "return", "land", "rtl")
_COOKIE = "swarmseek_map_session"
_STATIC_FILES = {"index.html": "text/html", "map.js": "application/javascript", "map.css": "text/css"}
_MAX_BODY_BYTES = 4096
FEED = web.AppKey("feed", MapFeed)
ACCESS = web.AppKey("access", object)
SEND = web.AppKey("send_command", object)
PLAYER = web.AppKey("player", object)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is a loopback address."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class MapAccess:
    """Who may command from the page.

    Parameters
    ----------
    bind_host : str
        The address the server binds.
    password : bytes, optional
        The operator password (from ``--password-file``): commands need a login.
    read_only_reason : str, optional
        Forces read-only (a replay, ``--read-only``, no command path).
    """

    def __init__(self, bind_host: str, password: bytes | None = None, read_only_reason: str | None = None):
        self.password = password
        self.csrf_token = secrets.token_urlsafe(32)
        self._sessions: set[str] = set()
        self.refused = 0
        if read_only_reason is None and password is None and not is_loopback(bind_host):
            read_only_reason = (f"bound to {bind_host}, not a loopback address, without --password-file: "
                                "commands are refused")
        self.read_only_reason = read_only_reason

    @property
    def read_only(self) -> bool:
        """Whether every command is refused."""
        return self.read_only_reason is not None

    def login(self, password: str) -> str | None:
        """A new session token if ``password`` is right (constant-time comparison), else None."""
        if self.password is None or not hmac.compare_digest(password.encode("utf-8"), self.password):
            return None
        token = secrets.token_urlsafe(32)
        self._sessions.add(token)
        return token

    def foreign(self, request: web.Request) -> str | None:
        """Why ``request`` does not come from this server's page (``Origin``, CSRF token), or None."""
        origin = request.headers.get("Origin")
        if origin != f"{request.scheme}://{request.host}":
            return f"cross-origin request refused (Origin {str(origin)[:80]!r})"
        if not hmac.compare_digest(request.headers.get("X-CSRF-Token", ""), self.csrf_token):
            return "missing or wrong CSRF token (reload the page)"
        return None

    def refusal(self, request: web.Request) -> str | None:
        """Why ``request`` may not command, or None."""
        if self.read_only:
            return f"read-only: {self.read_only_reason}"
        problem = self.foreign(request)
        if problem:
            return problem
        if self.password is not None:
            session = request.cookies.get(_COOKIE, "")
            if not any(hmac.compare_digest(session, s) for s in self._sessions):
                return "log in first (operator password)"
        return None


def _static(name: str) -> bytes:
    return resources.files("mission.telemetry").joinpath("map_static", name).read_bytes()


async def _events(request: web.Request) -> web.StreamResponse:
    """``/events``: the server-sent event stream of one page, until the page goes away or the
    server stops (``None`` queued by :meth:`MapFeed.close_pages`)."""
    feed: MapFeed = request.app[FEED]
    resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-store",
                                       "X-Accel-Buffering": "no"})
    await resp.prepare(request)
    q = feed.subscribe()
    try:
        while (msg := await q.get()) is not None:
            await resp.write(msg)
    except ConnectionResetError:
        pass  # the page went away: nothing to tell
    finally:
        feed.unsubscribe(q)
    return resp


async def _json_body(request: web.Request) -> dict | None:
    if request.content_length is not None and request.content_length > _MAX_BODY_BYTES:
        return None
    try:
        body = await request.json()
    except ValueError:
        return None
    return body if isinstance(body, dict) else None


async def _command(request: web.Request) -> web.Response:
    """``POST /api/command {"command": ...}``: the coordinator's acknowledgement, or a refusal (403/400)."""
    access: MapAccess = request.app[ACCESS]
    problem = access.refusal(request)
    if problem:
        access.refused += 1
        return web.json_response({"accepted": False, "reason": problem}, status=403)
    body = await _json_body(request)
    command = None if body is None else body.get("command")
    if command not in COMMANDS:
        return web.json_response({"accepted": False, "reason": f"unknown command; commands: {', '.join(COMMANDS)}"},
                                 status=400)
    send: Callable[[str], dict] = request.app[SEND]
    ack = await asyncio.get_running_loop().run_in_executor(None, send, command)
    return web.json_response(ack)


async def _login(request: web.Request) -> web.Response:
    access: MapAccess = request.app[ACCESS]
    body = await _json_body(request)
    if access.read_only or access.password is None or body is None or not isinstance(body.get("password"), str):
        return web.json_response({"ok": False, "reason": "no login here"}, status=400)
    if request.headers.get("Origin") != f"{request.scheme}://{request.host}":
        return web.json_response({"ok": False, "reason": "cross-origin request refused"}, status=403)
    token = access.login(body["password"])
    if token is None:
        return web.json_response({"ok": False, "reason": "wrong password"}, status=403)
    resp = web.json_response({"ok": True})
    resp.set_cookie(_COOKIE, token, httponly=True, samesite="Strict")
    return resp


async def _replay_control(request: web.Request) -> web.Response:
    player = request.app.get(PLAYER)
    problem = request.app[ACCESS].foreign(request)
    if problem:
        return web.json_response({"ok": False, "reason": problem}, status=403)
    body = await _json_body(request)
    if player is None or body is None:
        return web.json_response({"ok": False, "reason": "not a replay"}, status=400)
    player.control(body)
    return web.json_response({"ok": True})


def _static_handler(name: str, content_type: str):
    data = _static(name)

    async def handler(_request: web.Request) -> web.Response:
        return web.Response(body=data, content_type=content_type,
                            headers={"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff",
                                     "Content-Security-Policy": "default-src 'self'; img-src * data:; "
                                                                "style-src 'self'; script-src 'self'"})
    return handler


async def _no_content(_request: web.Request) -> web.Response:
    return web.Response(status=204)


def make_app(feed: MapFeed, access: MapAccess, send_command: Callable[[str], dict] | None,
             player=None) -> web.Application:
    """The map's web application.

    Parameters
    ----------
    feed : MapFeed
    access : MapAccess
    send_command : callable or None
        ``send_command(command) -> acknowledgement dict`` (blocking: run in the executor);
        None only when ``access`` is read-only.
    player : mission.telemetry.map_replay.ReplayPlayer, optional
        A replay's player (``POST /api/replay``: position, speed, pause).
    """
    app = web.Application(client_max_size=_MAX_BODY_BYTES)
    app[FEED], app[ACCESS], app[SEND], app[PLAYER] = feed, access, send_command, player
    app.router.add_get("/", _static_handler("index.html", "text/html"))
    for name, ctype in _STATIC_FILES.items():
        app.router.add_get(f"/static/{name}", _static_handler(name, ctype))
    app.router.add_get("/events", _events)
    app.router.add_get("/favicon.ico", _no_content)
    app.router.add_post("/api/command", _command)
    app.router.add_post("/api/login", _login)
    app.router.add_post("/api/replay", _replay_control)
    return app


class MapServer:
    """Runs the application on ``host:port`` on the current event loop.

    ``port`` 0 picks a free port (:attr:`port` after :meth:`start`). :meth:`start` raises
    ``OSError`` when the address cannot be bound (e.g. the port is in use).
    """

    def __init__(self, app: web.Application, host: str, port: int):
        self.app, self.host, self.port = app, host, int(port)
        self._runner: web.AppRunner | None = None

    async def start(self) -> None:
        """Bind and serve."""
        self._runner = web.AppRunner(self.app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=False)
        try:
            await site.start()
        except OSError:
            await self._runner.cleanup()
            self._runner = None
            raise
        addresses = self._runner.addresses
        if addresses:
            self.port = int(addresses[0][1])

    @property
    def url(self) -> str:
        """``http://HOST:PORT/`` (IPv6 hosts bracketed)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    async def stop(self) -> None:
        """Close every page's stream and stop serving (a page's handler that waits for its next
        message would otherwise hold the shutdown for aiohttp's 60 s ``shutdown_timeout``)."""
        if self._runner is not None:
            self.app[FEED].close_pages()
            await self._runner.cleanup()
            self._runner = None
