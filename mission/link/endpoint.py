"""MAVLink endpoints: connection strings, sockets and serial lines carrying one or more vehicles.

A :class:`MavEndpoint` owns one transport (a UDP socket, a TCP connection or server, or a serial
line), parses every frame it receives (robustly: bad frames are counted, never raised), hands
each message to the vehicle registered for its system id, remembers where each system id was
last heard from so that frames for a vehicle go only to that vehicle's address, logs every frame
sent and received in that vehicle's ``.tlog`` and sends the ground station's HEARTBEAT at 1 Hz to
every peer. Nothing blocks the event loop: UDP and TCP use asyncio transports, serial a
non-blocking file descriptor watched by the loop.

Connection strings are those of pymavlink and MAVProxy: ``udpin:HOST:PORT``, ``udpout:HOST:PORT``,
``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, ``serial:/dev/ttyX[:BAUD]`` and ``/dev/ttyX[,BAUD]``
(``udp:`` is read as ``udpin:`` like MAVProxy does).

A system id claimed by two vehicles is an error (:class:`LinkError`) that names both endpoints:
two addresses sending autopilot heartbeats with the same id on one endpoint, two different
AUTOPILOT_VERSION uids for one id, or one id heard on two endpoints sharing a
:class:`SysidRegistry`.
"""
from __future__ import annotations

import asyncio
import struct
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator import mavcrc

from mission.core.clock import cancel_and_wait, wait_on_clock
from mission.link.transport import open_transport
from mission.core.uri import DEFAULT_SERIAL_BAUD, ConnectionSpec, parse_connection
from mission.link.signing import (SignatureVerifier, SigningConfig, apply_signing, refresh_timestamp,
                             setup_signing_message, sign_frame)
from mission.link.tlog import TlogSet

__all__ = [
    "LinkError",
    "ConnectionSpec",
    "parse_connection",
    "SysidRegistry",
    "MavEndpoint",
    "DEFAULT_SERIAL_BAUD",
]

_V2_HEADER = struct.Struct("<BBBBBBBHB")
#: an address heard from within this many clock seconds is still "active" (duplicate detection)
_ACTIVE_WINDOW_S = 3.0


def _crc16(frame: bytes, crc_extra: int) -> int:
    """MAVLink CRC of a frame without its magic byte, then ``crc_extra`` (fastcrc when available)."""
    fast = mavcrc.mcrf4xx
    if fast is not None:
        return fast(bytes((crc_extra,)), fast(memoryview(frame)[1:], 0xFFFF))
    crc = mavcrc.x25crc(frame[1:])
    crc.accumulate(bytes((crc_extra,)))
    return crc.crc


class LinkError(ConnectionError):
    """A MAVLink link problem; the message names the endpoint (and the other one, if any)."""


class SysidRegistry:
    """Which endpoint each vehicle system id was heard on; share one between endpoints.

    :meth:`claim` raises :class:`LinkError` naming both endpoints when a system id shows up on a
    second endpoint.
    """

    def __init__(self) -> None:
        self._owner: dict[int, "MavEndpoint"] = {}

    def claim(self, sysid: int, endpoint: "MavEndpoint") -> None:
        """Record that ``sysid`` is on ``endpoint``; raise if it is already on another one."""
        owner = self._owner.setdefault(sysid, endpoint)
        if owner is not endpoint:
            raise LinkError(
                f"duplicate MAVLink system id {sysid}: heard on {owner.uri!r} and on {endpoint.uri!r}")

    def release(self, endpoint: "MavEndpoint") -> None:
        """Forget every system id of ``endpoint`` (when it closes)."""
        for sysid in [s for s, e in self._owner.items() if e is endpoint]:
            del self._owner[sysid]


_MSG_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_MSG_BAD = mavlink.MAVLINK_MSG_ID_BAD_DATA
_MSG_UNKNOWN = mavlink.MAVLINK_MSG_ID_UNKNOWN
_AUTOPILOT_INVALID = mavlink.MAV_AUTOPILOT_INVALID
_TYPE_GCS = mavlink.MAV_TYPE_GCS


def _raw_sender(frame) -> int:
    """Sender system id read from a raw MAVLink frame (v2: byte 5, v1: byte 3)."""
    index = 5 if frame[0] == mavlink.PROTOCOL_MARKER_V2 else 3
    return frame[index] if len(frame) > index else 0


def _is_autopilot_heartbeat(msg) -> bool:
    return msg.autopilot != _AUTOPILOT_INVALID and msg.type != _TYPE_GCS


class MavEndpoint:
    """One MAVLink transport, possibly carrying several vehicles (system ids).

    Create with :meth:`open`. Vehicles attach with :meth:`attach` (``VehicleLink`` does it).

    Attributes
    ----------
    uri : str
        The connection string.
    spec : ConnectionSpec
    counters : dict of str to int
        ``frames_in``, ``frames_out``, ``bytes_in``, ``bytes_out``, ``bad_crc``, ``malformed``
        (bad prefix, length, payload), ``unknown_msgid`` (logged in its sender's tlog, sysid
        read from the raw frame), ``truncated`` (partial frame at the end
        of a datagram), ``unroutable`` (frame for a system id never heard), ``send_errors``,
        ``duplicate_sysid``, ``handler_errors`` (a vehicle handler raised; the message is in
        :attr:`last_handler_error`, the link goes on).
    errors : list of LinkError
        Duplicate-sysid problems found so far (also delivered to the attached vehicles).
    tlogs : TlogSet or None
    """

    def __init__(self, spec: ConnectionSpec, *, clock, tlog_dir=None, gcs_sysid: int = 255,
                 gcs_compid: int = 190, heartbeat_hz: float = 1.0,
                 registry: SysidRegistry | None = None, poller=None,
                 signing: SigningConfig | None = None) -> None:
        self.spec = spec
        self.poller = poller
        self.uri = spec.uri
        self.clock = clock
        self.gcs_sysid = int(gcs_sysid)
        self.gcs_compid = int(gcs_compid)
        self.heartbeat_hz = float(heartbeat_hz)
        self.registry = registry if registry is not None else SysidRegistry()
        self.tlogs = TlogSet(tlog_dir, time_fn=clock.time) if tlog_dir is not None else None
        self.counters = dict.fromkeys(
            ("frames_in", "frames_out", "bytes_in", "bytes_out", "bad_crc", "malformed",
             "unknown_msgid", "truncated", "unroutable", "send_errors", "duplicate_sysid",
             "handler_errors"), 0)
        self.last_handler_error: str | None = None
        self.counters.update(unsigned=0, bad_signature=0, replayed=0, setup_signing_sent=0,
                             setup_signing_refused=0)
        self.signing = signing
        self.signing_state = signing.new_state(clock.time()) if signing is not None else None
        self.verifier = SignatureVerifier(signing, self.signing_state) if signing is not None else None
        self._setup_sent_s: dict[int, float] = {}
        #: system ids this mission waits for or attached: the only ones ever sent the key
        self._expected: set[int] = set()
        self.errors: list[LinkError] = []
        self._transport = None
        self._datagram_parser = self._new_parser()
        self._stream_parsers: dict[object, mavlink.MAVLink] = {}
        self._encoders: dict[object, mavlink.MAVLink] = {}
        self._peer_of: dict[int, object] = {}
        self._hb_seen: dict[int, dict[object, float]] = {}
        self._uids: dict[int, int] = {}
        self._last_heartbeat: dict[int, object] = {}
        self._handlers: dict[int, tuple[Callable, Callable]] = {}
        self._hb_waiters: list[tuple[int | None, asyncio.Future]] = []
        self._housekeeping: asyncio.Task | None = None
        self.closed = False

    # ------------------------------------------------------------------ opening and closing
    @classmethod
    async def open(cls, uri: str, *, clock, tlog_dir=None, gcs_sysid: int = 255,
                   gcs_compid: int = 190, heartbeat_hz: float = 1.0,
                   registry: SysidRegistry | None = None, poller=None,
                   signing: SigningConfig | None = None) -> "MavEndpoint":
        """Open the transport named by ``uri`` and start the 1 Hz GCS heartbeat.

        Parameters
        ----------
        uri : str
            Connection string (see :func:`parse_connection`).
        clock : object
            The mission clock (``time()``, ``async sleep``).
        tlog_dir : str or path-like, optional
            Directory for the per-vehicle ``.tlog`` files; None logs nothing.
        gcs_sysid, gcs_compid : int
            Our MAVLink identity.
        heartbeat_hz : float
            GCS HEARTBEAT rate (0 disables it).
        registry : SysidRegistry, optional
            Shared between the endpoints of one mission to catch a system id on two endpoints.
        poller : mission.link.poller.UdpPoller, optional
            Shared between the UDP endpoints of one mission: their sockets are drained every
            few milliseconds by one task instead of waking the loop per datagram (much cheaper
            with many vehicles). Ignored by TCP and serial endpoints.
        signing : mission.link.signing.SigningConfig, optional
            MAVLink 2 signing: every frame sent is signed (one timestamp per endpoint), every
            frame received is checked (:class:`mission.link.signing.SignatureVerifier`; rejections
            counted as ``unsigned``, ``bad_signature``, ``replayed``, never delivered nor
            logged); an autopilot heard unsigned that never signed gets SETUP_SIGNING (at most
            once a second, counted ``setup_signing_sent``) if ``signing.send_setup`` and it is a
            system id the mission waits for (:meth:`wait_heartbeat`) or attached; any other
            system id is never sent the key (counted ``setup_signing_refused``).

        Raises
        ------
        ValueError
            Bad connection string.
        LinkError
            The transport cannot be opened (the message names the endpoint and the reason).
        """
        spec = parse_connection(uri)
        self = cls(spec, clock=clock, tlog_dir=tlog_dir, gcs_sysid=gcs_sysid, gcs_compid=gcs_compid,
                   heartbeat_hz=heartbeat_hz, registry=registry, poller=poller, signing=signing)
        try:
            self._transport = await open_transport(spec, self, poller)
        except OSError as exc:
            if self.tlogs is not None:
                self.tlogs.close()
            raise LinkError(f"cannot open {spec.uri!r}: {exc.strerror or exc}") from exc
        if self.heartbeat_hz > 0:
            self._housekeeping = asyncio.ensure_future(self._housekeeping_loop())
        return self

    @property
    def local_address(self):
        """The bound local ``(host, port)`` for network transports (useful with port 0)."""
        return self._transport.local_address()

    async def close(self) -> None:
        """Stop the heartbeat, close the transport, flush and close the tlogs. Idempotent."""
        if self.closed:
            return
        self.closed = True
        await cancel_and_wait(self._housekeeping)
        if self._transport is not None:
            await self._transport.close()
        for _, fut in self._hb_waiters:
            if not fut.done():
                fut.set_exception(LinkError(f"{self.uri!r} closed"))
        self._hb_waiters.clear()
        self.registry.release(self)
        if self.tlogs is not None:
            self.tlogs.close()

    async def __aenter__(self) -> "MavEndpoint":
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()

    def __repr__(self) -> str:
        return f"MavEndpoint({self.uri!r}, sysids={sorted(self._peer_of)})"

    # ------------------------------------------------------------------ vehicles
    def sysids_seen(self) -> set[int]:
        """System ids heard on this endpoint so far (any component)."""
        return set(self._peer_of)

    def last_heartbeat(self, sysid: int):
        """The last autopilot HEARTBEAT of ``sysid``, or None."""
        return self._last_heartbeat.get(sysid)

    def attach(self, sysid: int, on_message: Callable, on_error: Callable | None = None) -> None:
        """Deliver every message of ``sysid`` to ``on_message(msg)`` and problems to ``on_error(exc)``.

        Raises
        ------
        LinkError
            If another handler is attached to ``sysid`` or a problem is already known for it.
        """
        if sysid in self._handlers:
            raise LinkError(f"system id {sysid} on {self.uri!r} is already attached to a vehicle")
        self.check_sysid(sysid)
        self._expected.add(sysid)
        self._handlers[sysid] = (on_message, on_error or (lambda exc: None))

    def detach(self, sysid: int) -> None:
        """Stop delivering ``sysid``'s messages."""
        self._handlers.pop(sysid, None)

    def check_sysid(self, sysid: int) -> None:
        """Raise the first known :class:`LinkError` about ``sysid``, if any."""
        for err in self.errors:
            if getattr(err, "sysid", None) == sysid:
                raise err

    async def wait_heartbeat(self, sysid: int | None, timeout_s: float):
        """Wait for an autopilot HEARTBEAT from ``sysid`` (None: any id not attached yet).

        Returns
        -------
        tuple
            ``(sysid, heartbeat_message)``.

        Raises
        ------
        LinkError
            On timeout (clock seconds), naming the endpoint and the system id.
        """
        if sysid is not None:
            self._expected.add(sysid)  # may be sent SETUP_SIGNING from now on
        for sid, hb in self._last_heartbeat.items():
            if (sysid is None and sid not in self._handlers) or sid == sysid:
                return sid, hb
        fut = asyncio.get_running_loop().create_future()
        entry = (sysid, fut)
        self._hb_waiters.append(entry)
        try:
            return await wait_on_clock(fut, timeout_s, self.clock)
        except TimeoutError:
            who = "any vehicle" if sysid is None else f"system id {sysid}"
            why = self.verifier.diagnose(sysid) if self.verifier is not None and sysid is not None else ""
            raise LinkError(f"no autopilot HEARTBEAT from {who} on {self.uri!r} within {timeout_s:g} s"
                            + (f" ({why})" if why else "")) from None
        finally:
            if entry in self._hb_waiters:
                self._hb_waiters.remove(entry)

    def note_uid(self, sysid: int, uid: int) -> None:
        """Record an AUTOPILOT_VERSION uid of ``sysid``; a different nonzero uid is a duplicate."""
        if not uid:
            return
        old = self._uids.setdefault(sysid, uid)
        if old != uid:
            self._report_duplicate(sysid, f"AUTOPILOT_VERSION uids {old:#x} and {uid:#x}")

    # ------------------------------------------------------------------ receiving
    @staticmethod
    def _new_parser() -> mavlink.MAVLink:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser

    def _on_datagram(self, data: bytes, peer) -> None:
        """Transport callback: one UDP datagram (whole frames; a partial tail is counted)."""
        parser = self._datagram_parser
        msgs = parser.parse_buffer(data)
        if parser.buf_len():
            self.counters["truncated"] += 1
            parser.buf = bytearray()
            parser.buf_index = 0
            parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        if msgs:
            self._deliver(msgs, peer, len(data))

    def _on_stream_data(self, data: bytes, peer) -> None:
        """Transport callback: bytes from a stream (TCP connection, serial line)."""
        parser = self._stream_parsers.get(peer)
        if parser is None:
            parser = self._stream_parsers[peer] = self._new_parser()
        msgs = parser.parse_buffer(data)
        if msgs:
            self._deliver(msgs, peer, len(data))

    def _on_peer_lost(self, peer) -> None:
        """Transport callback: a stream peer went away."""
        self._stream_parsers.pop(peer, None)
        self._encoders.pop(peer, None)

    def _deliver(self, msgs, peer, nbytes: int) -> None:
        counters = self.counters
        counters["bytes_in"] += nbytes
        tlogs = self.tlogs
        peer_of = self._peer_of
        handlers = self._handlers
        for msg in msgs:
            # not msg.id: BAD_DATA / UNKNOWN inherit id 0 (HEARTBEAT) and messages with a
            # field named "id" (BATTERY_STATUS...) shadow the class attribute
            msg_id = msg._header.msgId
            if msg_id == _MSG_BAD:
                counters["bad_crc" if "CRC" in msg.reason else "malformed"] += 1
                continue
            if self.verifier is not None:
                reason = self.verifier.check(msg)
                if reason is not None:
                    counters[reason] += 1
                    sysid = msg._header.srcSystem
                    if (reason == "unsigned" and msg_id == _MSG_HEARTBEAT and self.signing.send_setup
                            and _is_autopilot_heartbeat(msg) and self.verifier.needs_setup(sysid)):
                        if sysid in self._expected:
                            self._send_setup_signing(sysid, msg._header.srcComponent, peer)
                        else:  # not a vehicle of this mission: never hand it the key
                            counters["setup_signing_refused"] += 1
                    continue
            counters["frames_in"] += 1
            # MAVLink_unknown has no real header (srcSystem 0): its sender is in the raw frame
            sysid = msg._header.srcSystem if msg_id != _MSG_UNKNOWN else _raw_sender(msg.get_msgbuf())
            if tlogs is not None:
                tlogs.write(sysid, msg._msgbuf)
            if msg_id == _MSG_UNKNOWN:
                counters["unknown_msgid"] += 1
                continue
            if msg_id == _MSG_HEARTBEAT and _is_autopilot_heartbeat(msg):
                self._on_autopilot_heartbeat(sysid, msg, peer)
            elif sysid not in peer_of:
                peer_of[sysid] = peer
            handler = handlers.get(sysid)
            if handler is not None:
                try:
                    handler[0](msg)
                except Exception as exc:  # a vehicle's bug must not stop the link (or the poller)
                    counters["handler_errors"] += 1
                    self.last_handler_error = f"{msg.get_type()} from {sysid}: {type(exc).__name__}: {exc}"

    def _on_autopilot_heartbeat(self, sysid: int, msg, peer) -> None:
        now = self.clock.time()
        seen = self._hb_seen.setdefault(sysid, {})
        seen[peer] = now
        if len(seen) > 1:
            active = [p for p, t in seen.items() if now - t <= _ACTIVE_WINDOW_S]
            for p in [p for p in seen if p not in active]:
                del seen[p]
            if len(active) > 1:
                self._report_duplicate(sysid, f"autopilot heartbeats from {active[0]} and {active[1]}")
        new = sysid not in self._last_heartbeat
        self._peer_of[sysid] = peer
        self._last_heartbeat[sysid] = msg
        if new:
            try:
                self.registry.claim(sysid, self)
            except LinkError as exc:
                self._record_error(sysid, exc)
        for entry in list(self._hb_waiters):
            want, fut = entry
            if not fut.done() and (want == sysid or (want is None and sysid not in self._handlers)):
                fut.set_result((sysid, msg))

    def _report_duplicate(self, sysid: int, detail: str) -> None:
        if any(getattr(e, "sysid", None) == sysid for e in self.errors):
            return
        self._record_error(sysid, LinkError(f"duplicate MAVLink system id {sysid} on {self.uri!r}: {detail}"))

    def _record_error(self, sysid: int, exc: LinkError) -> None:
        exc.sysid = sysid
        self.counters["duplicate_sysid"] += 1
        self.errors.append(exc)
        handler = self._handlers.get(sysid)
        if handler is not None:
            handler[1](exc)

    # ------------------------------------------------------------------ sending
    def _encoder(self, peer) -> mavlink.MAVLink:
        enc = self._encoders.get(peer)
        if enc is None:
            enc = self._encoders[peer] = mavlink.MAVLink(None, srcSystem=self.gcs_sysid,
                                                         srcComponent=self.gcs_compid)
            if self.signing_state is not None:
                apply_signing(enc, self.signing_state)
        return enc

    def _send_setup_signing(self, sysid: int, compid: int, peer) -> None:
        """Give our key to a vehicle heard unsigned (at most once per clock second)."""
        now = self.clock.time()
        if now - self._setup_sent_s.get(sysid, -1e18) < 1.0:
            return
        self._setup_sent_s[sysid] = now
        enc = self._encoder(peer)
        msg = setup_signing_message(sysid, self.signing.key, self.signing_state.timestamp, compid)
        frame = msg.pack(enc)
        enc.seq = (enc.seq + 1) & 0xFF
        if self._transport.send(peer, frame):  # not _send_frame: the key must not go to the tlog
            self.counters["setup_signing_sent"] += 1

    def send(self, sysid: int, msg) -> bool:
        """Encode ``msg`` and send it to the address ``sysid`` was last heard from.

        Non-blocking. Returns False (and counts ``unroutable``) when ``sysid`` was never heard
        and the transport has no default destination.
        """
        peer = self._peer_of.get(sysid)
        if peer is None:
            peer = self._transport.default_peer()
            if peer is None:
                self.counters["unroutable"] += 1
                return False
        enc = self._encoder(peer)
        frame = msg.pack(enc)
        enc.seq = (enc.seq + 1) & 0xFF
        return self._send_frame(peer, frame, (sysid,))

    def send_payload(self, sysid: int, msg_id: int, crc_extra: int, payload: bytes) -> bool:
        """Send an already packed MAVLink 2 payload to ``sysid`` (the fast path for setpoints).

        The endpoint adds the header (our system and component ids, the peer's sequence number),
        truncates trailing zero bytes as MAVLink 2 requires and appends the CRC; the frame is
        byte-identical to pymavlink's ``msg.pack``. ``payload`` is the message's fields in wire
        order, e.g. ``MAVLink_set_position_target_local_ned_message.unpacker.pack(...)``.
        Same routing, counting and logging as :meth:`send`.
        """
        peer = self._peer_of.get(sysid)
        if peer is None:
            peer = self._transport.default_peer()
            if peer is None:
                self.counters["unroutable"] += 1
                return False
        enc = self._encoder(peer)
        seq = enc.seq
        enc.seq = (seq + 1) & 0xFF
        body = payload.rstrip(b"\x00") or b"\x00"
        frame = _V2_HEADER.pack(0xFD, len(body), 0, 0, seq, self.gcs_sysid, self.gcs_compid,
                                msg_id & 0xFFFF, msg_id >> 16) + body
        frame += _crc16(frame, crc_extra).to_bytes(2, "little")
        if self.signing_state is not None:
            frame = sign_frame(frame, crc_extra, self.signing_state)
        return self._send_frame(peer, frame, (sysid,))

    def _send_frame(self, peer, frame: bytes, sysids) -> bool:
        if not self._transport.send(peer, frame):
            self.counters["send_errors"] += 1
            return False
        self.counters["frames_out"] += 1
        self.counters["bytes_out"] += len(frame)
        if self.tlogs is not None:
            for sysid in sysids:
                self.tlogs.write(sysid, frame)
        return True

    def send_heartbeat(self) -> int:
        """Send one GCS HEARTBEAT to every peer; returns how many were sent."""
        peers = {}
        for sysid, peer in self._peer_of.items():
            peers.setdefault(peer, []).append(sysid)
        for peer in self._transport.peers():
            peers.setdefault(peer, [])
        sent = 0
        for peer, sysids in peers.items():
            enc = self._encoder(peer)
            msg = mavlink.MAVLink_heartbeat_message(
                _TYPE_GCS, _AUTOPILOT_INVALID, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0,
                mavlink.MAV_STATE_ACTIVE, 3)
            frame = msg.pack(enc)
            enc.seq = (enc.seq + 1) & 0xFF
            sent += self._send_frame(peer, frame, sysids)
        return sent

    async def _housekeeping_loop(self) -> None:
        period_s = 1.0 / self.heartbeat_hz
        while True:
            if self.signing_state is not None:
                refresh_timestamp(self.signing_state, self.clock.time())
            self.send_heartbeat()
            if self.tlogs is not None:
                self.tlogs.flush()
            await self.clock.sleep(period_s)
