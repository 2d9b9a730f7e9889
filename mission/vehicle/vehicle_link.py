"""One vehicle seen through a :class:`~mission.link.endpoint.MavEndpoint`: telemetry, commands, setpoints.

:class:`VehicleLink` keeps :attr:`VehicleLink.state` (a :class:`VehicleState`) up to date from the
vehicle's telemetry, sends commands with retries and ACK matching (:meth:`VehicleLink.command_long`),
runs the takeoff, land and RTL sequences each autopilot flavour expects, and converts mission-frame
setpoints to the vehicle's own frame (:meth:`VehicleLink.send_position_enu`).

Frames: the mission frame is ENU about the mission origin (``docs/interfaces.md``). A vehicle's
LOCAL_NED origin is derived from its HOME_POSITION (home geodetic minus home's local x, y, z), so
setpoints are right whatever the vehicle's home and EKF origin. Yaw is a heading in radians,
clockwise from north (the MAVLink convention).

The commands (COMMAND_LONG with retries, modes, arming, rates, home) are the mixin
:class:`mission.vehicle.vehicle_commands.VehicleCommands`, the telemetry handling
:class:`mission.vehicle.state.VehicleTelemetry`; this module holds the link itself, the takeoff,
land and RTL sequences and the setpoints.
"""
from __future__ import annotations

import asyncio
import collections
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from formation.geodesy import enu_to_geodetic
from mission.core.tasks import spawn
from mission.link.endpoint_registry import LinkError
from mission.link.endpoint import MavEndpoint
from mission.vehicle.frames import MissionToLocal
from mission.vehicle.prearm import PrearmStatus
from mission.vehicle.prearm_params import ParamCache
from mission.vehicle.state import CommandError, VehicleState, VehicleTelemetry
from mission.vehicle.vehicle_commands import VehicleCommands

__all__ = ["VehicleLink", "DEFAULT_RATES_HZ"]

#: Telemetry a mission needs, and at what rate (Hz); 0 stops what it does not need (CPU at N = 100+).
#: The position comes from LOCAL_POSITION_NED (5 Hz, which also updates ``relative_alt_m``);
#: GLOBAL_POSITION_INT (lat, lon, alt) at 1 Hz. See :meth:`VehicleLink.set_message_rates`.
DEFAULT_RATES_HZ: dict[str, float] = {
    "LOCAL_POSITION_NED": 5.0, "GLOBAL_POSITION_INT": 1.0, "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5, "GPS_RAW_INT": 1.0,
    "ATTITUDE": 0.0, "BATTERY_STATUS": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0,
    "POSITION_TARGET_GLOBAL_INT": 0.0,
}

_M = mavlink
_MASK_POSITION = 0x1F8 | 0x800          # ignore velocity, acceleration, yaw rate
_MASK_NO_YAW = _MASK_POSITION | 0x400
_HOLD_RATE_HZ = 10.0
_SP_LOCAL = _M.MAVLink_set_position_target_local_ned_message


def _chained(first, second):
    """A message handler calling ``first`` (if any) then ``second``."""
    if first is None:
        return second

    def both(msg):
        first(msg)
        second(msg)
    return both


class VehicleLink(VehicleCommands, VehicleTelemetry):
    """A vehicle (one system id) on an endpoint. Create with :meth:`create`.

    Attributes
    ----------
    sysid : int
    compid : int
        The autopilot's component id (from its HEARTBEAT).
    flavour : str
    uid : int or None
        AUTOPILOT_VERSION uid once :meth:`request_autopilot_version` ran.
    state : VehicleState
    endpoint : MavEndpoint
    setpoint_frame : str
        ``"local_ned"`` (SET_POSITION_TARGET_LOCAL_NED) or ``"global_int"``.
    statustexts : collections.deque
        The last STATUSTEXT messages as ``(clock_s, severity, text)``.
    prearm : mission.vehicle.prearm.PrearmStatus
        The autopilot's own pre-arm state (SYS_STATUS bits, EKF / estimator flags, refusal texts).
    params : mission.vehicle.prearm_params.ParamCache
        Parameter values heard (PARAM_VALUE), read with :func:`mission.vehicle.prearm_params.read_params`.
    errors : list of LinkError
        Link problems reported by the endpoint (e.g. duplicate system id).
    rejected : dict of str to int
        Telemetry messages rejected because their values cannot be true (NaN positions, a
        home out of range...), by message name; :attr:`last_rejection` says why.
    status_heartbeats : int
        How many autopilot heartbeats in a row (all from the vehicle's pinned address: the
        endpoint delivers no other) reported the current ``state.mode`` and ``state.armed``: a
        change reported once is not yet corroborated (``mission.flight.faults.loss`` waits for 2).
    status_since_s : float or None
        Clock time of the first of those heartbeats.
    """

    def __init__(self, endpoint: MavEndpoint, sysid: int, heartbeat, *, clock, mission_origin,
                 setpoint_frame: str = "local_ned") -> None:
        if setpoint_frame not in ("local_ned", "global_int"):
            raise ValueError(f"setpoint_frame must be 'local_ned' or 'global_int', got {setpoint_frame!r}")
        self.endpoint = endpoint
        self.clock = clock
        self.sysid = int(sysid)
        self.compid = int(heartbeat.get_srcComponent())
        self.mission_origin = tuple(float(v) for v in mission_origin)
        self.setpoint_frame = setpoint_frame
        autopilot = heartbeat.autopilot
        self.flavour = ("ardupilot" if autopilot == _M.MAV_AUTOPILOT_ARDUPILOTMEGA
                        else "px4" if autopilot == _M.MAV_AUTOPILOT_PX4 else "generic")
        self.uid: int | None = None
        self.state = VehicleState(sysid=self.sysid, flavour=self.flavour)
        self.statustexts: collections.deque = collections.deque(maxlen=20)
        self.errors: list[LinkError] = []
        self.rejected: dict[str, int] = {}
        self.last_rejection: str | None = None
        self.status_heartbeats = 0
        self.status_since_s: float | None = None
        self._heartbeat_request_s = -1e18  # when request_heartbeat last asked (clock s)
        self.frame_map: MissionToLocal | None = None
        self.setpoints_sent = 0
        self._home_local = (0.0, 0.0, 0.0)
        self._local_s: float | None = None
        self._enu_cache: tuple | None = None  # (position_ned_m, frame_map, enu): see position_enu_m
        self._last_rx_s = clock.time()
        self._t0_s = clock.time()  # time_boot_ms of the setpoints: clock seconds since the link opened
        self._acks: dict[int, asyncio.Queue] = {}
        self._locks: dict[int, asyncio.Lock] = {}
        self._events: dict[str, asyncio.Event] = {
            "home": asyncio.Event(), "version": asyncio.Event(), "update": asyncio.Event()}
        self._hold_task: asyncio.Task | None = None
        self._hold_target: tuple | None = None
        self._external_send_s = -1e18
        self._framer: tuple | None = None  # (compid, setpoint_frame, SetpointFramer): see _setpoint_framer
        self._handlers: dict[int, Callable] = {
            _M.MAVLINK_MSG_ID_HEARTBEAT: self._on_heartbeat,
            _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._on_global_position,
            _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._on_local_position,
            _M.MAVLINK_MSG_ID_SYS_STATUS: self._on_sys_status,
            _M.MAVLINK_MSG_ID_BATTERY_STATUS: self._on_battery,
            _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._on_extended_state,
            _M.MAVLINK_MSG_ID_HOME_POSITION: self._on_home,
            _M.MAVLINK_MSG_ID_COMMAND_ACK: self._on_ack,
            _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._on_version,
            _M.MAVLINK_MSG_ID_STATUSTEXT: self._on_statustext,
            _M.MAVLINK_MSG_ID_WIND_COV: self._on_wind_cov,
            _M.MAVLINK_MSG_ID_WIND: self._on_wind,
        }
        self.prearm = PrearmStatus(self.flavour)
        self.params = ParamCache(self.flavour)
        extra = {**self.prearm.handlers(clock), _M.MAVLINK_MSG_ID_PARAM_VALUE: self.params.on_param_value}
        for msg_id, fn in extra.items():
            self._handlers[msg_id] = _chained(self._handlers.get(msg_id), fn)
        self._on_heartbeat(heartbeat)

    @classmethod
    async def create(cls, endpoint: MavEndpoint, sysid: int | None = None, *, clock,
                     mission_origin: tuple[float, float, float], heartbeat_timeout_s: float = 10.0,
                     setpoint_frame: str = "local_ned") -> "VehicleLink":
        """Wait for the vehicle's first autopilot HEARTBEAT and attach to the endpoint.

        Parameters
        ----------
        endpoint : MavEndpoint
        sysid : int, optional
            The vehicle's system id; None takes the first autopilot heard that is not attached yet.
        clock : object
            The mission clock.
        mission_origin : tuple of float
            ``(lat_deg, lon_deg, alt_m)`` of the mission ENU frame.
        heartbeat_timeout_s : float
            Clock seconds to wait for the heartbeat.
        setpoint_frame : str
            ``"local_ned"`` (default) or ``"global_int"``.

        Raises
        ------
        LinkError
            No heartbeat in time, or the system id is a duplicate (names both endpoints).
        """
        sysid, heartbeat = await endpoint.wait_heartbeat(sysid, heartbeat_timeout_s)
        self = cls(endpoint, sysid, heartbeat, clock=clock, mission_origin=mission_origin,
                   setpoint_frame=setpoint_frame)
        endpoint.attach(sysid, self._on_message, self._on_link_error)
        return self

    def __repr__(self) -> str:
        return f"VehicleLink(sysid={self.sysid}, {self.flavour}, {self.endpoint.uri!r})"

    # ------------------------------------------------------------------ flight sequences
    async def takeoff(self, alt_m: float) -> None:
        """Take off to ``alt_m`` above home with the flavour's sequence; returns when commanded.

        ArduPilot: GUIDED, arm, MAV_CMD_NAV_TAKEOFF. PX4: stream setpoints at the current
        position and ``alt_m`` above home, OFFBOARD, arm; the setpoints keep streaming (10 Hz)
        until :meth:`send_position_enu` is called by someone else (e.g. a SetpointStreamer).
        """
        if self.flavour == "ardupilot":
            await self.set_mode("GUIDED")
            await self.arm()
            await self.command_long(_M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, float(alt_m),
                                    timeout_s=2.0)
            return
        if self.flavour != "px4":
            raise CommandError(f"{self._who()}: takeoff is not supported for a generic autopilot", sysid=self.sysid)
        here = self.position_enu_m()
        home = self.home_enu_m()
        if here is None or home is None:
            raise CommandError(f"{self._who()}: takeoff needs a position and a home (call wait_home first)",
                               sysid=self.sysid)
        self._hold_target = ((float(here[0]), float(here[1]), float(home[2]) + float(alt_m)), None)
        self._start_hold()
        await self.clock.sleep(0.5)
        await self.set_mode("OFFBOARD")
        await self.arm()

    @property
    def hold_streaming(self) -> bool:
        """True while the PX4 takeoff hold stream runs (until someone else sends setpoints)."""
        return self._hold_task is not None and not self._hold_task.done()

    def _start_hold(self) -> None:
        self._external_send_s = -1e18
        if self._hold_task is None or self._hold_task.done():
            self._hold_task = spawn(self._hold_loop(), f"the takeoff hold stream of vehicle {self.sysid}")

    def _stop_hold(self) -> None:
        if self._hold_task is not None:
            self._hold_task.cancel()
            self._hold_task = None

    async def _hold_loop(self) -> None:
        period_s = 1.0 / _HOLD_RATE_HZ
        while self.clock.time() - self._external_send_s > 3 * period_s:
            position, yaw = self._hold_target
            self._send_position(position, yaw)
            await self.clock.sleep(period_s)

    async def land(self) -> None:
        """Land where it is (LAND mode; PX4 AUTO.LAND); stops the takeoff hold stream."""
        self._stop_hold()
        await self.set_mode("LAND")

    async def rtl(self) -> None:
        """Return to launch (RTL mode; PX4 AUTO.RTL); stops the takeoff hold stream."""
        self._stop_hold()
        await self.set_mode("RTL")

    # ------------------------------------------------------------------ setpoints
    def send_position_enu(self, position_enu_m, yaw_rad: float | None = None) -> None:
        """Send one position setpoint given in the mission ENU frame (non-blocking, one datagram).

        Parameters
        ----------
        position_enu_m : array_like
            ``(east_m, north_m, up_m)`` in the mission frame.
        yaw_rad : float, optional
            Heading (clockwise from north); None leaves the yaw alone.

        Raises
        ------
        CommandError
            The vehicle's home (hence its frame) is not known yet.
        """
        now_s = self.clock.time()
        self._external_send_s = now_s
        self._send_position(position_enu_m, yaw_rad, now_s)

    def _send_position(self, position_enu_m, yaw_rad, now_s: float | None = None) -> None:
        east_m, north_m, up_m = position_enu_m
        mask = _MASK_NO_YAW if yaw_rad is None else _MASK_POSITION
        yaw = 0.0 if yaw_rad is None else float(yaw_rad)
        if now_s is None:
            now_s = self.clock.time()
        t_ms = int((now_s - self._t0_s) * 1000) & 0xFFFFFFFF
        if self.setpoint_frame == "local_ned":
            fmap = self.frame_map
            if fmap is None:
                raise CommandError(f"{self._who()}: no home yet, cannot place a LOCAL_NED setpoint "
                                   f"(call wait_home first)", sysid=self.sysid)
            x, y, z = fmap.mission_enu_to_local_ned(float(east_m), float(north_m), float(up_m))
        else:
            lat, lon, alt = enu_to_geodetic([float(east_m), float(north_m), float(up_m)], self.mission_origin)
            x, y, z = int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)), float(alt)
        if self.endpoint.send_setpoint(self.sysid, self._setpoint_framer(), t_ms, x, y, z, yaw, mask):
            self.setpoints_sent += 1

    def _setpoint_framer(self):
        """The endpoint's frame packer for this vehicle's setpoints (rebuilt if its component id
        or setpoint frame changed)."""
        cached = self._framer
        if cached is not None and cached[0] == self.compid and cached[1] == self.setpoint_frame:
            return cached[2]
        if self.setpoint_frame == "local_ned":
            msg_id, frame = _SP_LOCAL.id, _M.MAV_FRAME_LOCAL_NED
        else:
            msg_id, frame = _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT, _M.MAV_FRAME_GLOBAL_INT
        framer = self.endpoint.setpoint_framer(msg_id, self.sysid, self.compid, frame)
        self._framer = (self.compid, self.setpoint_frame, framer)
        return framer

    async def close(self) -> None:
        """Stop the hold stream and detach from the endpoint (the endpoint stays open)."""
        self._stop_hold()
        self.endpoint.detach(self.sysid)
