"""Support of the ``swarmseek publish`` tests: a mock autopilot, a ground station's reading
store on a real zenoh session, and an autopilot that never gets a GPS fix."""
from __future__ import annotations

import contextlib
import os
import socket
import threading

import numpy as np
import zenoh
from pymavlink.dialects.v20 import common as mavlink2

import sitl_mock.fleet as fleet_mod
from mission.core.clock import WallClock
from mission.telemetry.readings import ReadingStore, ReadingSubscriber
from wire.zenoh_config import zenoh_config

ORIGIN = (45.19, 5.72, 230.0)
HOME_ENU = np.array([12.0, -7.0, 0.0])


def free_tcp_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def mock_autopilot(fleet_name: str, personality: str = "ardupilot"):
    """One mock vehicle (sysid 1) parked at ``HOME_ENU``, MAVLink on TCP; yields its connection string."""
    fleet = fleet_mod.MockFleet(n=1, personality=personality, field=None, origin=ORIGIN,
                                home_offsets_enu=HOME_ENU[None, :], udp_base_port=0, udp_bind_base_port=0,
                                tcp_base_port=free_tcp_port(), fleet_name=fleet_name, zenoh=False)
    fleet.start()
    try:
        yield fleet, f"tcp:127.0.0.1:{fleet.vehicles[0].tcp_port}"
    finally:
        fleet.stop()
    assert not fleet.errors


@contextlib.contextmanager
def ground_station(fleet_name: str, sysids=(1,)):
    """The ground station's reading store and subscriber on a zenoh session listening on its own
    127.0.0.1 port; yields ``(store, endpoint, payloads)``, ``payloads`` the raw ``(key, bytes)``
    received (a second subscriber). The store judges lateness on the wall clock and positions
    against the mock vehicle's home (10 m, the plan's default)."""
    port = free_tcp_port()
    session = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{port}"))
    store = ReadingStore(fleet_name, sysids, ORIGIN, WallClock(), telemetry_position=lambda _sysid: HOME_ENU)
    sub = ReadingSubscriber(session, store)
    payloads: list = []
    raw = session.declare_subscriber(f"swarmseek/{fleet_name}/vehicle/*/sensor",
                                     lambda s: payloads.append((str(s.key_expr), s.payload.to_bytes())))
    try:
        yield store, f"tcp/127.0.0.1:{port}", payloads
    finally:
        raw.undeclare()
        sub.close()
        session.close()


class NoFixAutopilot:
    """A TCP MAVLink server that sends HEARTBEAT and GLOBAL_POSITION_INT with lat = lon = 0 (an
    autopilot before its first GPS fix) every 0.05 s, to every client, until closed."""

    def __init__(self, sysid: int = 5):
        self.sysid = sysid
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(2)
        self.sock.settimeout(0.2)
        self.connection = f"tcp:127.0.0.1:{self.sock.getsockname()[1]}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self) -> "NoFixAutopilot":
        self._thread.start()
        return self

    def __exit__(self, *_exc) -> None:
        self._stop.set()
        self._thread.join(10.0)
        self.sock.close()

    def _serve(self) -> None:
        out = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        while not self._stop.is_set():
            try:
                client, _ = self.sock.accept()
            except OSError:
                continue
            with client:
                tick = 0
                while not self._stop.wait(0.05):
                    frames = out.heartbeat_encode(2, 3, 0, 4, 4).pack(out)
                    frames += out.global_position_int_encode(tick * 50, 0, 0, 0, 0, 0, 0, 0, 0).pack(out)
                    tick += 1
                    try:
                        client.sendall(frames)
                    except OSError:
                        break


class LineSensor:
    """Writes ``0.5``, ``1.5``, ... (CR LF ended, through ``line_format``) into a pseudo terminal's
    master side at about 10 lines a second until stopped: a sensor that prints one reading a line."""

    def __init__(self, master: int, line_format: str = "{}"):
        self.master, self.written, self.line_format = master, [], line_format
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.1) and len(self.written) < 600:
            self.written.append(0.5 + len(self.written))
            os.write(self.master, (self.line_format.format(self.written[-1]) + "\r\n").encode())

    def __enter__(self) -> "LineSensor":
        self._thread.start()
        return self

    def __exit__(self, *_exc) -> None:
        self._stop.set()
        self._thread.join(60.0)
