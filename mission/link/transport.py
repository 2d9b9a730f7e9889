"""Transports under :class:`mission.link.endpoint.MavEndpoint`: UDP (in/out), TCP (client/server), serial.

Every transport is non-blocking and driven by the running asyncio loop. It hands received bytes
to the endpoint (``receive_datagram(data, peer)`` for UDP, ``receive_stream_data(data, peer)`` for
streams) and sends frames to a peer. A *peer* is an opaque, hashable address: the UDP
``(host, port)`` of the sender, the TCP connection's remote address, or the serial device.

Common interface: ``send(peer, frame) -> bool``, ``peers()``, ``default_peer()``,
``local_address()``, ``async close()``.
"""
from __future__ import annotations

import asyncio
import os
import socket
import termios
import tty

from mission.core.tasks import spawn

__all__ = ["open_transport"]

#: a stream peer that stops reading gets no more frames once this much is queued for it
_MAX_STREAM_BACKLOG_BYTES = 1 << 20
_TCP_RECONNECT_S = 1.0


class _UdpTransport(asyncio.DatagramProtocol):
    """``udpin`` (bind, learn peers) or ``udpout`` (send to one remote address)."""

    def __init__(self, spec, endpoint) -> None:
        self._spec = spec
        self._endpoint = endpoint
        self._transport = None
        self._heard: set = set()
        self._remote = (spec.host, spec.port) if spec.kind == "udpout" else None

    async def start(self) -> "_UdpTransport":
        loop = asyncio.get_running_loop()
        if self._remote is None:
            await loop.create_datagram_endpoint(lambda: self, local_addr=(self._spec.host, self._spec.port))
        else:
            await loop.create_datagram_endpoint(lambda: self, remote_addr=self._remote)
        return self

    # asyncio protocol callbacks
    def connection_made(self, transport) -> None:
        self._transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        if self._remote is not None:
            addr = self._remote
        elif addr not in self._heard:
            self._heard.add(addr)
        self._endpoint.receive_datagram(data, addr)

    def error_received(self, exc) -> None:
        self._endpoint.counters["send_errors"] += 1

    # transport interface
    def send(self, peer, frame: bytes) -> bool:
        transport = self._transport
        if transport is None or transport.is_closing():
            return False
        if self._remote is not None:
            transport.sendto(frame)
        else:
            transport.sendto(frame, peer)
        return True

    def peers(self):
        return [self._remote] if self._remote is not None else list(self._heard)

    def default_peer(self):
        return self._remote

    def local_address(self):
        return self._transport.get_extra_info("sockname")[:2]

    async def close(self) -> None:
        if self._transport is not None:
            self._transport.close()


class _PolledUdpTransport:
    """``udpin``/``udpout`` on a raw non-blocking socket drained by a shared ``UdpPoller``."""

    def __init__(self, spec, endpoint, poller) -> None:
        self._spec = spec
        self._endpoint = endpoint
        self._poller = poller
        self._heard: set = set()
        self._remote = (spec.host, spec.port) if spec.kind == "udpout" else None
        self._sock = None

    async def start(self) -> "_PolledUdpTransport":
        loop = asyncio.get_running_loop()
        family = socket.AF_INET
        if self._remote is not None:
            infos = await loop.getaddrinfo(*self._remote, type=socket.SOCK_DGRAM, family=family)
            self._remote = infos[0][4][:2]
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            if self._remote is None:
                sock.bind((self._spec.host, self._spec.port))
            else:
                sock.bind(("0.0.0.0", 0))
        except OSError:
            sock.close()
            raise
        self._sock = sock
        self._poller.register(sock, self._datagram)
        return self

    def _datagram(self, data: bytes, addr) -> None:
        if self._remote is not None:
            addr = self._remote
        elif addr not in self._heard:
            self._heard.add(addr)
        self._endpoint.receive_datagram(data, addr)

    def send(self, peer, frame: bytes) -> bool:
        if self._sock is None:
            return False
        try:
            self._sock.sendto(frame, self._remote if self._remote is not None else peer)
        except OSError:   # full buffer (BlockingIOError) or an ICMP error: counted by the caller
            return False
        return True

    def peers(self):
        return [self._remote] if self._remote is not None else list(self._heard)

    def default_peer(self):
        return self._remote

    def local_address(self):
        return self._sock.getsockname()[:2]

    async def close(self) -> None:
        if self._sock is not None:
            self._poller.unregister(self._sock)
            self._sock.close()
            self._sock = None


class _StreamProtocol(asyncio.Protocol):
    """One TCP connection; reports itself connected and lost, and its bytes, to the given callbacks.

    Parameters
    ----------
    connected, lost : callable
        Called with this protocol when the connection is made and when it is lost.
    received : callable
        ``received(data, peer)`` for every chunk of bytes (the endpoint's ``receive_stream_data``).
    """

    def __init__(self, connected, received, lost) -> None:
        self._connected = connected
        self._received = received
        self._lost = lost
        self.transport = None
        self.peer = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        self.peer = transport.get_extra_info("peername")[:2]
        self._connected(self)

    def data_received(self, data: bytes) -> None:
        self._received(data, self.peer)

    def connection_lost(self, exc) -> None:
        self._lost(self)


def _stream_send(proto, endpoint, frame: bytes) -> bool:
    transport = proto.transport
    if transport is None or transport.is_closing():
        return False
    if transport.get_write_buffer_size() > _MAX_STREAM_BACKLOG_BYTES:
        endpoint.counters["send_errors"] += 1
        return False
    transport.write(frame)
    return True


class _TcpClientTransport:
    """``tcp:HOST:PORT``: one connection, re-established every second if it drops."""

    def __init__(self, spec, endpoint) -> None:
        self._spec = spec
        self._endpoint = endpoint
        self._proto: _StreamProtocol | None = None
        self._peer = (spec.host, spec.port)
        self._lost_event = asyncio.Event()
        self._reconnect_task = None
        self._closing = False
        self.connects = 0

    async def start(self) -> "_TcpClientTransport":
        await self._connect()
        self._reconnect_task = spawn(self._reconnect_loop(), f"reconnecting {self._spec.uri}")
        return self

    async def _connect(self) -> None:
        loop = asyncio.get_running_loop()
        await loop.create_connection(self._new_protocol, self._spec.host, self._spec.port)

    def _new_protocol(self) -> _StreamProtocol:
        return _StreamProtocol(self._connected, self._endpoint.receive_stream_data, self._lost)

    def _connected(self, proto) -> None:
        proto.peer = self._peer
        self._proto = proto
        self.connects += 1
        self._lost_event.clear()

    def _lost(self, proto) -> None:
        if self._proto is proto:
            self._proto = None
            self._endpoint.peer_lost(self._peer)
            self._lost_event.set()

    async def _reconnect_loop(self) -> None:
        while not self._closing:
            await self._lost_event.wait()
            while not self._closing and self._proto is None:
                await asyncio.sleep(_TCP_RECONNECT_S)
                try:
                    await self._connect()
                except OSError:
                    continue

    def send(self, peer, frame: bytes) -> bool:
        return self._proto is not None and _stream_send(self._proto, self._endpoint, frame)

    def peers(self):
        return [self._peer] if self._proto is not None else []

    def default_peer(self):
        return self._peer

    def local_address(self):
        if self._proto is None or self._proto.transport is None:
            return None
        return self._proto.transport.get_extra_info("sockname")[:2]

    async def close(self) -> None:
        self._closing = True
        if self._reconnect_task is not None:
            self._reconnect_task.cancel()
        if self._proto is not None and self._proto.transport is not None:
            self._proto.transport.close()


class _TcpServerTransport:
    """``tcpin:HOST:PORT``: accept connections; each one is a peer."""

    def __init__(self, spec, endpoint) -> None:
        self._spec = spec
        self._endpoint = endpoint
        self._server = None
        self._conns: dict = {}

    async def start(self) -> "_TcpServerTransport":
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(self._new_protocol, self._spec.host, self._spec.port)
        return self

    def _new_protocol(self) -> _StreamProtocol:
        return _StreamProtocol(self._connected, self._endpoint.receive_stream_data, self._lost)

    def _connected(self, proto) -> None:
        self._conns[proto.peer] = proto

    def _lost(self, proto) -> None:
        if self._conns.get(proto.peer) is proto:
            del self._conns[proto.peer]
            self._endpoint.peer_lost(proto.peer)

    def send(self, peer, frame: bytes) -> bool:
        proto = self._conns.get(peer)
        return proto is not None and _stream_send(proto, self._endpoint, frame)

    def peers(self):
        return list(self._conns)

    def default_peer(self):
        return next(iter(self._conns)) if len(self._conns) == 1 else None

    def local_address(self):
        return self._server.sockets[0].getsockname()[:2]

    async def close(self) -> None:
        for proto in list(self._conns.values()):
            proto.transport.close()
        self._server.close()


_BAUDS = {b: getattr(termios, f"B{b}") for b in (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000,
    1500000, 2000000) if hasattr(termios, f"B{b}")}


class _SerialTransport:
    """A serial line (or pty) opened non-blocking, raw, at the given baud; watched by the loop."""

    def __init__(self, spec, endpoint) -> None:
        self._spec = spec
        self._endpoint = endpoint
        self._fd = None
        self._pending = bytearray()
        self._loop = None

    async def start(self) -> "_SerialTransport":
        if self._spec.baud not in _BAUDS:
            raise OSError(0, f"unsupported baud rate {self._spec.baud}; supported: "
                          f"{', '.join(map(str, sorted(_BAUDS)))}")
        self._loop = asyncio.get_running_loop()
        fd = os.open(self._spec.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            attrs[4] = attrs[5] = _BAUDS[self._spec.baud]
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
        except termios.error:
            pass  # a pty or a pipe: no line settings to make
        self._fd = fd
        self._loop.add_reader(fd, self._readable)
        return self

    def _readable(self) -> None:
        try:
            data = os.read(self._fd, 65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if data:
            self._endpoint.receive_stream_data(data, self._spec.device)

    def _writable(self) -> None:
        try:
            n = os.write(self._fd, self._pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._pending.clear()
            n = 0
        del self._pending[:n]
        if not self._pending:
            self._loop.remove_writer(self._fd)

    def send(self, peer, frame: bytes) -> bool:
        if self._fd is None:
            return False
        if self._pending:
            if len(self._pending) > _MAX_STREAM_BACKLOG_BYTES:
                return False
            self._pending += frame
            return True
        try:
            n = os.write(self._fd, frame)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError:
            return False
        if n < len(frame):
            self._pending += frame[n:]
            self._loop.add_writer(self._fd, self._writable)
        return True

    def peers(self):
        return [self._spec.device]

    def default_peer(self):
        return self._spec.device

    def local_address(self):
        return None

    async def close(self) -> None:
        if self._fd is not None:
            self._loop.remove_reader(self._fd)
            if self._pending:
                self._loop.remove_writer(self._fd)
            os.close(self._fd)
            self._fd = None


async def open_transport(spec, endpoint, poller=None):
    """Open the transport of ``spec`` for ``endpoint``; raises OSError when it cannot.

    UDP kinds use ``poller`` (a :class:`mission.link.poller.UdpPoller`) when given.
    """
    if spec.kind in ("udpin", "udpout"):
        if poller is not None:
            return await _PolledUdpTransport(spec, endpoint, poller).start()
        return await _UdpTransport(spec, endpoint).start()
    if spec.kind == "tcp":
        return await _TcpClientTransport(spec, endpoint).start()
    if spec.kind == "tcpin":
        return await _TcpServerTransport(spec, endpoint).start()
    return await _SerialTransport(spec, endpoint).start()
