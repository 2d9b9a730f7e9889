"""Sending half of :class:`~mission.link.endpoint.MavEndpoint`: encoding, routing, framing, heartbeat.

:class:`EndpointSending` is a mixin: it encodes messages (one pymavlink encoder, hence one
sequence number, per peer; signed when signing is on), routes each to the address its system id
is pinned to (never to an address that only claimed it), builds MAVLink 2 frames from packed payloads (the setpoint fast path), logs
what it sends in the ``.tlog`` files and runs the 1 Hz GCS heartbeat. It works on the attributes
that :class:`~mission.link.endpoint.MavEndpoint` sets up in its constructor (``counters``,
``tlogs``, ``signing``, ``signing_state``, ``_transport``, ``_encoders``, ``_peer_of`` ...).
"""
from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.link.setpoint_frame import SetpointFramer, crc16
from mission.link.signing import apply_signing, refresh_timestamp, setup_signing_message, sign_frame

__all__ = ["EndpointSending"]

_V2_HEADER = struct.Struct("<BBBBBBBHB")
_AUTOPILOT_INVALID = mavlink.MAV_AUTOPILOT_INVALID
_TYPE_GCS = mavlink.MAV_TYPE_GCS


class EndpointSending:
    """Mixin of :class:`~mission.link.endpoint.MavEndpoint`: everything on the way out."""

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

    def _route(self, sysid: int):
        """The address ``sysid`` is pinned to, else the transport's default; None (counted
        ``unroutable``) when there is neither."""
        peer = self._peer_of.get(sysid)
        if peer is None:
            peer = self._transport.default_peer()
            if peer is None:
                self.counters["unroutable"] += 1
        return peer

    def send(self, sysid: int, msg) -> bool:
        """Encode ``msg`` and send it to the address ``sysid`` is pinned to (its first autopilot HEARTBEAT's).

        Non-blocking. Returns False (and counts ``unroutable``) when ``sysid`` was never heard
        and the transport has no default destination.
        """
        peer = self._route(sysid)
        if peer is None:
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
        taken = self._next_seq(sysid)
        if taken is None:
            return False
        peer, seq = taken
        body = payload.rstrip(b"\x00") or b"\x00"
        frame = _V2_HEADER.pack(0xFD, len(body), 0, 0, seq, self.gcs_sysid, self.gcs_compid,
                                msg_id & 0xFFFF, msg_id >> 16) + body
        frame += crc16(frame, crc_extra).to_bytes(2, "little")
        if self.signing_state is not None:
            frame = sign_frame(frame, crc_extra, self.signing_state)
        return self._send_frame(peer, frame, (sysid,))

    def setpoint_framer(self, msg_id: int, target_system: int, target_component: int,
                        coordinate_frame: int) -> SetpointFramer:
        """A :class:`~mission.link.setpoint_frame.SetpointFramer` from this endpoint's system and
        component ids to a vehicle, for :meth:`send_setpoint`."""
        return SetpointFramer(msg_id, self.gcs_sysid, self.gcs_compid, target_system, target_component,
                              coordinate_frame)

    def send_setpoint(self, sysid: int, framer: SetpointFramer, time_boot_ms: int, x, y, z, yaw: float,
                      type_mask: int) -> bool:
        """Send one setpoint frame built by ``framer`` (:meth:`setpoint_framer`) to ``sysid``.

        The frame is byte-identical to pymavlink's ``pack`` of the same message (the peer's
        sequence number, signed when signing is on); same routing, counting and logging as
        :meth:`send`. ``x, y, z`` are the message's own fields (metres NED, or degE7 and metres).
        """
        taken = self._next_seq(sysid)
        if taken is None:
            return False
        peer, seq = taken
        frame = framer.frame(seq, time_boot_ms, x, y, z, yaw, type_mask)
        if self.signing_state is not None:
            frame = sign_frame(frame, framer.crc_extra, self.signing_state)
        return self._send_frame(peer, frame, (sysid,))

    def _next_seq(self, sysid: int):
        """``(peer, sequence number)`` for the next frame to ``sysid`` (the peer's number taken),
        or None when it cannot be routed (counted by :meth:`_route`)."""
        peer = self._peer_of.get(sysid)   # the pinned address (nearly always there): no _route call
        if peer is None:
            peer = self._route(sysid)
            if peer is None:
                return None
        enc = self._encoders.get(peer)
        if enc is None:
            enc = self._encoder(peer)
        seq = enc.seq
        enc.seq = (seq + 1) & 0xFF
        return peer, seq

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
        """Send one GCS HEARTBEAT to every vehicle's address (and the transport's own peer).

        A ``udpin`` endpoint's transport peers are every address that ever sent a datagram
        (garbage, forgeries): only the addresses of system ids it accepted get the heartbeat.
        Returns how many were sent.
        """
        peers = {}
        for sysid, peer in self._peer_of.items():
            peers.setdefault(peer, []).append(sysid)
        if self.spec.kind != "udpin":
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
            self.send_heartbeat()  # no disk I/O here: the tlogs are written by their own thread
            await self.clock.sleep(period_s)
