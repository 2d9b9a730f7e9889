"""Receiving half of :class:`~mission.link.endpoint.MavEndpoint`: parsing, checks and demultiplexing.

:class:`EndpointReceiving` is a mixin: the transport callbacks (``receive_datagram``,
``receive_stream_data``, ``peer_lost``) parse frames robustly (bad frames are counted, never
raised), check signatures, screen each frame's sender (:meth:`EndpointReceiving._screen`: the
vehicle's pinned address, the plan's system ids), log each accepted frame in its sender's
``.tlog`` and every refused one in the quarantine log, hand each message to the vehicle attached
to its system id and detect duplicate system ids. It works on the attributes that
:class:`~mission.link.endpoint.MavEndpoint` sets up in its constructor (``counters``, ``tlogs``,
``quarantine``, ``verifier``, ``planned_sysids``, ``_pins``, ``_peer_of``, ``_handlers``,
``_hb_waiters`` ...).
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.link.endpoint_registry import LinkError
from wire.fast_decode import decode_single_frame

__all__ = ["EndpointReceiving", "SUSPECT_REASONS"]

#: counters of suspect senders: a frame for a pinned system id from another address (refused),
#: a system id not in the plan (refused), a planned one before its first autopilot HEARTBEAT
#: beyond the ``_EARLY_FRAMES_MAX`` held until it (refused), a vehicle pinned again after its address was silent for ``_REPIN_SILENCE_S``
#: distinct refused system ids remembered for the operator (a flood of random ids stays bounded)
_MAX_REFUSED_SYSIDS = 256
SUSPECT_REASONS = ("foreign_address", "unplanned_sysid", "unverified", "repinned")

#: a pinned address heard from within this many clock seconds is still "active": a second
#: address sending autopilot heartbeats meanwhile, before the vehicle is attached, is a duplicate
_ACTIVE_WINDOW_S = 3.0
#: frames of a planned system id held (per id) until its first autopilot HEARTBEAT pins it: then
#: those from the pinned address go to its ``.tlog``, the others to the quarantine log
_EARLY_FRAMES_MAX = 64
#: a vehicle whose pinned address sent no autopilot HEARTBEAT for this long may be pinned again
#: (a rebooted autopilot on a new UDP port); a vehicle that long silent was declared lost already
_REPIN_SILENCE_S = 10.0

_MSG_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_MSG_BAD = mavlink.MAVLINK_MSG_ID_BAD_DATA
_MSG_UNKNOWN = mavlink.MAVLINK_MSG_ID_UNKNOWN
_AUTOPILOT_INVALID = mavlink.MAV_AUTOPILOT_INVALID
_TYPE_GCS = mavlink.MAV_TYPE_GCS


def _is_autopilot_heartbeat(msg) -> bool:
    return msg.autopilot != _AUTOPILOT_INVALID and msg.type != _TYPE_GCS


class EndpointReceiving:
    """Mixin of :class:`~mission.link.endpoint.MavEndpoint`: everything on the way in."""

    @staticmethod
    def _new_parser() -> mavlink.MAVLink:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser

    def receive_datagram(self, data: bytes, peer) -> None:
        """Transport callback: one UDP datagram (whole frames; a partial tail is counted).

        A datagram of exactly one valid frame of a fixed-layout message (nearly all telemetry)
        is decoded by :func:`~wire.fast_decode.decode_single_frame` into the message
        pymavlink would return; anything else goes through pymavlink's parser.
        """
        msg = decode_single_frame(data)
        if msg is not None:
            self._deliver((msg,), peer, len(data))
            return
        parser = self._datagram_parser
        msgs = parser.parse_buffer(data)
        if parser.buf_len():
            self.counters["truncated"] += 1
            parser.buf = bytearray()
            parser.buf_index = 0
            parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        if msgs:
            self._deliver(msgs, peer, len(data))

    def receive_stream_data(self, data: bytes, peer) -> None:
        """Transport callback: bytes from a stream (TCP connection, serial line)."""
        parser = self._stream_parsers.get(peer)
        if parser is None:
            parser = self._stream_parsers[peer] = self._new_parser()
        msgs = parser.parse_buffer(data)
        if msgs:
            self._deliver(msgs, peer, len(data))

    def peer_lost(self, peer) -> None:
        """Transport callback: a stream peer went away (its vehicles may pin again on reconnection)."""
        self._stream_parsers.pop(peer, None)
        self._encoders.pop(peer, None)
        for sysid in [s for s, pin in self._pins.items() if pin[0] == peer]:
            del self._pins[sysid]

    def _deliver(self, msgs, peer, nbytes: int) -> None:
        counters = self.counters
        counters["bytes_in"] += nbytes
        tlogs = self.tlogs
        peer_of = self._peer_of
        handlers = self._handlers
        pins = self._pins
        verifier = self.verifier
        for msg in msgs:
            # not msg.id: BAD_DATA / UNKNOWN inherit id 0 (HEARTBEAT) and messages with a
            # field named "id" (BATTERY_STATUS...) shadow the class attribute; get_header() and
            # get_msgbuf() return pymavlink's own objects (no copy)
            header = msg.get_header()
            msg_id = header.msgId
            if msg_id == _MSG_BAD:
                counters["bad_crc" if "CRC" in msg.reason else "malformed"] += 1
                continue
            if verifier is not None and self._refused_by_signing(msg, msg_id, peer):
                continue
            counters["frames_in"] += 1
            if msg_id == _MSG_UNKNOWN:  # CRC not checkable (no CRC_EXTRA): never in a vehicle's tlog
                counters["unknown_msgid"] += 1
                self._quarantine_frame(msg.get_msgbuf())
                continue
            sysid = header.srcSystem
            autopilot_hb = msg_id == _MSG_HEARTBEAT and _is_autopilot_heartbeat(msg)
            pin = pins.get(sysid)
            # a pinned vehicle's own address (nearly every frame) passes _screen: not asked
            refused = None if pin is not None and pin[0] == peer else self._screen(sysid, msg, peer, autopilot_hb)
            if refused is not None:
                frame = msg.get_msgbuf()
                if refused == "unverified" and self._hold_early(sysid, frame, peer):
                    continue
                counters[refused] += 1
                if refused == "unplanned_sysid" and len(self._refused_sysids) < _MAX_REFUSED_SYSIDS:
                    self._refused_sysids.add(sysid)
                self._quarantine_frame(frame)
                continue
            if autopilot_hb and sysid in self._early:
                self._release_early(sysid, peer)
            if tlogs is not None:
                tlogs.write(sysid, msg.get_msgbuf())
            if self.forward is not None:
                self.forward(msg.get_msgbuf())
            if autopilot_hb:
                self._on_autopilot_heartbeat(sysid, msg, peer)
            elif sysid not in peer_of:
                peer_of[sysid] = peer  # a provisional route (any system id accepted): a pin replaces it
            handler = handlers.get(sysid)
            if handler is not None:
                try:
                    handler[0](msg)
                except Exception as exc:  # a vehicle's bug must not stop the link (or the poller)
                    counters["handler_errors"] += 1
                    self.last_handler_error = f"{msg.get_type()} from {sysid}: {type(exc).__name__}: {exc}"

    def _refused_by_signing(self, msg, msg_id: int, peer) -> bool:
        """Check ``msg``'s signature; True (counted, SETUP_SIGNING maybe sent) if rejected."""
        reason = self.verifier.check(msg)
        if reason is None:
            return False
        self.counters[reason] += 1
        sysid = msg.get_srcSystem()
        if (reason == "unsigned" and msg_id == _MSG_HEARTBEAT and self.signing.send_setup
                and _is_autopilot_heartbeat(msg) and self.verifier.needs_setup(sysid)):
            pin = self._pins.get(sysid)
            first = self._setup_peer.setdefault(sysid, peer) if sysid in self._expected else None
            if first == peer and (pin is None or pin[0] == peer):
                self._send_setup_signing(sysid, msg.get_srcComponent(), peer)
            else:  # not a vehicle of this mission, or not its address: never hand it the key
                self.counters["setup_signing_refused"] += 1
        return True

    def _screen(self, sysid: int, msg, peer, autopilot_hb: bool) -> str | None:
        """None if ``msg`` may be delivered, else the counter naming why not (:data:`SUSPECT_REASONS`).

        A system id is pinned to the address of its first autopilot HEARTBEAT; any frame for it
        from another address is ``foreign_address`` (before the vehicle is attached, a foreign
        autopilot HEARTBEAT while the pinned address is active is also a duplicate system id),
        unless the pinned address has been silent for ``_REPIN_SILENCE_S``. With
        ``planned_sysids``, other system ids are ``unplanned_sysid`` and a planned one's frames
        before its pin ``unverified`` (held by :meth:`_hold_early` until the pin, counted only
        when its buffer is full).
        """
        pin = self._pins.get(sysid)
        if pin is None:
            planned = self.planned_sysids
            if planned is not None and sysid not in planned:
                return "unplanned_sysid"
            return None if autopilot_hb or planned is None else "unverified"
        if peer == pin[0]:
            return None
        if autopilot_hb:
            silent_s = self.clock.time() - self._pin_heard_s.get(sysid, -1e18)
            if silent_s >= _REPIN_SILENCE_S and msg.get_srcComponent() == pin[1]:
                return None  # _on_autopilot_heartbeat pins it again (counted "repinned")
            if sysid not in self._handlers and silent_s <= _ACTIVE_WINDOW_S:
                self._report_duplicate(sysid, f"autopilot heartbeats from {pin[0]} and {peer}")
        return "foreign_address"

    def _hold_early(self, sysid: int, frame, peer) -> bool:
        """Hold a planned vehicle's frame until its pin (False when its buffer is full)."""
        held = self._early.setdefault(sysid, [])
        if len(held) >= _EARLY_FRAMES_MAX:
            return False
        held.append((self.clock.time(), peer, bytes(frame)))
        return True

    def _release_early(self, sysid: int, peer) -> None:
        """``sysid`` is being pinned to ``peer``: its held frames to its tlog, or to the quarantine."""
        for t_s, sender, frame in self._early.pop(sysid):
            if sender != peer:
                self.counters["foreign_address"] += 1
                self._quarantine_frame(frame)
            elif self.tlogs is not None:
                self.tlogs.write(sysid, frame, t_s)

    def _quarantine_frame(self, frame) -> None:
        quarantine = self.quarantine
        if quarantine is None:
            return
        self.counters["quarantined" if quarantine.write(frame) else "quarantine_dropped"] += 1

    def _on_autopilot_heartbeat(self, sysid: int, msg, peer) -> None:
        compid = msg.get_srcComponent()
        pin = self._pins.get(sysid)
        if pin is None or pin[0] != peer:  # the first one (or a re-pin that _screen allowed)
            if pin is not None:
                self.counters["repinned"] += 1
            pin = self._pins[sysid] = (peer, compid)
        elif pin[1] != compid:
            return  # another component at the vehicle's address: delivered, but not the autopilot
        self._pin_heard_s[sysid] = self.clock.time()
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
        if any(e.sysid == sysid for e in self.errors):
            return
        self._record_error(sysid, LinkError(f"duplicate MAVLink system id {sysid} on {self.uri!r}: {detail}"))

    def _record_error(self, sysid: int, exc: LinkError) -> None:
        exc.sysid = sysid
        self.counters["duplicate_sysid"] += 1
        self.errors.append(exc)
        handler = self._handlers.get(sysid)
        if handler is not None:
            handler[1](exc)
