"""MAVLink forwarding to ground-control clients (QGroundControl, MAVProxy), like MAVProxy's ``--out``.

Every frame the mission's endpoints accept from a vehicle (the frames that go to its ``.tlog``:
forged or unplanned ones never do) is copied, byte for byte, to each ``udp:HOST:PORT`` of the
plan's ``[forward] out`` and of ``--out``. Frames a client sends back (to the forwarding
socket's address, as QGroundControl and MAVProxy do) are **dropped and counted** unless the plan
says ``[forward] allow_commands = true``; then a message addressed to a vehicle of the mission
(``target_system``; 0: every vehicle) is sent to it by the ground station, re-packed with the
ground station's own system id and signing, like any of its commands. Messages with no target
(the client's HEARTBEAT, ...) are never relayed.

Sockets are non-blocking; clients are read by an event-loop reader (never blocking the loop);
a frame a socket cannot take is counted in ``send_errors``, never waited for. Host names are
resolved **once**, before the mission connects to any vehicle (:func:`resolve_outs`, called by
``run``, ``fly``, ``resume`` and ``dry-run`` before their event loop starts: a name that does
not resolve is an invalid option, exit status 2, nothing armed); the :class:`Forwarder` sends to
numeric addresses only, so no frame ever waits on a DNS lookup (a ``sendto`` to a host name
resolves it on every call, inside the event loop).
"""
from __future__ import annotations

import asyncio
import socket

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.plan_sections import parse_forward_out

__all__ = ["Forwarder", "COUNTERS", "ForwardAddressError", "forwarding", "out_address", "plan_with_outs",
           "resolve_out", "resolve_outs"]

COUNTERS = ("frames_out", "bytes_out", "send_errors", "client_frames", "relayed",
            "dropped_read_only", "dropped_no_target", "dropped_bad")


class ForwardAddressError(ValueError):
    """A forward address that is invalid or whose host name does not resolve (one line, for the operator)."""


def resolve_out(text: str, numeric_only: bool = False) -> tuple[str, int]:
    """The numeric ``(IPv4, port)`` of the forward address ``text`` (``udp:HOST:PORT``).

    Parameters
    ----------
    text : str
        ``udp:HOST:PORT``; HOST an IPv4 address or a host name.
    numeric_only : bool
        Refuse a host name instead of resolving it (no DNS lookup: safe inside an event loop).

    Returns
    -------
    tuple of (str, int)

    Raises
    ------
    ForwardAddressError
        Not of that form, a port out of 1..65535, an invalid IPv4 address, or a name that does
        not resolve (to an IPv4 address: the forward sockets are IPv4).
    """
    try:
        host, port = parse_forward_out(text)
    except ValueError as exc:
        raise ForwardAddressError(str(exc)) from None
    flags = socket.AI_NUMERICHOST if numeric_only else 0
    try:
        info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM, 0, flags)
    except (socket.gaierror, UnicodeError) as exc:
        why = ("a host name: resolve it first (resolve_outs)" if numeric_only
               else f"the host name does not resolve to an IPv4 address ({(exc.strerror if isinstance(exc, OSError) else None) or exc})")
        raise ForwardAddressError(f"forward address {text!r}: {why}") from None
    return info[0][4][0], int(info[0][4][1])


def resolve_outs(outs) -> dict[str, tuple[str, int]]:
    """``{address text: (IPv4, port)}`` for every forward address of ``outs``, each resolved once.

    Blocking (DNS): call it before the event loop starts, or in a worker thread.

    Raises
    ------
    ForwardAddressError
        The first address that is invalid or does not resolve.
    """
    return {str(out): resolve_out(str(out)) for out in outs}


class Forwarder:
    """Copies vehicle frames to UDP clients; relays their commands only when allowed.

    Parameters
    ----------
    outs : iterable of str
        ``udp:HOST:PORT`` addresses (ValueError for any other form).
    addresses : dict, optional
        ``{out: (IPv4, port)}`` from :func:`resolve_outs`; without it every HOST must be a
        numeric IPv4 address (a host name is a :class:`ForwardAddressError`, never looked up here).
    allow_commands : bool
        Relay the clients' messages addressed to the vehicles (default False: read-only).
    vehicle_sysids : iterable of int
        The mission's vehicles (a client's message for any other system id is dropped).
    on_first_drop : callable, optional
        ``on_first_drop(text)`` once, at the first client frame dropped as read-only (tell the operator).
    """

    def __init__(self, outs, allow_commands: bool = False, vehicle_sysids=(), on_first_drop=None,
                 addresses: dict | None = None):
        self.outs = [str(o) for o in outs]
        addresses = addresses or {}
        self.addresses = [addresses[o] if o in addresses else resolve_out(o, numeric_only=True) for o in self.outs]
        self.allow_commands = bool(allow_commands)
        self.vehicle_sysids = frozenset(int(s) for s in vehicle_sysids)
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.on_first_drop = on_first_drop
        self._socks: list[socket.socket] = []
        self._parsers: list = []
        self._endpoints: list = []
        self._loop: asyncio.AbstractEventLoop | None = None
        for _host, _port in self.addresses:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setblocking(False)
            sock.bind(("0.0.0.0", 0))
            self._socks.append(sock)
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            self._parsers.append(parser)

    # ------------------------------------------------------------------ vehicles -> clients
    def copy(self, frame: bytes) -> None:
        """Send one vehicle frame to every client (the endpoints' ``forward`` hook)."""
        c = self.counters
        for sock, address in zip(self._socks, self.addresses):
            try:
                sock.sendto(frame, address)
            except OSError:  # full buffer, unreachable: the vehicle side never waits
                c["send_errors"] += 1
                continue
            c["frames_out"] += 1
            c["bytes_out"] += len(frame)

    def attach(self, endpoint) -> None:
        """Forward what ``endpoint`` (a :class:`~mission.link.endpoint.MavEndpoint`) accepts."""
        if endpoint not in self._endpoints:
            endpoint.forward = self.copy
            self._endpoints.append(endpoint)

    # ------------------------------------------------------------------ clients -> vehicles
    def _on_client(self, i: int) -> None:
        sock = self._socks[i]
        while True:
            try:
                data, _peer = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP port unreachable reported on the socket: the client is gone
                self.counters["send_errors"] += 1
                return
            for msg in self._parsers[i].parse_buffer(data) or ():
                self._from_client(msg)

    def _from_client(self, msg) -> None:
        c = self.counters
        if msg.get_type() in ("BAD_DATA", "UNKNOWN_MSG"):
            c["dropped_bad"] += 1
            return
        c["client_frames"] += 1
        if not self.allow_commands:
            c["dropped_read_only"] += 1
            if c["dropped_read_only"] == 1 and self.on_first_drop is not None:
                self.on_first_drop(f"a forward client sent {msg.get_type()} (sysid {msg.get_srcSystem()}): "
                                   "dropped, the forward is read-only ([forward] allow_commands = false); "
                                   "further drops are counted")
            return
        target = getattr(msg, "target_system", None)
        if target is None or (target and target not in self.vehicle_sysids):
            c["dropped_no_target"] += 1
            return
        targets = sorted(self.vehicle_sysids) if target == 0 else [target]
        for sysid in targets:
            endpoint = next((ep for ep in self._endpoints if sysid in ep.sysids_seen()), None)
            if endpoint is not None and endpoint.send(sysid, msg):
                c["relayed"] += 1
            else:
                c["dropped_no_target"] += 1

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Read the clients on the running loop (an event-loop reader per socket; no timer).

        Attach the endpoints with :meth:`attach` (:func:`forwarding` has the coordinator call it
        for every endpoint it opens).
        """
        self._loop = asyncio.get_running_loop()
        for i, sock in enumerate(self._socks):
            self._loop.add_reader(sock.fileno(), self._on_client, i)

    async def close(self) -> None:
        """Stop forwarding: detach from the endpoints, close the sockets."""
        for endpoint in self._endpoints:
            endpoint.forward = None
        for sock in self._socks:
            if self._loop is not None and not self._loop.is_closed():
                self._loop.remove_reader(sock.fileno())
            sock.close()
        self._socks = []

    def summary(self) -> str:
        """One line for the operator: where, how much, and what was dropped."""
        c = self.counters
        mode = "commands relayed" if self.allow_commands else "read-only"
        return (f"MAVLink forwarded to {', '.join(self.outs)} ({mode}): {c['frames_out']} frames; client "
                f"frames {c['client_frames']}, relayed {c['relayed']}, dropped {c['dropped_read_only']} "
                f"(read-only) + {c['dropped_no_target']} (no vehicle target) + {c['dropped_bad']} (malformed); "
                f"send errors {c['send_errors']}")


def out_address(text: str) -> str:
    """argparse type of ``--out``: ``udp:HOST:PORT`` (ArgumentTypeError otherwise)."""
    import argparse

    try:
        parse_forward_out(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def plan_with_outs(plan, outs):
    """``plan`` with ``outs`` (``--out``) added to its ``[forward] out``."""
    from dataclasses import replace

    if not outs:
        return plan
    return replace(plan, forward=replace(plan.forward, out=tuple(plan.forward.out) + tuple(outs)))


async def forwarding(work, forward, sysids: list[int], event, watch_endpoints, addresses: dict | None = None):
    """Await ``work`` (a mission's run) while the plan's ``[forward]`` runs; the start and the
    counts at the end are events of the mission (its log, the display).

    Parameters
    ----------
    work : coroutine
        The mission (never started when the forward addresses do not resolve).
    forward : mission.core.plan_types.ForwardPlan
        The plan's ``[forward]`` (``out``, ``allow_commands``); no ``out``: ``work`` alone.
    sysids : list of int
        The plan's vehicles (the system ids a client's frames may be relayed to).
    event : callable
        ``event(message, level="info", **fields)``: the mission's events.
    watch_endpoints : callable
        ``watch_endpoints(watcher)``: calls ``watcher(endpoint)`` for every MAVLink endpoint of the
        mission, open now or later (the forwarder attaches to each).
    addresses : dict, optional
        The forward addresses resolved before the loop started (:func:`resolve_outs`); any
        missing are resolved in a worker thread here, before ``work`` starts (so before any
        vehicle is contacted: a :class:`ForwardAddressError` then leaves ``work`` never started).
    """
    if not forward.out:
        return await work
    missing = [o for o in forward.out if o not in (addresses or {})]
    try:
        resolved = {**(addresses or {}), **(await asyncio.to_thread(resolve_outs, missing) if missing else {})}
    except BaseException:
        work.close()  # never started: no "coroutine was never awaited"
        raise
    forwarder = Forwarder(forward.out, forward.allow_commands, list(sysids),
                          on_first_drop=lambda text: event(text, level="warning"), addresses=resolved)
    forwarder.start()
    watch_endpoints(forwarder.attach)  # at once, no polling task: nothing on the mission's clock
    event(f"forwarding MAVLink to {', '.join(forward.out)} "
          f"({'commands relayed' if forward.allow_commands else 'read-only: client frames dropped'})",
          forward_out=list(forward.out), allow_commands=forward.allow_commands)
    try:
        return await work
    finally:
        await forwarder.close()
        event(forwarder.summary(), forward=dict(forwarder.counters))
