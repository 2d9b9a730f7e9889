"""A tiny fake MAVLink autopilot for tests and benchmarks of the ground-station links (test
support, not shipped: ``from tests.support.fake_autopilot import ...`` in tests and in
``benchmarks/bench_setpoints.py``).

Not a simulator (that is ``sitl_mock``): a :class:`FakeAutopilot` answers commands (ACCEPTED by
default; configurable drops, denials and IN_PROGRESS), reports its mode, armed state, a position
(the last setpoint it received, applied at once) and its home, and records every setpoint with its
arrival time. A :class:`FakeUdpVehicle` puts one or more autopilots behind one UDP socket, in the
running asyncio loop, sending to the ground station's port like PX4 SITL does.
"""
from __future__ import annotations

import asyncio
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from formation.geodesy import enu_to_geodetic, ned_to_enu

from mission.core.clock import cancel_and_wait

__all__ = ["FakeAutopilot", "FakeUdpVehicle"]

_M = mavlink
_SETPOINT_IDS = (_M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT)


def _as_command_long(msg):
    """COMMAND_INT -> the equivalent COMMAND_LONG (x, y as plain numbers) for uniform handling."""
    return _M.MAVLink_command_long_message(msg.target_system, msg.target_component, msg.command, 0,
                                           msg.param1, msg.param2, msg.param3, msg.param4,
                                           float(msg.x), float(msg.y), msg.z)


class FakeAutopilot:
    """Protocol-level fake autopilot (no I/O): feed it messages, send what it returns.

    Parameters
    ----------
    sysid : int
    flavour : str
        ``"ardupilot"`` or ``"px4"`` (sets HEARTBEAT.autopilot).
    uid : int, optional
        AUTOPILOT_VERSION uid (default ``0xFA4E0000 + sysid``).
    home : tuple of float
        ``(lat_deg, lon_deg, alt_m)``; the LOCAL_NED origin is the home.
    drop_first : dict of int to int, optional
        ``{command: n}``: ignore the first ``n`` sends of that command (no ACK).
    results : dict of int to int, optional
        ``{command: MAV_RESULT}`` to answer instead of ACCEPTED.
    in_progress : set of int, optional
        Commands first answered IN_PROGRESS, then with the final result on the first telemetry
        tick at least ``in_progress_delay_s`` later.
    record_setpoints : bool
        Keep every setpoint in :attr:`setpoints` and its arrival ``time.perf_counter()`` in
        :attr:`setpoint_times`.
    compid : int
        Autopilot component id.
    position_rate_hz : float
        Initial rate of GLOBAL_POSITION_INT and LOCAL_POSITION_NED (SET_MESSAGE_INTERVAL changes it).
    """

    def __init__(self, sysid: int, *, flavour: str = "ardupilot", uid: int | None = None,
                 home=(45.0, 5.0, 200.0), drop_first=None, results=None, in_progress=None,
                 record_setpoints: bool = True, compid: int = 1, position_rate_hz: float = 5.0,
                 in_progress_delay_s: float = 0.5) -> None:
        self.sysid = int(sysid)
        self.flavour = flavour
        self.uid = int(uid) if uid is not None else 0xFA4E0000 + self.sysid
        self.home = tuple(float(v) for v in home)
        self.encoder = _M.MAVLink(None, srcSystem=self.sysid, srcComponent=compid)
        self.drop_first = dict(drop_first or {})
        self.results = dict(results or {})
        self.in_progress = set(in_progress or ())
        self.in_progress_delay_s = float(in_progress_delay_s)
        self.record_setpoints = record_setpoints
        self.armed = False
        self.custom_mode = 0
        self.position_ned_m = (0.0, 0.0, 0.0)
        self.commands: list = []
        self.setpoints: list = []
        self.setpoint_count = 0
        self.setpoint_times: list[float] = []
        self.gcs_heartbeats = 0
        self.rates_hz = {_M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: float(position_rate_hz),
                         _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: float(position_rate_hz)}
        self._global_cache = (None, None)
        self._pending_final: list = []

    def encode(self, msg) -> bytes:
        """Pack ``msg`` with this autopilot's identity and sequence."""
        frame = msg.pack(self.encoder)
        self.encoder.seq = (self.encoder.seq + 1) & 0xFF
        return frame

    def heartbeat(self):
        """This autopilot's HEARTBEAT."""
        autopilot = _M.MAV_AUTOPILOT_ARDUPILOTMEGA if self.flavour == "ardupilot" else _M.MAV_AUTOPILOT_PX4
        base = _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (_M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        return _M.MAVLink_heartbeat_message(_M.MAV_TYPE_QUADROTOR, autopilot, base, self.custom_mode,
                                            _M.MAV_STATE_ACTIVE if self.armed else _M.MAV_STATE_STANDBY, 3)

    def telemetry(self, tick: int = 0, tick_hz: float = 5.0) -> list:
        """Messages due at ``tick`` of a ``tick_hz`` clock: position messages at their rates
        (:attr:`rates_hz`, changed by SET_MESSAGE_INTERVAL) and any deferred final ACKs."""
        now = time.monotonic()
        out = [ack for t, ack in self._pending_final if t <= now]
        self._pending_final = [(t, ack) for t, ack in self._pending_final if t > now]
        n, e, d = self.position_ned_m
        for msg_id, rate_hz in self.rates_hz.items():
            if rate_hz <= 0 or (tick + self.sysid) % max(1, round(tick_hz / rate_hz)):
                continue
            if msg_id == _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                out.append(_M.MAVLink_local_position_ned_message(0, n, e, d, 0.0, 0.0, 0.0))
            else:
                if self._global_cache[0] != self.position_ned_m:
                    lat, lon, alt = enu_to_geodetic(ned_to_enu([n, e, d]), self.home)
                    self._global_cache = (self.position_ned_m, (
                        int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)), int(round(float(alt) * 1e3))))
                lat_e7, lon_e7, alt_mm = self._global_cache[1]
                out.append(_M.MAVLink_global_position_int_message(0, lat_e7, lon_e7, alt_mm, int(round(-d * 1e3)),
                                                                  0, 0, 0, 0))
        return out

    def slow_telemetry(self) -> list:
        """Once-a-second messages: HEARTBEAT, SYS_STATUS, EXTENDED_SYS_STATE."""
        gps = _M.MAV_SYS_STATUS_SENSOR_GPS
        landed = _M.MAV_LANDED_STATE_IN_AIR if self.position_ned_m[2] < -0.5 else _M.MAV_LANDED_STATE_ON_GROUND
        return [self.heartbeat(),
                _M.MAVLink_sys_status_message(gps, gps, gps, 100, 12600, -1, 87, 0, 0, 0, 0, 0, 0),
                _M.MAVLink_extended_sys_state_message(0, landed)]

    def home_position(self):
        """HOME_POSITION (home at the local origin: x = y = z = 0)."""
        lat, lon, alt = self.home
        return _M.MAVLink_home_position_message(int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1e3)),
                                               0, 0, 0, [1, 0, 0, 0], 0, 0, 0)

    def handle(self, msg) -> list:
        """React to one message from the ground station; returns the messages to send back."""
        msg_id = msg.get_msgId()
        if msg_id < 0:  # BAD_DATA, UNKNOWN (whose class attribute id is 0, like HEARTBEAT)
            return []
        if msg_id == _M.MAVLINK_MSG_ID_HEARTBEAT:
            self.gcs_heartbeats += 1
            return []
        if msg_id in _SETPOINT_IDS:
            if msg.target_system != self.sysid:
                return []
            self.setpoint_count += 1
            if self.record_setpoints:
                self.setpoint_times.append(time.perf_counter())
                self.setpoints.append(msg)
            if msg_id == _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
                self.position_ned_m = (msg.x, msg.y, msg.z)
            return []
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg_id == _M.MAVLINK_MSG_ID_COMMAND_INT and msg.target_system == self.sysid:
            msg = _as_command_long(msg)
        elif msg_id != _M.MAVLINK_MSG_ID_COMMAND_LONG or msg.target_system != self.sysid:
            return []
        command = msg.command
        self.commands.append(msg)
        if self.drop_first.get(command, 0) > 0:
            self.drop_first[command] -= 1
            return []
        result = self.results.get(command, _M.MAV_RESULT_ACCEPTED)
        out = []
        if result == _M.MAV_RESULT_ACCEPTED:
            out += self._apply(msg)
        ack = _M.MAVLink_command_ack_message(command, result, 0, 0, *src)
        if command in self.in_progress:
            self._pending_final.append((time.monotonic() + self.in_progress_delay_s, ack))
            return [_M.MAVLink_command_ack_message(command, _M.MAV_RESULT_IN_PROGRESS, 10, 0, *src)]
        return [ack] + out

    def _apply(self, msg) -> list:
        command = msg.command
        if command == _M.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 == 1
        elif command == _M.MAV_CMD_DO_SET_MODE:
            if self.flavour == "ardupilot":
                self.custom_mode = int(msg.param2)
            else:
                self.custom_mode = (int(msg.param2) << 16) | (int(msg.param3) << 24)
        elif command == _M.MAV_CMD_NAV_TAKEOFF:
            n, e, _ = self.position_ned_m
            self.position_ned_m = (n, e, -float(msg.param7))
        elif command == _M.MAV_CMD_SET_MESSAGE_INTERVAL and int(msg.param1) in self.rates_hz:
            self.rates_hz[int(msg.param1)] = 1e6 / msg.param2 if msg.param2 > 0 else 0.0
        elif command == _M.MAV_CMD_REQUEST_MESSAGE:
            if int(msg.param1) == _M.MAVLINK_MSG_ID_HOME_POSITION:
                return [self.home_position()]
            if int(msg.param1) == _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                return [_M.MAVLink_autopilot_version_message(
                    _M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.uid)]
        return []


class FakeUdpVehicle(asyncio.DatagramProtocol):
    """One UDP socket (``127.0.0.1``, any port) carrying one or more fake autopilots.

    It sends telemetry to ``gcs_address`` and answers whoever talks to it.

    Parameters
    ----------
    autopilots : list of FakeAutopilot
    gcs_address : tuple
        ``(host, port)`` of the ground station's ``udpin`` socket.
    telemetry_hz : float
        Telemetry tick rate (the highest position rate possible); HEARTBEAT, SYS_STATUS and
        EXTENDED_SYS_STATE go at 1 Hz.
    """

    def __init__(self, autopilots, gcs_address, telemetry_hz: float = 5.0) -> None:
        self.autopilots = list(autopilots)
        self.gcs_address = tuple(gcs_address)
        self.telemetry_hz = float(telemetry_hz)
        self.transport = None
        self.parser = _M.MAVLink(None)
        self.parser.robust_parsing = True
        self.peers = {self.gcs_address}
        self._task = None
        self.frames_in = 0

    async def start(self, port: int = 0) -> "FakeUdpVehicle":
        """Bind and start the telemetry task."""
        loop = asyncio.get_running_loop()
        await loop.create_datagram_endpoint(lambda: self, local_addr=("127.0.0.1", port))
        self._task = asyncio.ensure_future(self._telemetry_loop())
        return self

    @property
    def address(self):
        """The bound ``(host, port)``."""
        return self.transport.get_extra_info("sockname")[:2]

    def connection_made(self, transport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr) -> None:
        self.peers.add(addr)
        for msg in self.parser.parse_buffer(data) or ():
            if msg.get_msgId() < 0:  # BAD_DATA, UNKNOWN
                continue
            self.frames_in += 1
            for ap in self.autopilots:
                for reply in ap.handle(msg):
                    self._send(ap, reply, (addr,))

    def error_received(self, exc) -> None:
        pass

    def _send(self, ap, msg, addrs=None) -> None:
        if self.transport is None or self.transport.is_closing():
            return
        frame = ap.encode(msg)
        for addr in addrs or self.peers:
            self.transport.sendto(frame, addr)

    def send_all(self, ap, msgs) -> None:
        """Send ``msgs`` from ``ap`` to every peer."""
        for msg in msgs:
            self._send(ap, msg)

    async def _telemetry_loop(self) -> None:
        tick = 0
        per_second = max(1, int(round(self.telemetry_hz)))
        # spread the vehicles' telemetry over the tick so N fakes in one process do not burst together
        await asyncio.sleep((self.autopilots[0].sysid * 0.0173) % (1.0 / self.telemetry_hz))
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        while True:
            for ap in self.autopilots:
                if (tick + ap.sysid) % per_second == 0:
                    self.send_all(ap, ap.slow_telemetry())
                self.send_all(ap, ap.telemetry(tick, self.telemetry_hz))
            tick += 1
            next_t += 1.0 / self.telemetry_hz
            await asyncio.sleep(max(0.0, next_t - loop.time()))

    async def stop(self) -> None:
        """Stop telemetry and close the socket."""
        await cancel_and_wait(self._task)
        if self.transport is not None:
            self.transport.close()
