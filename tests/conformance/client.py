"""A plain-pymavlink client that records what one autopilot does (for the conformance script).

Deliberately independent of ``mission/``: the coordinator and the mock could share a
misunderstanding, so the conformance sequence talks MAVLink with nothing but pymavlink.
Blocking code (no asyncio). Times are the *autopilot's* clock (``time_boot_ms`` of its
telemetry), so a lagging SITL or a sped-up mock compare in simulated seconds.
"""
from __future__ import annotations

import logging
import os
import struct
import time
from collections import Counter
from dataclasses import dataclass, field

__all__ = ["Client", "ConformanceError", "Observation"]

_LOG = logging.getLogger("conformance")
_GCS_SYSID = 246
_GCS_COMPID = 190
_MAV_LANDED_STATE_ON_GROUND = 1
_MAV_LANDED_STATE_IN_AIR = 2
_ARMED_FLAG = 128
_INT_PARAM_TYPES = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}


class ConformanceError(RuntimeError):
    """The autopilot did not do what the script waits for (the message says what and where)."""


@dataclass
class Observation:
    """What the scripted sequence saw one autopilot do.

    Attributes
    ----------
    flavour : str
        ``"px4"`` or ``"ardupilot"``.
    acks : dict
        Step name -> COMMAND_ACK result (None: no ACK within the timeout).
    modes : dict
        Step name -> HEARTBEAT custom_mode seen after the step.
    custom_modes_seen : set
        Every HEARTBEAT custom_mode seen.
    params : dict
        Step name -> ``(param_id, value, param_type)`` of the PARAM_VALUE answer (None: none).
    message_counts : Counter
        Message type -> number received over the whole run.
    rates_hz : dict
        Message type -> rate over the rate window (per second of autopilot time).
    statustexts : list
        ``(step, severity, text)`` in order of arrival.
    events_s : dict
        ``armed``, ``airborne``, ``landed``, ``disarmed`` ... -> autopilot time (s) it was first seen.
    details : dict
        Per-step facts (mission round trip, setpoint approach, arm attempts).
    """

    flavour: str
    acks: dict = field(default_factory=dict)
    modes: dict = field(default_factory=dict)
    custom_modes_seen: set = field(default_factory=set)
    params: dict = field(default_factory=dict)
    message_counts: Counter = field(default_factory=Counter)
    rates_hz: dict = field(default_factory=dict)
    statustexts: list = field(default_factory=list)
    events_s: dict = field(default_factory=dict)
    details: dict = field(default_factory=dict)


class Client:
    """One pymavlink link to one autopilot (system id ``sysid``, component 1), recording everything.

    Parameters
    ----------
    uri : str
        pymavlink connection string (``udpin:...`` for PX4 SITL, ``tcp:...`` for ArduCopter).
    sysid : int
        The autopilot's system id.
    flavour : str
        ``"px4"`` or ``"ardupilot"``.
    wall_scale : float
        Multiplies every wall-clock timeout (a loaded host or a slow SITL).
    """

    def __init__(self, uri: str, sysid: int, flavour: str, wall_scale: float = 1.0):
        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink import (
            mavutil,  # after MAVLINK20: MAVLink 2 (mission_type, extensions)
        )
        self.mavutil = mavutil
        self.conn = mavutil.mavlink_connection(uri, source_system=_GCS_SYSID, source_component=_GCS_COMPID,
                                               dialect="ardupilotmega", autoreconnect=False)
        self.m = mavutil.mavlink
        self.sysid = int(sysid)
        self.obs = Observation(flavour=flavour)
        self.wall_scale = float(wall_scale)
        self._step = "connect"
        self.boot_s = 0.0
        self.last: dict = {}
        self.armed = False
        self.landed_state = 0
        self.custom_mode: int | None = None
        self._window: Counter | None = None
        self._next_heartbeat_wall_s = 0.0
        #: send the GCS HEARTBEAT once a wall second (False: a data-link loss as PX4 sees it)
        self.heartbeats = True
        self._chunks: dict[int, list[str]] = {}

    @property
    def step(self) -> str:
        """The script step now running (tags STATUSTEXTs and error messages)."""
        return self._step

    @step.setter
    def step(self, name: str) -> None:
        _LOG.info("%s: step %s at autopilot time %.1f s", self.obs.flavour, name, self.boot_s)
        self._step = name

    def close(self) -> None:
        """Close the link."""
        self.conn.close()

    # ------------------------------------------------------------------ receiving
    def _record(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA" or msg.get_srcSystem() != self.sysid or msg.get_srcComponent() != 1:
            return
        self.obs.message_counts[kind] += 1
        if self._window is not None:
            self._window[kind] += 1
        boot_ms = getattr(msg, "time_boot_ms", None)
        if isinstance(boot_ms, int) and boot_ms > 0:
            self.boot_s = max(self.boot_s, boot_ms / 1000.0)
        self.last[kind] = msg
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg)
        elif kind == "EXTENDED_SYS_STATE":
            if msg.landed_state != self.landed_state:
                self.event(f"landed_state_{msg.landed_state}")
            self.landed_state = msg.landed_state
            if msg.landed_state == _MAV_LANDED_STATE_IN_AIR:
                self.event("airborne")
            elif msg.landed_state == _MAV_LANDED_STATE_ON_GROUND and "airborne" in self.obs.events_s:
                self.event("landed")
        elif kind == "STATUSTEXT":
            self._on_statustext(msg)

    def _on_statustext(self, msg) -> None:
        """Record a STATUSTEXT; chunks of one long text (same non-zero ``id``) are joined first."""
        text = msg.text.rstrip("\x00")
        chunk_id = getattr(msg, "id", 0)
        if chunk_id:
            self._chunks.setdefault(chunk_id, []).append(text)
            if len(msg.text) == 50 and "\x00" not in msg.text:
                return  # more chunks follow
            text = "".join(self._chunks.pop(chunk_id))
        text = text.strip("\t ")
        if text:
            self.obs.statustexts.append((self.step, int(msg.severity), text))
            _LOG.info("%s: STATUSTEXT %s %r", self.obs.flavour, msg.severity, text)

    def _on_heartbeat(self, msg) -> None:
        if msg.autopilot == self.m.MAV_AUTOPILOT_INVALID:
            return
        self.custom_mode = int(msg.custom_mode)
        self.obs.custom_modes_seen.add(self.custom_mode)
        armed = bool(msg.base_mode & _ARMED_FLAG)
        if armed and not self.armed:
            self.event("armed")
        if self.armed and not armed:
            self.event("disarmed")
        self.armed = armed

    def event(self, name: str) -> None:
        """Note the autopilot time of ``name`` (first occurrence only)."""
        self.obs.events_s.setdefault(name, self.boot_s)

    def pump(self, wall_s: float, until=None):
        """Receive for up to ``wall_s`` wall seconds (scaled) or until ``until(msg)`` is true; return that msg."""
        deadline = time.monotonic() + wall_s * self.wall_scale
        while True:
            self._heartbeat()
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            msg = self.conn.recv_match(blocking=True, timeout=min(left, 0.1))
            if msg is None:
                continue
            self._record(msg)
            if until is not None and msg.get_srcSystem() == self.sysid and until(msg):
                return msg

    def _heartbeat(self) -> None:
        """A GCS HEARTBEAT once a wall second (PX4 refuses to arm without a GCS when NAV_DLL_ACT is set)."""
        now = time.monotonic()
        if self.heartbeats and now >= self._next_heartbeat_wall_s:
            self._next_heartbeat_wall_s = now + 1.0
            self.conn.mav.heartbeat_send(self.m.MAV_TYPE_GCS, self.m.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def settle(self, wall_s: float) -> None:
        """Receive (and record) for ``wall_s`` wall seconds, not scaled: a pause, not a timeout."""
        self.pump(wall_s / self.wall_scale)

    def wait(self, predicate, wall_s: float, what: str, *, kind: str | None = None):
        """Receive until ``predicate(msg)`` holds for a message (of type ``kind``), or raise."""
        def until(msg):
            return (kind is None or msg.get_type() == kind) and predicate(msg)
        msg = self.pump(wall_s, until)
        if msg is None:
            raise ConformanceError(f"step {self.step}: timed out after {wall_s * self.wall_scale:.0f} s "
                                   f"(wall) waiting for {what}")
        return msg

    def wait_state(self, predicate, wall_s: float, what: str) -> None:
        """Receive until ``predicate()`` (on the recorded state) holds, or raise."""
        self.wait(lambda msg: predicate(), wall_s, what)

    def window_rates(self, autopilot_s: float, wall_s: float) -> dict:
        """Message rates (per autopilot second) over a window of ``autopilot_s`` autopilot seconds."""
        self.settle(0.3)
        self._window = Counter()
        start = self.boot_s
        self.wait_state(lambda: self.boot_s - start >= autopilot_s, wall_s, "the rate window")
        span = self.boot_s - start
        counts, self._window = self._window, None
        return {kind: round(n / span, 2) for kind, n in sorted(counts.items())}

    # ------------------------------------------------------------------ sending
    def command(self, name: str, command: int, *params: float, wall_s: float = 5.0, tries: int = 3):
        """COMMAND_LONG; record and return the COMMAND_ACK result under ``name`` (None: no ACK)."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        result = None
        for attempt in range(tries):
            self.conn.mav.command_long_send(self.sysid, 1, command, attempt, *p)
            ack = self.pump(wall_s / tries, lambda msg: msg.get_type() == "COMMAND_ACK" and msg.command == command
                            and msg.result != self.m.MAV_RESULT_IN_PROGRESS)
            if ack is not None:
                result = int(ack.result)
                break
        self.obs.acks[name] = result
        return result

    def set_mode(self, name: str, p2: int, p3: int = 0, **kw):
        """MAV_CMD_DO_SET_MODE with the custom-mode flag; returns the ACK result."""
        return self.command(name, self.m.MAV_CMD_DO_SET_MODE, self.m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                            p2, p3, **kw)

    def wait_mode(self, name: str, custom_mode: int, wall_s: float) -> None:
        """Wait for a HEARTBEAT with ``custom_mode`` and record it under ``name``."""
        self.wait(lambda msg: msg.custom_mode == custom_mode and msg.autopilot != self.m.MAV_AUTOPILOT_INVALID,
                  wall_s, f"custom_mode {custom_mode}", kind="HEARTBEAT")
        self.obs.modes[name] = custom_mode

    def read_param(self, name: str | None, param_id: str, wall_s: float = 4.0, *, scaled: bool = True):
        """PARAM_REQUEST_READ by name; record ``(id, value, type)`` or None under ``name`` (if given)."""
        answer = None
        for _ in range(2):
            self.conn.mav.param_request_read_send(self.sysid, 1, param_id.encode(), -1)
            msg = self.pump(wall_s / 2 / (1.0 if scaled else self.wall_scale), lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == param_id)
            if msg is not None:
                answer = self._param_answer(msg)
                break
        if name is not None:
            self.obs.params[name] = answer
        return answer

    def set_param(self, name: str, param_id: str, value: float, param_type: int, wall_s: float = 4.0):
        """PARAM_SET; record the PARAM_VALUE echo (None: none) under ``name``."""
        self.conn.mav.param_set_send(self.sysid, 1, param_id.encode(), float(value), param_type)
        msg = self.pump(wall_s, lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == param_id)
        answer = None if msg is None else self._param_answer(msg)
        self.obs.params[name] = answer
        return answer

    def connect(self, rates_hz: dict[str, float], heartbeat_wall_s: float, position_wall_s: float) -> None:
        """Step ``connect``: wait for the autopilot's HEARTBEAT, ask for each message of ``rates_hz``
        (name -> Hz) at its rate, wait for a local position and a home."""
        self.step = "connect"
        self.wait(lambda m: m.get_srcComponent() == 1 and m.autopilot != self.m.MAV_AUTOPILOT_INVALID,
                  heartbeat_wall_s, "the autopilot HEARTBEAT", kind="HEARTBEAT")
        for name, rate_hz in rates_hz.items():
            self.command(f"interval_{name}", self.m.MAV_CMD_SET_MESSAGE_INTERVAL,
                         getattr(self.m, f"MAVLINK_MSG_ID_{name}"), 1e6 / rate_hz)
        self.wait_state(lambda: "LOCAL_POSITION_NED" in self.last and "HOME_POSITION" in self.last,
                        position_wall_s, "a local position and a home")

    def arm(self, attempts: int = 61, pause_wall_s: float = 2.0) -> None:
        """Arm, retried every ``pause_wall_s`` while the pre-arm checks refuse; raise after ``attempts``."""
        for attempt in range(attempts):
            if self.command("arm", self.m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == self.m.MAV_RESULT_ACCEPTED:
                return
            if attempt == attempts - 1:
                raise ConformanceError(f"step {self.step}: arming refused: {self.obs.statustexts[-3:]}")
            self.settle(pause_wall_s)

    def rel_alt_m(self) -> float:
        """Height above home (m) from LOCAL_POSITION_NED and HOME_POSITION (-1 before both)."""
        lp, home = self.last.get("LOCAL_POSITION_NED"), self.last.get("HOME_POSITION")
        return -1.0 if lp is None or home is None else home.z - lp.z

    def _param_answer(self, msg) -> tuple:
        """``(id, value, type)``; integer values decoded bytewise (PX4) or cast (ArduPilot)."""
        value, ptype = float(msg.param_value), int(msg.param_type)
        if self.obs.flavour == "px4" and ptype in _INT_PARAM_TYPES:
            raw = struct.pack("<f", value)
            value = struct.unpack(_INT_PARAM_TYPES[ptype], raw[:struct.calcsize(_INT_PARAM_TYPES[ptype])])[0]
        return msg.param_id, round(value, 4), ptype

    def send_local_target(self, north_m: float, east_m: float, down_m: float) -> None:
        """One SET_POSITION_TARGET_LOCAL_NED (position only, LOCAL_NED)."""
        mask = 0x1F8 | 0x400 | 0x800  # ignore velocity, acceleration, yaw and yaw rate
        self.conn.mav.set_position_target_local_ned_send(int(self.boot_s * 1000) & 0xFFFFFFFF, self.sysid, 1,
                                                         self.m.MAV_FRAME_LOCAL_NED, mask, north_m, east_m,
                                                         down_m, 0, 0, 0, 0, 0, 0, 0, 0)
