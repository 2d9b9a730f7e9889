"""MAVLink transports of a mock vehicle: UDP (PX4-SITL style) and TCP (ArduPilot-SITL style).

One :class:`VehicleLinks` per vehicle owns its sockets (non-blocking, registered on the fleet's
``selectors`` selector), parses incoming bytes with one pymavlink parser per peer (robust
parsing: garbage and bad CRCs come out as counted BAD_DATA, never an exception; a UDP datagram is
a whole unit: a partial frame ending it is counted in ``rx_truncated`` and dropped, never joined
to the next datagram; a datagram of exactly one valid frame of a fixed-layout message, nearly
every setpoint, is decoded by :func:`wire.fast_decode.decode_single_frame` into the same message
instead) and injects the link faults of the vehicle's
:class:`~sitl_mock.faults.FaultSet`:

* ``loss_uplink`` / ``loss_downlink``: each frame dropped with that probability;
* ``latency_uplink_s`` / ``latency_downlink_s``: each frame delayed (simulated seconds);
* ``link_cut``: nothing passes either way; ``crashed``: the vehicle transmits nothing.

UDP: binds ``127.0.0.1:bind_port``, sends its stream to ``127.0.0.1:send_port`` and to every
peer that sent it something. TCP: a listening server; several clients at once.
"""
from __future__ import annotations

import errno
import heapq
import itertools
import selectors
import socket
from collections import OrderedDict

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from wire.fast_decode import decode_single_frame

__all__ = ["VehicleLinks", "PortInUseError", "make_parser", "MAX_UDP_PEERS"]

MAX_UDP_PEERS = 8
_HOST = "127.0.0.1"
_DATAGRAM_MAX = 1400
_TCP_BACKLOG_MAX = 1 << 20


class PortInUseError(OSError):
    """A port the mock must bind is already taken."""


def make_parser(sysid: int = 0) -> mavlink2.MAVLink:
    """A robust pymavlink parser (bad input becomes BAD_DATA messages, never exceptions)."""
    parser = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    parser.robust_parsing = True
    return parser


class _TcpClient:
    def __init__(self, sock: socket.socket, addr):
        self.sock = sock
        self.addr = addr
        self.parser = make_parser()
        self.out = bytearray()


class VehicleLinks:
    """UDP endpoint + TCP server of one vehicle, with fault injection.

    Parameters
    ----------
    autopilot : sitl_mock.autopilot.MockAutopilot
        Receives parsed messages, provides outgoing frames and the FaultSet.
    clock : clock object
        ``time()`` gives the simulated time used for latencies.
    selector : selectors.BaseSelector
        The fleet's selector (the sockets are registered on it).
    rng : numpy.random.Generator
        Draws the packet losses (seeded).
    udp_bind_port, udp_send_port, tcp_port : int
        0 disables UDP (both) or TCP.
    """

    def __init__(self, autopilot, clock, selector: selectors.BaseSelector, rng,
                 udp_bind_port: int = 0, udp_send_port: int = 0, tcp_port: int = 0):
        self.ap = autopilot
        self.clock = clock
        self.selector = selector
        self.rng = rng
        self.udp_bind_port = int(udp_bind_port)
        self.udp_send_port = int(udp_send_port)
        self.tcp_port = int(tcp_port)
        self._udp: socket.socket | None = None
        self._tcp: socket.socket | None = None
        self._clients: dict[int, _TcpClient] = {}
        self._udp_peers: OrderedDict = OrderedDict()
        self._seq = itertools.count()
        self._rx_delayed: list = []
        self._tx_delayed: list = []

    # ------------------------------------------------------------- lifecycle
    def open(self) -> None:
        """Bind the sockets and register them (raises :class:`PortInUseError`)."""
        try:
            if self.udp_bind_port:
                self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._udp.setblocking(False)
                self._bind(self._udp, self.udp_bind_port, "UDP")
                self.selector.register(self._udp, selectors.EVENT_READ, self._on_udp)
            if self.tcp_port:
                self._tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                self._tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._tcp.setblocking(False)
                self._bind(self._tcp, self.tcp_port, "TCP")
                self._tcp.listen(8)
                self.selector.register(self._tcp, selectors.EVENT_READ, self._on_accept)
        except BaseException:
            self.close()
            raise

    def _bind(self, sock: socket.socket, port: int, kind: str) -> None:
        try:
            sock.bind((_HOST, port))
        except OSError as exc:
            if exc.errno in (errno.EADDRINUSE, errno.EACCES):
                raise PortInUseError(
                    exc.errno, f"{kind} port {_HOST}:{port} for vehicle {self.ap.sysid} is "
                    f"already in use ({exc.strerror})") from None
            raise

    def close(self) -> None:
        """Unregister and close every socket (idempotent)."""
        for client in list(self._clients.values()):
            self._drop_client(client)
        for sock in (self._udp, self._tcp):
            if sock is not None:
                try:
                    self.selector.unregister(sock)
                except (KeyError, ValueError):
                    pass
                sock.close()
        self._udp = self._tcp = None

    @property
    def tcp_clients(self) -> int:
        """Number of connected TCP clients."""
        return len(self._clients)

    # ---------------------------------------------------------------- uplink
    def _on_udp(self, mask: int) -> None:
        sock = self._udp
        for _ in range(64):
            try:
                data, addr = sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionRefusedError:  # ICMP from an earlier send to a closed port
                continue
            except OSError:
                self.ap.counters["rx_socket_error"] += 1
                return
            peer = self._udp_peers.get(addr)
            if peer is None:
                peer = make_parser()
                self._udp_peers[addr] = peer
                while len(self._udp_peers) > MAX_UDP_PEERS:
                    self._udp_peers.popitem(last=False)
            else:
                self._udp_peers.move_to_end(addr)
            self._receive(peer, data)

    def _on_accept(self, mask: int) -> None:
        try:
            sock, addr = self._tcp.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self.ap.counters["tcp_accept_error"] += 1
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _TcpClient(sock, addr)
        self._clients[sock.fileno()] = client
        self.selector.register(sock, selectors.EVENT_READ, lambda m, c=client: self._on_tcp(c, m))

    def _on_tcp(self, client: _TcpClient, mask: int) -> None:
        if mask & selectors.EVENT_WRITE:
            self._tcp_flush(client)
        if not mask & selectors.EVENT_READ:
            return
        try:
            data = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop_client(client)
            return
        if not data:
            self._drop_client(client)
            return
        self._receive(client.parser, data, stream=True)

    def _receive(self, parser, data: bytes, stream: bool = False) -> None:
        """Parse ``data`` (one datagram, or with ``stream`` a chunk of a TCP stream) and hand
        its messages to the autopilot, through the link faults."""
        ap = self.ap
        faults = ap.faults
        # one whole valid frame (nearly every datagram): the message pymavlink's parser would return
        msg = None if stream else decode_single_frame(data)
        if msg is not None:
            msgs = (msg,)
        else:
            try:
                msgs = parser.parse_buffer(data) or []
            except Exception as exc:  # pymavlink should not raise with robust parsing; never crash
                ap.counters["rx_parser_error"] += 1
                ap.counters["rx_parser_error:" + type(exc).__name__] += 1
                _reset_parser(parser)
                return
            if not stream and parser.buf_len():
                ap.counters["rx_truncated"] += 1  # a datagram holds whole frames: drop its partial tail
                _reset_parser(parser)
        t_s = self.clock.time()
        for msg in msgs:
            if faults.link_cut or faults.crashed:
                ap.counters["rx_dropped_link"] += 1
                continue
            if faults.loss_uplink > 0.0 and self.rng.random() < faults.loss_uplink:
                ap.counters["rx_dropped_loss"] += 1
                continue
            if faults.latency_uplink_s > 0.0:
                heapq.heappush(self._rx_delayed,
                               (t_s + faults.latency_uplink_s, next(self._seq), msg))
                continue
            ap.handle_message(msg, t_s)

    # -------------------------------------------------------------- downlink
    def pump(self, t_s: float) -> None:
        """Deliver delayed uplink messages and send the vehicle's outgoing frames."""
        ap = self.ap
        while self._rx_delayed and self._rx_delayed[0][0] <= t_s:
            _due, _n, msg = heapq.heappop(self._rx_delayed)
            ap.handle_message(msg, t_s)
        frames = ap.drain_outbox()
        faults = ap.faults
        ready: list[bytes] = []
        if frames:
            if faults.link_cut or faults.crashed:
                ap.counters["tx_dropped_link"] += len(frames)
                frames = []
            for frame in frames:
                if faults.loss_downlink > 0.0 and self.rng.random() < faults.loss_downlink:
                    ap.counters["tx_dropped_loss"] += 1
                elif faults.latency_downlink_s > 0.0:
                    heapq.heappush(self._tx_delayed,
                                   (t_s + faults.latency_downlink_s, next(self._seq), frame))
                else:
                    ready.append(frame)
        if self._tx_delayed:
            due = []
            while self._tx_delayed and self._tx_delayed[0][0] <= t_s:
                due.append(heapq.heappop(self._tx_delayed)[2])
            ready = due + ready
        if ready:
            self._send(ready)

    def _send(self, frames: list[bytes]) -> None:
        if self._udp is not None:
            for datagram in _batches(frames):
                self._udp_send(datagram)
        if self._clients:
            blob = b"".join(frames)
            for client in list(self._clients.values()):
                if len(client.out) > _TCP_BACKLOG_MAX:
                    self.ap.counters["tcp_client_too_slow"] += 1
                    self._drop_client(client)
                    continue
                client.out += blob
                self._tcp_flush(client)

    def _udp_send(self, datagram: bytes) -> None:
        targets = list(self._udp_peers)
        default = (_HOST, self.udp_send_port)
        if self.udp_send_port and default not in self._udp_peers:
            targets.append(default)
        for addr in targets:
            try:
                self._udp.sendto(datagram, addr)
            except (BlockingIOError, InterruptedError):
                self.ap.counters["tx_dropped_busy"] += 1
            except OSError:  # ConnectionRefused (nobody listening) and the like
                self.ap.counters["tx_unreachable"] += 1

    def _tcp_flush(self, client: _TcpClient) -> None:
        try:
            sent = client.sock.send(client.out)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self._drop_client(client)
            return
        del client.out[:sent]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.out else 0)
        try:
            key = self.selector.get_key(client.sock)
            if key.events != events:
                self.selector.modify(client.sock, events, key.data)
        except (KeyError, ValueError):
            pass

    def _drop_client(self, client: _TcpClient) -> None:
        self._clients.pop(client.sock.fileno(), None)
        try:
            self.selector.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()


def _reset_parser(parser) -> None:
    """Forget the bytes a pymavlink parser holds (as a fresh parser: no partial frame)."""
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink2.HEADER_LEN_V1 + 2


def _batches(frames: list[bytes]):
    """Pack frames into datagrams of at most ~1400 bytes (whole frames only)."""
    batch: list[bytes] = []
    size = 0
    for frame in frames:
        if batch and size + len(frame) > _DATAGRAM_MAX:
            yield b"".join(batch)
            batch, size = [], 0
        batch.append(frame)
        size += len(frame)
    if batch:
        yield b"".join(batch)
