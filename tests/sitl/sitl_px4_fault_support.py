"""Fixtures of the PX4 SIH fault tests (``tests/sitl/test_sitl_faults_px4.py``): a UDP relay that can cut
one vehicle's link both ways, a listener on PX4's own GCS link (what the autopilots say, heard
beside the ground station, not through it), and a ``swarmseek fly`` mission run step by step so
that faults can be injected at seek iterations.

Every process and thread started here is stopped by the context managers' exits, pass or fail.
"""
from __future__ import annotations

import json
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from pymavlink import mavutil

from mission.sim.sitl_mission import sensor_argv
from mission.sim.sitl_procs import stop_groups

__all__ = ["UdpRelay", "GcsListener", "FlyRun", "free_udp_port", "log_records"]

_ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class UdpRelay:
    """Relay between a PX4 API link and the ground station, with a switch that cuts it both ways.

    PX4 sends from ``127.0.0.1:14580+i+K`` to ``127.0.0.1:vehicle_port`` (14540+i+K): the relay binds
    that port, forwards to the ground station's ``udpin`` port ``gcs_port`` from a socket of its own,
    and sends the ground station's frames back to the address PX4 sent from. It runs in its own
    process (``python tests/sitl/sitl_px4_fault_support.py VEHICLE_PORT GCS_PORT``): a thread of the test
    process, sharing its interpreter with the log polling, stalled for over 1 s on a loaded host
    and the ground station lost the vehicle before any cut. SIGUSR1 cuts (every datagram either way
    dropped, counted), SIGUSR2 restores; on SIGTERM it prints its counts as JSON and exits.

    Parameters
    ----------
    vehicle_port : int
        The port PX4 sends its API link to.
    gcs_port : int
        The port the plan's ``udpin:127.0.0.1:PORT`` makes the ground station listen on.
    """

    def __init__(self, vehicle_port: int, gcs_port: int):
        self.vehicle_port, self.gcs_port = vehicle_port, gcs_port
        self.proc: subprocess.Popen | None = None
        self.counts: dict = {}

    def __enter__(self) -> UdpRelay:
        self.proc = subprocess.Popen([sys.executable, __file__, str(self.vehicle_port), str(self.gcs_port)],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        line = self.proc.stdout.readline()
        if line.strip() != "ready":
            self.close()
            raise RuntimeError(f"relay did not start: {line.strip()} {self.proc.stderr.read()[-500:]}")
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def cut(self, on: bool) -> None:
        """Cut (True) or restore (False) the link both ways."""
        self.proc.send_signal(signal.SIGUSR1 if on else signal.SIGUSR2)

    def close(self) -> None:
        """Stop the relay process and keep its counts (:attr:`counts`: forwarded, dropped)."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.terminate()
        try:  # generous: at load average 30 its counts did not come within 5 s
            out, _ = self.proc.communicate(timeout=30.0)
        except subprocess.TimeoutExpired:
            stop_groups([self.proc])
            out = ""
        for line in (out or "").splitlines():
            if line.startswith("{"):
                self.counts = json.loads(line)
        self.proc = None


def _relay_main(vehicle_port: int, gcs_port: int) -> None:
    """The relay process (see :class:`UdpRelay`)."""
    state = {"cut": False, "stop": False}
    counts = {"forwarded": {"up": 0, "down": 0}, "dropped": {"up": 0, "down": 0}}
    signal.signal(signal.SIGUSR1, lambda *_: state.update(cut=True))
    signal.signal(signal.SIGUSR2, lambda *_: state.update(cut=False))
    signal.signal(signal.SIGTERM, lambda *_: state.update(stop=True))
    vside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        vside.bind(("127.0.0.1", vehicle_port))
    except OSError as exc:
        print(f"cannot bind the vehicle side 127.0.0.1:{vehicle_port}: {exc}", flush=True)
        return
    gside.bind(("127.0.0.1", 0))
    print("ready", flush=True)
    vehicle_addr = None
    while not state["stop"]:
        try:
            ready, _, _ = select.select([vside, gside], [], [], 0.1)
        except InterruptedError:
            continue
        for sock in ready:
            try:
                data, addr = sock.recvfrom(65535)
            except OSError:
                continue
            if sock is vside:
                vehicle_addr, way, out, dest = addr, "down", gside, ("127.0.0.1", gcs_port)
            elif vehicle_addr is not None:
                way, out, dest = "up", vside, vehicle_addr
            else:
                continue
            if state["cut"]:
                counts["dropped"][way] += 1
                continue
            try:
                out.sendto(data, dest)
                counts["forwarded"][way] += 1
            except OSError:
                counts["dropped"][way] += 1
    print(json.dumps(counts), flush=True)


class GcsListener:
    """Everything the fleet's autopilots say on PX4's GCS link (``127.0.0.1:14550+K``), in a thread.

    Records ``(time.time(), sysid, mode, armed)`` at each mode or arming change and keeps the
    latest ``armed``, ``landed_state``, ``alt`` (relative, m) and mode of each vehicle. Nothing is
    sent (no heartbeat): PX4's data-link-loss timer hears only the ground station.
    """

    def __init__(self, port: int, sysids):
        self._conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=253)
        self.latest: dict = {s: {} for s in sysids}
        self.changes: list[tuple[float, int, str, bool]] = []
        self.alt_track: dict = {s: [] for s in sysids}
        self.landed_track: dict = {s: [] for s in sysids}
        self.battery_track: dict = {s: [] for s in sysids}
        self.texts: list[tuple[float, int, str]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gcs-listener", daemon=True)

    def __enter__(self) -> GcsListener:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._conn.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._conn.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT", "EXTENDED_SYS_STATE",
                                              "SYS_STATUS", "STATUSTEXT"], blocking=True, timeout=0.2)
            if msg is None or msg.get_srcSystem() not in self.latest or msg.get_srcComponent() != 1:
                continue
            with self._lock:
                self._record(msg)

    def _record(self, msg) -> None:
        s = msg.get_srcSystem()
        state = self.latest[s]
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            mode, armed = mavutil.mode_string_v10(msg), bool(msg.base_mode & 128)
            if (state.get("mode"), state.get("armed")) != (mode, armed):
                self.changes.append((time.time(), s, mode, armed))
            state.update(mode=mode, armed=armed, heard=time.time())
        elif kind == "SYS_STATUS":
            if state.get("battery_pct") != msg.battery_remaining:
                self.battery_track[s].append((time.time(), msg.battery_remaining))
            state["battery_pct"] = msg.battery_remaining
        elif kind == "STATUSTEXT":
            self.texts.append((time.time(), s, msg.text.rstrip("\x00")))
        elif kind == "EXTENDED_SYS_STATE":
            if state.get("landed_state") != msg.landed_state:
                self.landed_track[s].append((time.time(), msg.landed_state))
            state["landed_state"] = msg.landed_state
        else:
            state["alt"] = msg.relative_alt / 1000.0
            self.alt_track[s].append((time.time(), state["alt"]))

    def state(self, sysid: int) -> dict:
        """A copy of the latest state of ``sysid``."""
        with self._lock:
            return dict(self.latest[sysid])

    def modes(self, sysid: int, since: float = 0.0) -> list[tuple[float, str, bool]]:
        """``(time, mode, armed)`` changes of ``sysid`` from ``since`` (time.time()) on."""
        with self._lock:
            return [(t, m, a) for t, s, m, a in self.changes if s == sysid and t >= since]

    def alts(self, sysid: int, since: float = 0.0) -> list[tuple[float, float]]:
        """``(time, relative altitude m)`` of ``sysid`` heard from ``since`` (time.time()) on."""
        with self._lock:
            return [(t, a) for t, a in self.alt_track[sysid] if t >= since]

    def landed_states(self, sysid: int, since: float = 0.0) -> list[tuple[float, int]]:
        """``(time, MAV_LANDED_STATE)`` changes of ``sysid`` from ``since`` (time.time()) on."""
        with self._lock:
            return [(t, x) for t, x in self.landed_track[sysid] if t >= since]

    def batteries(self, sysid: int, since: float = 0.0) -> list[tuple[float, int]]:
        """``(time, battery %)`` changes of ``sysid`` (SYS_STATUS) from ``since`` on."""
        with self._lock:
            return [(t, b) for t, b in self.battery_track[sysid] if t >= since]

    def statustexts(self, sysid: int, since: float = 0.0) -> list[tuple[float, str]]:
        """``(time, text)`` of ``sysid``'s STATUSTEXTs from ``since`` on."""
        with self._lock:
            return [(t, x) for t, s, x in self.texts if s == sysid and t >= since]

    def wait(self, predicate, timeout_s: float, what: str) -> None:
        """Poll ``predicate(self)`` every 0.2 s until truthy; fail naming ``what`` and every
        vehicle's latest state after ``timeout_s`` wall seconds."""
        deadline = time.monotonic() + timeout_s
        while not predicate(self):
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}: "
                                     f"{ {s: self.state(s) for s in self.latest} }")
            time.sleep(0.2)

    def down(self, sysid: int) -> bool:
        """PX4 says the vehicle is disarmed and its land detector says on the ground."""
        st = self.state(sysid)
        return st.get("armed") is False and st.get("landed_state") == _ON_GROUND and "alt" in st


def log_records(log: Path) -> list[dict]:
    """The mission log's records read so far (a partly written last line is left out)."""
    out = []
    try:
        text = log.read_text()
    except FileNotFoundError:
        return out
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


class FlyRun:
    """One ``swarmseek sensor`` per vehicle and ``swarmseek fly``, each in its own session.

    Parameters
    ----------
    fleet : mission.sim.sitl_fleet.SitlFleet
        The running fleet.
    plan, log_dir : Path
        The plan and ``fly --log-dir``.
    source : tuple of float
        The sensors' sigma_2 source, mission ENU metres.
    zenoh : str
        The plan's coordinator endpoint.
    noise : float
        The sensors' noise.
    """

    def __init__(self, fleet, plan: Path, log_dir: Path, source, *, zenoh: str, noise: float = 0.005):
        self.fleet, self.plan, self.log_dir = fleet, plan, log_dir
        self.source, self.zenoh, self.noise = source, zenoh, noise
        self.log = log_dir / "mission.jsonl"
        self.sensors: list[subprocess.Popen] = []
        self.fly: subprocess.Popen | None = None
        self.started = 0.0
        self._offset = 0
        self._records: list[dict] = []

    def __enter__(self) -> FlyRun:
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _start(self) -> None:
        fleet = self.fleet
        rate_hz = min(10.0 * fleet.config.speedup, 40.0)
        for v in fleet.vehicles:
            with open(self.log_dir.parent / f"sensor-{v.sysid}.log", "wb") as err:
                self.sensors.append(subprocess.Popen(
                    sensor_argv(v, fleet.origin, self.source, fleet="sitl", zenoh=self.zenoh, noise=self.noise,
                                rate_hz=rate_hz), stdout=err, stderr=subprocess.STDOUT, start_new_session=True))
        self.started = time.monotonic()
        with open(self.log_dir.with_suffix(".stdout"), "wb") as out, \
                open(self.log_dir.with_suffix(".stderr"), "wb") as err:
            self.fly = subprocess.Popen([sys.executable, "-m", "mission", "fly", "--plan", str(self.plan),
                                         "--log-dir", str(self.log_dir)], stdout=out, stderr=err,
                                        start_new_session=True)

    def stop(self) -> None:
        """Stop ``fly`` (if still running) and every sensor; reap them all."""
        stop_groups(([self.fly] if self.fly is not None else []) + self.sensors)

    def records(self, kind: str | None = None) -> list[dict]:
        """The mission log's records (of type ``kind``), read on from where the last call stopped."""
        try:
            with open(self.log, "rb") as f:
                f.seek(self._offset)
                chunk = f.read()
        except FileNotFoundError:
            chunk = b""
        end = chunk.rfind(b"\n") + 1  # a partly written last line waits for the next call
        for line in chunk[:end].splitlines():
            try:
                self._records.append(json.loads(line))
            except ValueError:
                continue
        self._offset += end
        return [r for r in self._records if kind is None or r.get("type") == kind]

    def wait_for(self, predicate, timeout_s: float, what: str):
        """Poll ``predicate(records)`` until truthy; fail with ``what`` and the output on a timeout or
        when ``fly`` has ended first."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = predicate(self.records())
            if value:
                return value
            if self.fly.poll() is not None:
                raise AssertionError(f"fly ended (exit {self.fly.returncode}) before {what}:\n{self.output()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}:\n{self.output()}")
            time.sleep(0.2)

    def wait_end(self, timeout_s: float) -> int:
        """``fly``'s exit status; killed (its group) after ``timeout_s``, then the assertion fails."""
        try:
            return self.fly.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.stop()
            raise AssertionError(f"fly still running after {timeout_s} s:\n{self.output()}") from None

    def output(self) -> str:
        """The tails of ``fly``'s standard output and error."""
        out = self.log_dir.with_suffix(".stdout").read_text(errors="replace")[-2500:]
        err = self.log_dir.with_suffix(".stderr").read_text(errors="replace")[-2500:]
        return f"--- stdout\n{out}\n--- stderr\n{err}"

    def summary(self) -> dict | None:
        """The log's ``summary`` record."""
        found = self.records("summary")
        return found[-1] if found else None


if __name__ == "__main__":
    _relay_main(int(sys.argv[1]), int(sys.argv[2]))
