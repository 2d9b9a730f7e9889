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
two addresses sending autopilot heartbeats with the same id on one endpoint before the vehicle
is attached, two different AUTOPILOT_VERSION uids for one id, or one id heard on two endpoints
sharing a :class:`SysidRegistry`.

Without signing nothing is authenticated, so the endpoint refuses to be steered instead: each
vehicle is *pinned* to the address (and autopilot component id) of its first autopilot
HEARTBEAT; frames for a pinned system id from any other address are never delivered, never
routed to and counted ``foreign_address``; with ``planned_sysids`` (the mission's vehicles on
this endpoint) frames of any other system id are counted ``unplanned_sysid``; a planned one's
frames before its pin are held and, once it is pinned, logged in its ``.tlog`` if they came from
its address (else counted ``foreign_address``). All of those, and frames of unknown message ids (CRC
unchecked), go to the mission's one capped quarantine log (:class:`~mission.link.tlog.QuarantineLog`),
never to a vehicle's ``.tlog``. See ``docs/faults.md`` ("Forged MAVLink without signing").

The endpoint is split by concern: :mod:`mission.link.endpoint_receive` (parsing, checks,
demultiplexing), :mod:`mission.link.endpoint_send` (encoding, routing, framing, heartbeat) and
:mod:`mission.link.endpoint_registry` (:class:`LinkError`, :class:`SysidRegistry`, imported from
there); this module holds the endpoint itself: opening, closing and the vehicles' API.
"""
from __future__ import annotations

import asyncio
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.tasks import spawn
from mission.core.clock import cancel_and_wait, wait_on_clock
from mission.link.transport import open_transport
from mission.core.uri import ConnectionSpec, parse_connection
from mission.link.endpoint_receive import SUSPECT_REASONS, EndpointReceiving
from mission.link.endpoint_registry import LinkError, SysidRegistry
from mission.link.endpoint_send import EndpointSending
from mission.link.signing import SignatureVerifier
from mission.core.signing_config import SigningConfig
from mission.link.tlog import TlogSet

__all__ = ["MavEndpoint"]


class MavEndpoint(EndpointReceiving, EndpointSending):
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
        :attr:`last_handler_error`, the link goes on); the suspect senders (:data:`SUSPECT_REASONS`,
        also :attr:`suspect_counters`): ``foreign_address``, ``unplanned_sysid``, ``unverified``,
        ``repinned``; ``quarantined`` / ``quarantine_dropped`` (frames this endpoint put in the
        quarantine log / that were beyond its cap).
    errors : list of LinkError
        Duplicate-sysid problems found so far (also delivered to the attached vehicles).
    tlogs : TlogSet or None
    quarantine : mission.link.tlog.QuarantineLog or None
        The mission's quarantine log (shared through the registry), None without ``tlog_dir``.
    planned_sysids : frozenset of int or None
        The only system ids this endpoint accepts (None: any).
    """

    def __init__(self, spec: ConnectionSpec, *, clock, tlog_dir=None, gcs_sysid: int = 255,
                 gcs_compid: int = 190, heartbeat_hz: float = 1.0,
                 registry: SysidRegistry | None = None, poller=None,
                 signing: SigningConfig | None = None, planned_sysids=None) -> None:
        self.spec = spec
        self.poller = poller
        self.uri = spec.uri
        self.clock = clock
        self.gcs_sysid = int(gcs_sysid)
        self.gcs_compid = int(gcs_compid)
        self.heartbeat_hz = float(heartbeat_hz)
        self.registry = registry if registry is not None else SysidRegistry()
        self.tlogs = TlogSet(tlog_dir, time_fn=clock.time) if tlog_dir is not None else None
        self.quarantine = (self.registry.quarantine(tlog_dir, self, clock.time)
                           if tlog_dir is not None else None)
        self.planned_sysids = frozenset(int(s) for s in planned_sysids) if planned_sysids is not None else None
        self.counters = dict.fromkeys(
            ("frames_in", "frames_out", "bytes_in", "bytes_out", "bad_crc", "malformed",
             "unknown_msgid", "truncated", "unroutable", "send_errors", "duplicate_sysid",
             "handler_errors", *SUSPECT_REASONS, "quarantined", "quarantine_dropped"), 0)
        self.last_handler_error: str | None = None
        self.forward = None  # mission.link.forward.Forwarder.copy: accepted vehicle frames to GCS clients
        self.counters.update(unsigned=0, bad_signature=0, replayed=0, setup_signing_sent=0,
                             setup_signing_refused=0)
        self.signing = signing
        self.signing_state = signing.new_state(clock.time()) if signing is not None else None
        self.verifier = SignatureVerifier(signing, self.signing_state) if signing is not None else None
        self._setup_sent_s: dict[int, float] = {}
        #: sysid -> the address its first SETUP_SIGNING went to (the key never goes elsewhere)
        self._setup_peer: dict[int, object] = {}
        #: system ids this mission waits for or attached: the only ones ever sent the key
        self._expected: set[int] = set()
        self.errors: list[LinkError] = []
        self._transport = None
        self._datagram_parser = self._new_parser()
        self._stream_parsers: dict[object, mavlink.MAVLink] = {}
        self._encoders: dict[object, mavlink.MAVLink] = {}
        self._peer_of: dict[int, object] = {}
        #: sysid -> (address, autopilot component id) of its first autopilot HEARTBEAT
        self._pins: dict[int, tuple[object, int]] = {}
        self._pin_heard_s: dict[int, float] = {}
        #: sysid -> frames of a planned vehicle before its pin: (clock s, sender, frame)
        self._early: dict[int, list] = {}
        self._refused_sysids: set[int] = set()  # refused as unplanned (at most 256 remembered)
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
                   signing: SigningConfig | None = None, planned_sysids=None) -> "MavEndpoint":
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
        planned_sysids : iterable of int, optional
            The mission's system ids on this endpoint: frames of any other go to the quarantine
            log, counted ``unplanned_sysid``. None accepts any system id (each gets its own
            ``.tlog``).

        Raises
        ------
        ValueError
            Bad connection string.
        LinkError
            The transport cannot be opened (the message names the endpoint and the reason).
        """
        spec = parse_connection(uri)
        self = cls(spec, clock=clock, tlog_dir=tlog_dir, gcs_sysid=gcs_sysid, gcs_compid=gcs_compid,
                   heartbeat_hz=heartbeat_hz, registry=registry, poller=poller, signing=signing,
                   planned_sysids=planned_sysids)
        try:
            self._transport = await open_transport(spec, self, poller)
        except OSError as exc:
            if self.tlogs is not None:
                self.tlogs.close()
            self.registry.release(self)
            raise LinkError(f"cannot open {spec.uri!r}: {exc.strerror or exc}") from exc
        if self.heartbeat_hz > 0:
            self._housekeeping = spawn(self._housekeeping_loop(), f"the heartbeat of link {self.uri}")
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
    @property
    def suspect_counters(self) -> dict[str, int]:
        """Frames refused by sender (:data:`SUSPECT_REASONS`) and the quarantine's counts.

        ``quarantined`` / ``quarantine_dropped`` are this endpoint's; ``quarantine_records``,
        ``quarantine_bytes``, ``quarantine_dropped_total`` are the mission's quarantine log's (shared).
        """
        c = self.counters
        out = {k: c[k] for k in (*SUSPECT_REASONS, "unknown_msgid", "quarantined", "quarantine_dropped")}
        if self.quarantine is not None:
            q = self.quarantine.counters
            out.update(quarantine_records=q["records"], quarantine_bytes=q["bytes"],
                       quarantine_dropped_total=q["dropped"])
        return out

    def pinned_address(self, sysid: int):
        """The address ``sysid`` is pinned to (its first autopilot HEARTBEAT's), or None."""
        pin = self._pins.get(sysid)
        return None if pin is None else pin[0]

    def sysids_seen(self) -> set[int]:
        """System ids heard on this endpoint so far (any component), refused ones included."""
        return set(self._peer_of) | self._refused_sysids

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
            if err.sysid == sysid:
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
