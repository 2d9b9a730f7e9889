"""Helpers of tests/sitl/test_sitl_faults_ardupilot.py: watch a real ArduCopter SITL vehicle on its own
MAVLink port (not the ground station's) and change its parameters there, mid-mission.

:class:`VehicleWatch` connects to a spare SERIAL port of one SITL instance (SERIAL2, the port
:class:`mission.sim.sitl_fleet.SitlFleet` only used to see it ready) with a system id that is not
a ground station's (252, so it never feeds ArduCopter's GCS failsafe), and in a thread records
every HEARTBEAT (wall time ``time.time()``, custom mode, armed) and the relative altitude; it sets
parameters (PARAM_SET, resent until the PARAM_VALUE echo). Also: the mission log read while it
is written, and stopping processes for sure.
"""
from __future__ import annotations

import subprocess
import threading
import time

from tests.support.wait_helpers import wait_until

__all__ = ["COPTER_MODES", "VehicleWatch", "stop_procs", "watch_connection"]

#: ArduCopter custom modes met here
COPTER_MODES = {0: "STABILIZE", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL", 9: "LAND", 17: "BRAKE",
                21: "SMART_RTL"}


def watch_connection(sensor_connection: str) -> str:
    """The instance's SERIAL2 (``tcp:host:port + 1`` of the sensor's SERIAL1 connection)."""
    scheme, host, port = sensor_connection.split(":")
    return f"{scheme}:{host}:{int(port) + 1}"


def _port_closed() -> None:
    raise ConnectionResetError("the autopilot closed its port")


class VehicleWatch:
    """One vehicle seen from its own MAVLink port; a context manager (thread and link closed).

    Attributes
    ----------
    modes : list of tuple
        ``(time.time(), custom_mode, armed)`` of every HEARTBEAT of the autopilot.
    rel_alt_m : float or None
        The last altitude above home (GLOBAL_POSITION_INT).
    """

    def __init__(self, connection: str, sysid: int):
        from pymavlink import mavutil

        self.sysid = sysid
        self.conn = mavutil.mavlink_connection(connection, source_system=252, source_component=190,
                                               autoreconnect=False, retries=3)
        # pymavlink answers a closed TCP port by printing "EOF on TCP socket" and reconnecting, which
        # fails at once when the autopilot is dead: millions of lines and a core spinning. A closed port
        # ends the watch instead (its thread returns on OSError).
        self.conn.handle_eof = self.conn.handle_disconnect = _port_closed
        self.modes: list[tuple[float, int, bool]] = []
        self.rel_alt_m: float | None = None
        self.params: dict[str, float] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        #: set when the autopilot's port closed (its process is gone)
        self.port_closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"watch-{sysid}", daemon=True)

    def __enter__(self) -> VehicleWatch:
        self._thread.start()
        self._ask_position()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=10)
        self.conn.close()

    def _ask_position(self) -> None:
        # MAV_CMD_SET_MESSAGE_INTERVAL (511): GLOBAL_POSITION_INT (33) at 5 Hz on this port only
        self.conn.mav.command_long_send(self.sysid, 1, 511, 0, 33, 200000, 0, 0, 0, 0, 0)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT", "PARAM_VALUE"],
                                           blocking=True, timeout=0.5)
            except OSError:
                self.port_closed.set()
                return  # the instance is gone (the fleet stopped)
            if msg is None or msg.get_srcSystem() != self.sysid or msg.get_srcComponent() != 1:
                continue
            kind = msg.get_type()
            with self._lock:
                if kind == "HEARTBEAT":
                    self.modes.append((time.time(), int(msg.custom_mode), bool(msg.base_mode & 128)))
                elif kind == "GLOBAL_POSITION_INT":
                    self.rel_alt_m = msg.relative_alt / 1000.0
                else:
                    self.params[msg.param_id] = float(msg.param_value)

    def set_param(self, name: str, value: float, timeout_s: float = 20.0) -> float:
        """PARAM_SET ``name`` (REAL32) until the vehicle echoes it; returns ``time.time()`` of the send."""
        sent = [0.0]

        def echoed() -> bool:
            with self._lock:
                got = self.params.get(name)
            if got is not None and abs(got - value) < 1e-3:
                return True
            if time.monotonic() - sent[0] > 1.0:
                sent[0] = time.monotonic()
                self.conn.mav.param_set_send(self.sysid, 1, name.encode(), float(value), 9)
            return False

        t = time.time()
        wait_until(echoed, timeout_s, f"vehicle {self.sysid} to take {name} = {value}", poll_s=0.05)
        return t

    def send_param(self, name: str, value: float) -> float:
        """One PARAM_SET of ``name`` (REAL32), not waiting for its echo (a starved watch may miss
        it: check the parameter's effect instead); returns ``time.time()`` of the send."""
        self.conn.mav.param_set_send(self.sysid, 1, name.encode(), float(value), 9)
        return time.time()

    def snapshot(self) -> tuple[list[tuple[float, int, bool]], float | None]:
        """A copy of (:attr:`modes`, :attr:`rel_alt_m`)."""
        with self._lock:
            return list(self.modes), self.rel_alt_m

    def first_mode_after(self, t0: float, modes: set[int]) -> float | None:
        """``time.time()`` of the first heartbeat at or after ``t0`` in one of ``modes``."""
        return next((t for t, m, _ in self.snapshot()[0] if t >= t0 and m in modes), None)

    def down(self) -> bool:
        """Disarmed, below 1 m above home."""
        modes, alt = self.snapshot()
        return bool(modes) and not modes[-1][2] and alt is not None and abs(alt) < 1.0


def stop_procs(procs) -> None:
    """SIGTERM every process still running, then SIGKILL the ones that do not exit; reap all."""
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)
