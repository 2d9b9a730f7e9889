"""Receiving half of :class:`~mission.link.endpoint.MavEndpoint`: parsing, checks and demultiplexing.

:class:`EndpointReceiving` is a mixin: the transport callbacks (``_on_datagram``,
``_on_stream_data``, ``_on_peer_lost``) parse frames robustly (bad frames are counted, never
raised), check signatures, log each frame in its sender's ``.tlog``, hand each message to the
vehicle attached to its system id and detect duplicate system ids. It works on the attributes
that :class:`~mission.link.endpoint.MavEndpoint` sets up in its constructor (``counters``,
``tlogs``, ``verifier``, ``_peer_of``, ``_handlers``, ``_hb_seen``, ``_hb_waiters`` ...).
"""
from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.link.endpoint_registry import LinkError

__all__ = ["EndpointReceiving"]

#: an address heard from within this many clock seconds is still "active" (duplicate detection)
_ACTIVE_WINDOW_S = 3.0

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


class EndpointReceiving:
    """Mixin of :class:`~mission.link.endpoint.MavEndpoint`: everything on the way in."""

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
