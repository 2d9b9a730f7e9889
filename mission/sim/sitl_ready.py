"""Waiting until real SITL instances are ready: heartbeat received and position known.

Each instance's ``ready_connection`` (PX4: the GCS link every instance sends to; ArduCopter: its
SERIAL2 TCP port) is opened by the launcher only while it waits, then closed, so the ground
station and the sensors find their own links untouched. An instance is ready when its
autopilot heartbeat (component 1) and a GLOBAL_POSITION_INT with a non-zero position have been
received. Blocking code, for the launcher's thread (no asyncio loop).
"""
from __future__ import annotations

import select
import time
from collections.abc import Callable

from pymavlink import mavutil

from mission.sim.sitl_settings import SitlSetupError

__all__ = ["wait_ready"]

_MSG_GLOBAL_POSITION_INT = 33
_MAV_CMD_SET_MESSAGE_INTERVAL = 511
_MAV_AUTOPILOT_INVALID = 8
_LAUNCHER_SYSID = 253
_REQUEST_PERIOD_S = 2.0


def _open(uri: str, deadline_s: float, check_alive: Callable[[], None]):
    """Open a pymavlink connection; TCP is retried until the instance accepts or time runs out."""
    while True:
        try:
            return mavutil.mavlink_connection(uri, source_system=_LAUNCHER_SYSID, source_component=190,
                                              autoreconnect=False, retries=0)
        except OSError:
            check_alive()
            if time.monotonic() > deadline_s:
                raise SitlSetupError(f"SITL link {uri} did not accept a connection") from None
            select.select([], [], [], 0.2)


def _request_streams(conn, sysids) -> None:
    """Ask for position messages (ArduPilot sends nothing on a serial port until asked)."""
    for sysid in sysids:
        conn.mav.request_data_stream_send(sysid, 1, mavutil.mavlink.MAV_DATA_STREAM_ALL, 4, 1)
        conn.mav.command_long_send(sysid, 1, _MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                   _MSG_GLOBAL_POSITION_INT, 250000, 0, 0, 0, 0, 0)


def _note(msg, wanted: dict[int, dict]) -> None:
    """Record what ``msg`` tells about a wanted system id."""
    state = wanted.get(msg.get_srcSystem())
    if state is None or msg.get_srcComponent() != 1:
        return
    kind = msg.get_type()
    if kind == "HEARTBEAT" and msg.autopilot != _MAV_AUTOPILOT_INVALID:
        state["heartbeat"] = True
    elif kind == "GLOBAL_POSITION_INT" and (msg.lat != 0 or msg.lon != 0):
        state["position"] = True


def wait_ready(groups: dict[str, list[int]], *, timeout_s: float, check_alive: Callable[[], None],
               request_streams: bool) -> None:
    """Block until every system id has sent a heartbeat and a known position.

    Parameters
    ----------
    groups : dict
        Readiness connection string -> the system ids heard on it.
    timeout_s : float
        Give up after this long (wall seconds).
    check_alive : callable
        Raises :class:`SitlSetupError` when an instance's process has died; called while waiting.
    request_streams : bool
        Ask each system id for its position messages (ArduPilot) instead of waiting for them.

    Raises
    ------
    SitlSetupError
        A process died, or the timeout passed: the message lists what each late instance lacks.
    """
    deadline = time.monotonic() + timeout_s
    states = {sysid: {"heartbeat": False, "position": False} for ids in groups.values() for sysid in ids}
    conns = []
    try:
        for uri, ids in groups.items():
            conns.append((_open(uri, deadline, check_alive), ids))
        last_request = -1e9
        while not all(s["heartbeat"] and s["position"] for s in states.values()):
            check_alive()
            now = time.monotonic()
            if now > deadline:
                late = {sid: [k for k, ok in s.items() if not ok] for sid, s in states.items()
                        if not all(s.values())}
                raise SitlSetupError(f"SITL not ready after {timeout_s:.0f} s; missing per system id: {late}")
            if request_streams and now - last_request > _REQUEST_PERIOD_S:
                for conn, ids in conns:
                    _request_streams(conn, ids)
                last_request = now
            readable, _, _ = select.select([c.fd for c, _ in conns], [], [], 0.2)
            for conn, _ids in conns:
                if conn.fd not in readable:
                    continue
                for _ in range(500):
                    msg = conn.recv_msg()
                    if msg is None:
                        break
                    _note(msg, states)
    finally:
        for conn, _ in conns:
            conn.close()
