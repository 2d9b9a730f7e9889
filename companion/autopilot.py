"""The autopilot's position over MAVLink, for a sensor riding on it (virtual or real).

Plain blocking pymavlink: :func:`open_mavlink` opens any pymavlink connection string,
:func:`wait_heartbeat` waits for the autopilot's heartbeat (sending the heartbeat
that ``udpout`` links and PX4 need), and :class:`PositionStream` reads the autopilot's
GLOBAL_POSITION_INT, asking for the rate it needs with MAV_CMD_SET_MESSAGE_INTERVAL until the
positions flow (again, after a silence), skipping the zeros an autopilot sends before its first
GPS fix.

The sensor's own heartbeat says *onboard controller* (MAV_TYPE_ONBOARD_CONTROLLER) from system id
:data:`COMPANION_SYSID`, never a ground station's: ArduPilot takes any heartbeat from system id
``MAV_GCS_SYSID`` (255) as its ground station's and PX4 any MAV_TYPE_GCS one, so a sensor sending
255 / GCS on the vehicle's second port kept the autopilot's ground-station-loss failsafe
(``FS_GCS_ENABLE``, ``NAV_DLL_ACT``) from ever firing: measured on ArduCopter SITL, a vehicle whose
ground-station link was cut hovered in GUIDED for good (docs/faults.md). :class:`AutopilotTelemetry` runs a stream on its own thread and keeps the latest fix
for :class:`companion.publisher.Publisher`; ``swarmseek sensor`` (:mod:`sitl_mock.virtual_sensor`)
reads a stream in its main loop.
"""
from __future__ import annotations

import argparse
import threading
import time
from dataclasses import dataclass
from typing import Callable

__all__ = ["AutopilotError", "AutopilotTelemetry", "PositionFix", "PositionStream", "close_mavlink",
           "connection_arg", "open_mavlink", "receive", "send_heartbeat", "sysid_arg", "wait_heartbeat",
           "COMPANION_SYSID"]

_MSG_ID_GLOBAL_POSITION_INT = 33
_MAV_CMD_SET_MESSAGE_INTERVAL = 511
_MAV_TYPE_GCS = 6
_MAV_TYPE_ONBOARD_CONTROLLER = 18
#: the sensor's MAVLink system id: not a ground station's (255, ArduPilot's ``MAV_GCS_SYSID``
#: default), not a vehicle's; component 158 (MAV_COMP_ID_PERIPHERAL)
COMPANION_SYSID = 254
_COMPANION_COMPID = 158
_MAV_AUTOPILOT_INVALID = 8
_HEARTBEAT_PERIOD_S = 1.0
_REREQUEST_PERIOD_S = 3.0
_SILENCE_WARN_S = 5.0
_NET_PREFIXES = ("tcp:", "tcpin:", "udp:", "udpin:", "udpout:", "udpbcast:")


class AutopilotError(RuntimeError):
    """The autopilot cannot be reached (no link, no heartbeat, link lost): a clear message."""


# ----------------------------------------------------------------------------- argument types
def sysid_arg(text: str) -> int:
    """argparse type of a MAVLink system id, 1..255."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= 255:
        raise argparse.ArgumentTypeError(f"a MAVLink system id is 1..255, got {text!r}")
    return v


def connection_arg(text: str) -> str:
    """argparse type of a pymavlink connection string (``tcp:HOST:PORT``, ``udpin:HOST:PORT``, a
    serial device, ...); network forms are checked here, the rest is left to pymavlink."""
    for prefix in _NET_PREFIXES:
        if text.startswith(prefix):
            host, sep, port = text[len(prefix):].rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
                raise argparse.ArgumentTypeError(
                    f"bad connection {text!r}: expected {prefix}HOST:PORT, e.g. tcp:127.0.0.1:5762")
            return text
    if not text or text.startswith("-"):
        raise argparse.ArgumentTypeError(f"bad connection {text!r}")
    return text  # serial device or another pymavlink form: pymavlink judges it


# ----------------------------------------------------------------------------- the link
def open_mavlink(connection: str, retries: int):
    """A pymavlink connection (source system :data:`COMPANION_SYSID`, component 158, reconnecting TCP).

    Raises
    ------
    AutopilotError
        When pymavlink cannot open it.
    """
    from pymavlink import mavutil

    try:
        return mavutil.mavlink_connection(connection, source_system=COMPANION_SYSID, source_component=_COMPANION_COMPID,
                                          autoreconnect=True, retries=retries, reconnect_delay=0.5)
    except (OSError, ValueError, ImportError) as exc:
        raise AutopilotError(f"cannot open MAVLink connection {connection!r}: {exc}") from None
    except Exception as exc:  # pymavlink raises assorted errors for odd device strings
        raise AutopilotError(
            f"cannot open MAVLink connection {connection!r}: {type(exc).__name__}: {exc}") from None


def close_mavlink(conn) -> None:
    """Close a connection of :func:`open_mavlink` (also one whose reconnection failed)."""
    if getattr(conn, "port", True) is None:
        return  # pymavlink's mavtcp.close() fails after a failed reconnect left no socket
    try:
        conn.close()
    except OSError:
        pass


def send_heartbeat(conn) -> None:
    """Send one HEARTBEAT of an onboard controller (not a ground station's: see the module's text)."""
    conn.mav.heartbeat_send(_MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID, 0, 0, 0)


def receive(conn, types, timeout_s: float):
    """The next message of one of ``types`` within ``timeout_s`` (None when none came).

    Raises
    ------
    AutopilotError
        When the link is lost.
    """
    try:
        return conn.recv_match(type=types, blocking=True, timeout=timeout_s)
    except OSError as exc:
        raise AutopilotError(f"lost the MAVLink connection: {exc}") from None


def wait_heartbeat(conn, sysid: int | None, timeout_s: float):
    """The first HEARTBEAT of an autopilot (of ``sysid``, or any when None), other ground
    stations ignored.

    Raises
    ------
    AutopilotError
        None within ``timeout_s``, or the link is lost.
    """
    deadline = time.monotonic() + timeout_s
    next_hb = 0.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_hb:
            send_heartbeat(conn)  # lets udpout links and PX4 know we are here
            next_hb = time.monotonic() + _HEARTBEAT_PERIOD_S
        msg = receive(conn, ["HEARTBEAT"], 0.2)
        if msg is None:
            continue
        if msg.type == _MAV_TYPE_GCS or msg.autopilot == _MAV_AUTOPILOT_INVALID:
            continue  # another ground station, not an autopilot
        if sysid is None or msg.get_srcSystem() == sysid:
            return msg
    who = "an autopilot" if sysid is None else f"autopilot sysid {sysid}"
    raise AutopilotError(f"no heartbeat from {who} within {timeout_s:g} s")


# ----------------------------------------------------------------------------- positions
@dataclass(frozen=True)
class PositionFix:
    """One GLOBAL_POSITION_INT of the autopilot with a GPS fix.

    Attributes
    ----------
    lat_deg, lon_deg : float
        WGS-84 latitude and longitude, degrees.
    alt_m : float
        Altitude above mean sea level, metres (GLOBAL_POSITION_INT ``alt``).
    received_s : float
        ``time.monotonic()`` when it was received.
    time_boot_ms : int
        The autopilot's time since boot in the message, milliseconds.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    received_s: float
    time_boot_ms: int


class PositionStream:
    """The GLOBAL_POSITION_INT of one autopilot on an open link, and the link's upkeep.

    Parameters
    ----------
    conn
        A connection of :func:`open_mavlink` on which the autopilot's heartbeat was seen.
    sysid, compid : int
        The autopilot's system and component ids.
    rate_hz : float
        The GLOBAL_POSITION_INT rate asked for (until positions flow, every 3 s).
    log : callable
        ``log(text)``: told when positions stop for 5 s, flow again, or lack a fix.

    Attributes
    ----------
    positions : int
        GLOBAL_POSITION_INT received from the autopilot (with or without a fix).
    no_fix : int
        Those with lat = lon = 0 (before the first GPS fix), not returned.
    """

    def __init__(self, conn, sysid: int, compid: int, rate_hz: float, log: Callable[[str], None]):
        self.conn, self.sysid, self.compid, self.rate_hz, self.log = conn, sysid, compid, rate_hz, log
        self.positions = self.no_fix = 0
        now = time.monotonic()
        self._next_hb = self._next_request = now
        self._last_position = now  # monotonic time of the last GLOBAL_POSITION_INT
        self._flowing = self._silent = False

    def _upkeep(self, now: float) -> None:
        if now >= self._next_hb:
            send_heartbeat(self.conn)
            self._next_hb = now + _HEARTBEAT_PERIOD_S
        if now - self._last_position > _SILENCE_WARN_S and not self._silent:
            self._silent, self._flowing = True, False  # ask again: the autopilot may have rebooted
            self.log(f"no GLOBAL_POSITION_INT from sysid {self.sysid} for {_SILENCE_WARN_S:g} s; still trying")
        if now >= self._next_request and not self._flowing:  # until positions flow, ask now and then
            self.conn.mav.command_long_send(self.sysid, self.compid, _MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                            _MSG_ID_GLOBAL_POSITION_INT, 1e6 / self.rate_hz, 0, 0, 0, 0, 0)
            self._next_request = now + _REREQUEST_PERIOD_S

    def next_fix(self, timeout_s: float) -> PositionFix | None:
        """Wait up to ``timeout_s`` for one message; the fix it carries, else None.

        Raises
        ------
        AutopilotError
            When the link is lost.
        """
        self._upkeep(time.monotonic())
        msg = receive(self.conn, ["GLOBAL_POSITION_INT"], timeout_s)
        if msg is None or msg.get_srcSystem() != self.sysid:
            return None
        self.positions += 1
        self._flowing, self._last_position = True, time.monotonic()
        if self._silent:
            self._silent = False
            self.log("positions flow again")
        if msg.lat == 0 and msg.lon == 0:
            self.no_fix += 1  # autopilots send zeros before their first GPS fix
            if self.no_fix == 1:
                self.log("autopilot has no position fix yet (lat = lon = 0); waiting")
            return None
        return PositionFix(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3, self._last_position,
                           int(msg.time_boot_ms))


class AutopilotTelemetry:
    """The latest position fix of one autopilot, read by a background thread.

    The constructor opens the link and waits for the autopilot's heartbeat; a daemon thread then
    reads a :class:`PositionStream` until :meth:`close`.

    Parameters
    ----------
    connection : str
        pymavlink connection string (``tcp:127.0.0.1:5760``, ``udpin:0.0.0.0:14550``,
        ``/dev/ttyAMA0,921600``, ...).
    sysid : int or None
        The autopilot's system id; None: the first autopilot heartbeat's.
    rate_hz : float
        GLOBAL_POSITION_INT rate asked for.
    heartbeat_timeout_s : float
        How long to wait for the heartbeat.
    retries : int
        TCP connection attempts.
    log : callable, optional
        ``log(text)`` for the stream's notices.

    Attributes
    ----------
    sysid : int
        The autopilot's system id.
    error : str or None
        Why the reading thread stopped (the link was lost), else None.

    Raises
    ------
    AutopilotError
        The link cannot be opened or no heartbeat came in time.
    """

    def __init__(self, connection: str, sysid: int | None = None, *, rate_hz: float = 10.0,
                 heartbeat_timeout_s: float = 30.0, retries: int = 3, log: Callable[[str], None] | None = None):
        self._conn = open_mavlink(connection, retries)
        try:
            hb = wait_heartbeat(self._conn, sysid, heartbeat_timeout_s)
        except BaseException:
            close_mavlink(self._conn)
            raise
        self.sysid = hb.get_srcSystem()
        self.stream = PositionStream(self._conn, self.sysid, hb.get_srcComponent(), rate_hz,
                                     log or (lambda _text: None))
        self.error: str | None = None
        self._latest: PositionFix | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"autopilot-{self.sysid}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                fix = self.stream.next_fix(0.05)
            except AutopilotError as exc:
                self.error = str(exc)
                return
            if fix is not None:
                with self._lock:
                    self._latest = fix

    def latest(self) -> PositionFix | None:
        """The newest fix received (None before the first)."""
        with self._lock:
            return self._latest

    def close(self) -> None:
        """Stop the thread and close the link (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        close_mavlink(self._conn)
