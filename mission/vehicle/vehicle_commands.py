"""Commands of :class:`~mission.vehicle.vehicle_link.VehicleLink`: COMMAND_LONG with retries and ACK matching.

:class:`VehicleCommands` is a mixin: :meth:`~VehicleCommands.command_long` (retries, IN_PROGRESS,
one command of a kind at a time) and the plain commands built on it: message requests, the
autopilot version, the home position, telemetry rates, flight modes, arming. It works on the
attributes :class:`~mission.vehicle.vehicle_link.VehicleLink` sets up in its constructor
(``endpoint``, ``clock``, ``sysid``, ``compid``, ``flavour``, ``state``, ``statustexts``,
``_acks``, ``_locks``, ``_events``) and on :class:`~mission.vehicle.state.VehicleTelemetry`
(``_who``, ``_raise_link_error``).
"""
from __future__ import annotations

import asyncio

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.clock import wait_on_clock
from mission.vehicle.frames import resolve_mode
from mission.vehicle.state import CommandError, command_name
from mission.vehicle.state import result_name as _result_name

__all__ = ["VehicleCommands"]

_M = mavlink
_ACCEPTED = _M.MAV_RESULT_ACCEPTED
_IN_PROGRESS = _M.MAV_RESULT_IN_PROGRESS


class VehicleCommands:
    """Mixin of :class:`~mission.vehicle.vehicle_link.VehicleLink`: commands and their acknowledgements."""

    def _recent_text(self, since_s: float) -> str:
        texts = [t for (ts, _, t) in self.statustexts if ts >= since_s]
        return f"; autopilot says: {' | '.join(texts[-3:])}" if texts else ""

    async def command_long(self, command: int, *params: float, timeout_s: float = 1.0, retries: int = 3,
                           accept: tuple[int, ...] = (_ACCEPTED,)) -> int:
        """Send COMMAND_LONG with retries and wait for its COMMAND_ACK.

        Each retry increments ``confirmation``. An IN_PROGRESS ack stops the retries and extends
        the wait (up to ``max(5 * timeout_s, 5)`` seconds per progress report).

        Parameters
        ----------
        command : int
            ``MAV_CMD_*``.
        *params : float
            Up to 7 parameters (missing ones are 0).
        timeout_s : float
            Clock seconds to wait for an ack after each send.
        retries : int
            Sends after the first one.
        accept : tuple of int
            MAV_RESULT values that count as success.

        Returns
        -------
        int
            The final MAV_RESULT.

        Raises
        ------
        CommandError
            Timeout or a result not in ``accept``; names the vehicle, the command and the result.
        LinkError
            A link problem is known for this vehicle (e.g. duplicate system id).
        ValueError
            More than 7 parameters.
        """
        if len(params) > 7:
            raise ValueError(f"{command_name(command)}: at most 7 parameters, got {len(params)}")
        self._raise_link_error()
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        lock = self._locks.setdefault(command, asyncio.Lock())
        async with lock:
            queue = self._acks[command] = asyncio.Queue()
            started_s = self.clock.time()
            try:
                result = await self._command_attempts(command, p, timeout_s, retries, queue)
            finally:
                self._acks.pop(command, None)
        name = command_name(command)
        if result is None:
            raise CommandError(f"{self._who()}: {name} not acknowledged after {retries + 1} attempts of "
                               f"{timeout_s:g} s{self._recent_text(started_s)}", sysid=self.sysid, command=command)
        if result not in accept:
            raise CommandError(f"{self._who()}: {name} failed: {_result_name(result)}{self._recent_text(started_s)}",
                               sysid=self.sysid, command=command, result=result)
        return result

    async def _command_attempts(self, command, p, timeout_s, retries, queue) -> int | None:
        for confirmation in range(retries + 1):
            msg = _M.MAVLink_command_long_message(self.sysid, self.compid, command, min(confirmation, 255), *p)
            self.endpoint.send(self.sysid, msg)
            wait_s = timeout_s
            while True:
                try:
                    ack = await wait_on_clock(queue.get(), wait_s, self.clock)
                except TimeoutError:
                    if wait_s != timeout_s:
                        return None  # IN_PROGRESS then silence: no resend (the spec says so)
                    break
                if ack.result != _IN_PROGRESS:
                    return ack.result
                wait_s = max(5.0 * timeout_s, 5.0)
        return None

    async def request_message(self, msg_id: int, timeout_s: float = 1.0) -> int:
        """MAV_CMD_REQUEST_MESSAGE for ``msg_id``; returns the MAV_RESULT (raises like command_long)."""
        return await self.command_long(_M.MAV_CMD_REQUEST_MESSAGE, msg_id, timeout_s=timeout_s)

    def request_heartbeat(self, min_interval_s: float = 0.5) -> bool:
        """Ask for an immediate HEARTBEAT (MAV_CMD_REQUEST_MESSAGE, not waited for, no retries).

        Corroborates a mode or armed change a single heartbeat reported
        (``VehicleLink.status_heartbeats``) without waiting a second for the next one. At
        most one request per ``min_interval_s`` clock seconds; returns True if one was sent.
        """
        now = self.clock.time()
        if now - self._heartbeat_request_s < min_interval_s:
            return False
        self._heartbeat_request_s = now
        msg = _M.MAVLink_command_long_message(self.sysid, self.compid, _M.MAV_CMD_REQUEST_MESSAGE, 0,
                                              float(_M.MAVLINK_MSG_ID_HEARTBEAT), 0, 0, 0, 0, 0, 0)
        return bool(self.endpoint.send(self.sysid, msg))

    async def request_autopilot_version(self, timeout_s: float = 3.0) -> int:
        """Ask for AUTOPILOT_VERSION and return its uid (also checked for duplicates by the endpoint).

        Falls back to MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES when REQUEST_MESSAGE is unsupported.
        """
        event = self._events["version"]
        event.clear()
        try:
            await self.request_message(_M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        except CommandError as exc:
            if exc.result != _M.MAV_RESULT_UNSUPPORTED:
                raise
            await self.command_long(_M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
        try:
            await wait_on_clock(event.wait(), timeout_s, self.clock)
        except TimeoutError:
            raise CommandError(f"{self._who()}: no AUTOPILOT_VERSION within {timeout_s:g} s",
                               sysid=self.sysid) from None
        self._raise_link_error()
        return int(self.uid)

    async def wait_home(self, timeout_s: float) -> tuple[float, float, float]:
        """Return the home ``(lat_deg, lon_deg, alt_m)``, requesting HOME_POSITION until it comes.

        Raises
        ------
        CommandError
            No HOME_POSITION within ``timeout_s`` clock seconds.
        """
        deadline = self.clock.time() + timeout_s
        event = self._events["home"]
        while self.state.home is None:
            remaining = deadline - self.clock.time()
            if remaining <= 0:
                raise CommandError(f"{self._who()}: no HOME_POSITION within {timeout_s:g} s", sysid=self.sysid)
            try:
                await self.command_long(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_HOME_POSITION,
                                        timeout_s=min(1.0, remaining), retries=0,
                                        accept=(_ACCEPTED, _M.MAV_RESULT_TEMPORARILY_REJECTED,
                                                _M.MAV_RESULT_DENIED, _M.MAV_RESULT_FAILED))
            except CommandError:
                pass
            try:
                await wait_on_clock(event.wait(), max(0.0, min(1.0, deadline - self.clock.time())), self.clock)
            except TimeoutError:
                pass
        return self.state.home

    async def set_message_rates(self, rates_hz: dict[str, float], *, strict: bool = True) -> dict[str, str]:
        """Set telemetry rates with MAV_CMD_SET_MESSAGE_INTERVAL (0 Hz stops a message).

        Parameters
        ----------
        rates_hz : dict of str to float
            Message name -> rate in Hz (e.g. :data:`DEFAULT_RATES_HZ`).
        strict : bool
            If True the first refusal raises; if False refusals are collected and returned.

        Returns
        -------
        dict of str to str
            Message name -> why it was refused (empty when all were accepted).

        Raises
        ------
        ValueError
            Unknown message name or negative rate (nothing is sent then).
        CommandError
            ``strict`` and the autopilot refused one or did not answer.
        """
        plan = []
        for name, rate_hz in rates_hz.items():
            msg_id = getattr(_M, f"MAVLINK_MSG_ID_{str(name).upper()}", None)
            if msg_id is None:
                raise ValueError(f"unknown MAVLink message {name!r}")
            if not rate_hz >= 0:
                raise ValueError(f"rate of {name} must be >= 0 Hz, got {rate_hz}")
            plan.append((str(name).upper(), msg_id, 1e6 / rate_hz if rate_hz > 0 else -1.0))
        refused = {}
        for name, msg_id, interval_us in plan:
            try:
                await self.command_long(_M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)
            except CommandError as exc:
                if strict:
                    raise
                refused[name] = str(exc)
        return refused

    async def set_mode(self, name: str) -> None:
        """Switch flight mode with MAV_CMD_DO_SET_MODE (aliases per flavour: see vehicle_frames).

        Raises
        ------
        CommandError
            Unknown mode for this flavour, or refused.
        """
        try:
            _, p2, p3 = resolve_mode(self.flavour, name)
        except ValueError as exc:
            raise CommandError(f"{self._who()}: {exc}", sysid=self.sysid) from None
        await self.command_long(_M.MAV_CMD_DO_SET_MODE, _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, p2, p3)

    async def arm(self) -> None:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM 1); returns when acknowledged."""
        await self.command_long(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    async def disarm(self, force: bool = False) -> None:
        """Disarm (``force`` uses the magic 21196 that disarms in flight)."""
        await self.command_long(_M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)
