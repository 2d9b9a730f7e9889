"""``swarmseek publish`` end to end: a line sensor on a pseudo terminal, the mock autopilot's
position, the ground station's reading store on a real zenoh session; and its standard input,
its counts and its errors."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import zenoh

from companion.publisher import Publisher
from formation.geodesy import geodetic_to_enu
from mission.cli import main as swarmseek
from tests.companion.publish_support import (HOME_ENU, ORIGIN, LineSensor, NoFixAutopilot, free_tcp_port, ground_station,
                             mock_autopilot)
from tests.support.wait_helpers import wait_until
from wire.zenoh_config import zenoh_config

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 60.0


class _Stderr:
    """A child's stderr lines, read by a thread; :meth:`wait_for` waits for one holding a text."""

    def __init__(self, stream):
        self.lines: list[str] = []
        self._new = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            with self._new:
                self.lines.append(line)
                self._new.notify_all()

    def wait_for(self, text: str) -> None:
        with self._new:
            assert self._new.wait_for(lambda: any(text in line for line in self.lines), TIMEOUT_S), self.text()

    def text(self) -> str:
        """Everything read (all of it once the child has exited and :meth:`join` returned)."""
        return "".join(self.lines)

    def join(self) -> None:
        self._thread.join(TIMEOUT_S)


def _start_publish(argv: list[str], stdin=None) -> tuple[subprocess.Popen, _Stderr]:
    """``python -m mission publish ARGV`` in a child process, and its stderr."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")])}
    proc = subprocess.Popen([sys.executable, "-m", "mission", "publish", *argv], stdin=stdin,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    return proc, _Stderr(proc.stderr)


def test_serial_line_sensor_on_a_pseudo_terminal():
    master, slave = os.openpty()
    device = os.ttyname(slave)
    with mock_autopilot("pubs") as (_fleet, mavlink), ground_station("pubs") as (store, endpoint, _payloads):
        proc, stderr = _start_publish(["--connect", mavlink, "--serial", device, "--baud", "115200", "--fleet", "pubs",
                                       "--zenoh-connect", endpoint, "--count", "3", "--wait-subscriber", "30",
                                       "--timeout", str(TIMEOUT_S)])
        try:
            stderr.wait_for(f"publishing swarmseek/pubs/vehicle/1/sensor from {device}")
            os.write(master, b"abc\n\r\nnan\n" + b"9" * 300 + b"\n")  # four bad lines, one of each reason
            with LineSensor(master) as sensor:  # readings before the autopilot's first fix are held
                assert proc.wait(TIMEOUT_S) == 0, stderr.text()
        finally:
            if proc.poll() is None:
                proc.kill()
            os.close(master)
            os.close(slave)
    stderr.join()
    err = stderr.text()
    assert "Traceback" not in err
    assert "bad line (not a number): b'abc'" in err
    summary = re.search(r"published 3; held (\d+) \(no position yet (\d+), stale position (\d+)\); "
                        r"bad lines 4 \(empty 1, not a number 1, not finite 1, too long 1\)", err)
    assert summary, err
    readings = store.history(1)
    assert store.counts()["rejected"] == dict.fromkeys(store.counts()["rejected"], 0)
    assert [r.seq for r in readings] == [0, 1, 2]
    values = [r.value for r in readings]
    assert values == sorted(values) and set(values) <= set(sensor.written)
    for r in readings:
        np.testing.assert_allclose(geodetic_to_enu(r.lat_deg, r.lon_deg, r.alt_m, ORIGIN), HOME_ENU, atol=0.05)


def test_standard_input_before_the_first_fix_is_held_and_counted():
    with NoFixAutopilot(sysid=5) as autopilot, ground_station("pubs", sysids=(5,)) as (_store, endpoint, payloads):
        proc, stderr = _start_publish(["--connect", autopilot.connection, "--fleet", "pubs", "--zenoh-connect",
                                       endpoint, "--wait-subscriber", "30", "--timeout", str(TIMEOUT_S)],
                                      stdin=subprocess.PIPE)
        try:
            proc.stdin.write("1.0\n2.0\nbad\n3.0")  # the last line without its newline
            proc.stdin.close()
            assert proc.wait(TIMEOUT_S) == 0, stderr.text()
        finally:
            if proc.poll() is None:
                proc.kill()
    stderr.join()
    err = stderr.text()
    assert "Traceback" not in err
    assert "reading held: no position fix from the autopilot yet" in err
    assert "end of standard input" in err
    assert ("published 0; held 3 (no position yet 3, stale position 0); "
            "bad lines 1 (empty 0, not a number 1, not finite 0, too long 0)") in err
    assert payloads == []


def test_usage_and_input_errors_are_one_line(capsys, tmp_path):
    base = ["publish", "--connect", "tcp:127.0.0.1:5760"]
    assert swarmseek(base) == 2
    assert "give --zenoh-connect" in capsys.readouterr().err
    missing = str(tmp_path / "ttyUSB9")
    assert swarmseek([*base, "--zenoh-connect", "tcp/127.0.0.1:7447", "--serial", missing]) == 1
    err = capsys.readouterr().err
    assert f"swarmseek publish: error: cannot open serial device {missing!r}" in err and "Traceback" not in err
    for bad in (["--baud", "0"], ["--sysid", "256"], ["--connect", "tcp:nohost"], ["--max-fix-age", "nan"]):
        try:
            status = swarmseek([*base, "--zenoh-connect", "tcp/127.0.0.1:7447", *bad])
        except SystemExit as exc:
            status = exc.code
        assert status == 2, bad
        assert "swarmseek publish: error:" in capsys.readouterr().err


def test_the_python_api_example_publishes_a_co2_sensors_lines():
    """examples/real_sensor/co2_serial.py, as shipped, on a pseudo terminal."""
    master, slave = os.openpty()
    device = os.ttyname(slave)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with mock_autopilot("co2") as (_fleet, mavlink), ground_station("co2") as (store, endpoint, _payloads):
        proc = subprocess.Popen([sys.executable, str(ROOT / "examples" / "real_sensor" / "co2_serial.py"),
                                 "--serial", device, "--connect", mavlink, "--fleet", "co2", "--zenoh-connect",
                                 endpoint, "--count", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True, env=env)
        stderr = _Stderr(proc.stderr)
        try:
            stderr.wait_for("publishing swarmseek/co2/vehicle/1/sensor")
            os.write(master, b"warming up\r\n")
            with LineSensor(master, "CO2 {} ppm") as sensor:
                assert proc.wait(TIMEOUT_S) == 0, stderr.text()
        finally:
            if proc.poll() is None:
                proc.kill()
            os.close(master)
            os.close(slave)
    stderr.join()
    assert re.search(r"published 2; held \d+ .*; bad values 0; lines without a reading 1", stderr.text()), stderr.text()
    values = [r.value for r in store.history(1)]
    assert len(values) == 2 and set(values) <= set(sensor.written)
    assert store.counts()["rejected"] == dict.fromkeys(store.counts()["rejected"], 0)


def test_the_listener_example_shows_what_the_ground_station_accepts_and_rejects():
    """examples/real_sensor/listen.py prints the readings the ground station's checks accept and
    the rejections with their reason (here ``wrong_schema``)."""
    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(ROOT / "examples" / "real_sensor" / "listen.py"), "--fleet", "lis",
                             "--sysid", "1", "--origin", ",".join(map(str, ORIGIN)), "--zenoh-listen", endpoint,
                             "--count", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    stderr = _Stderr(proc.stderr)
    try:
        stderr.wait_for("listening for swarmseek/lis/vehicle/*/sensor")
        with mock_autopilot("lis") as (_fleet, mavlink), Publisher(
                "lis", mavlink=mavlink, zenoh_connect=[endpoint], heartbeat_timeout_s=TIMEOUT_S) as pub:
            assert pub.wait_for_subscriber(TIMEOUT_S)
            wait_until(pub.telemetry.latest, TIMEOUT_S, "the autopilot's first position fix")
            with zenoh.open(zenoh_config(connect=endpoint)) as session:
                session.put(pub.key, b'{"schema": "other"}')
            assert pub.put(2.5) and pub.put(3.5)
            out, _ = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr.text()
    accepted = re.findall(r"accepted sysid 1 seq (\d) value ([0-9.]+) age [0-9.]+ s at E 12.0 N -7.0 U -?0.0 m", out)
    assert accepted == [("0", "2.5"), ("1", "3.5")], out
    assert "rejected 1 (wrong_schema: schema 'other', expected 'swarmseek.sensor.v1')" in out, out


def test_the_autopilot_going_away_ends_with_a_clear_error_and_the_counts():
    with ground_station("pubs", sysids=(5,)) as (_store, endpoint, _payloads):
        with NoFixAutopilot(sysid=5) as autopilot:
            proc, stderr = _start_publish(["--connect", autopilot.connection, "--retries", "1", "--fleet", "pubs",
                                           "--zenoh-connect", endpoint, "--wait-subscriber", "30"],
                                          stdin=subprocess.PIPE)
            stderr.wait_for("publishing swarmseek/pubs/vehicle/5/sensor from standard input")
        try:  # the autopilot is gone; standard input stays open
            assert proc.wait(TIMEOUT_S) == 1, stderr.text()
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.stdin.close()
    stderr.join()
    err = stderr.text()
    assert "swarmseek publish: error: lost the MAVLink connection" in err and "Traceback" not in err
    assert "swarmseek publish: published 0; held 0" in err


def test_the_counts_are_reported_while_it_runs():
    with NoFixAutopilot(sysid=5) as autopilot, ground_station("pubs", sysids=(5,)) as (_store, endpoint, _payloads):
        proc, stderr = _start_publish(["--connect", autopilot.connection, "--fleet", "pubs", "--zenoh-connect",
                                       endpoint, "--wait-subscriber", "30", "--report-every", "0.2"],
                                      stdin=subprocess.PIPE)
        try:
            stderr.wait_for("publishing swarmseek/pubs/vehicle/5/sensor from standard input")
            proc.stdin.write("1.0\n")
            proc.stdin.flush()
            # before the end of the input: the periodic report, not the final one
            stderr.wait_for("swarmseek publish: published 0; held 1 (no position yet 1, stale position 0)")
            proc.stdin.close()
            assert proc.wait(TIMEOUT_S) == 0, stderr.text()
        finally:
            if proc.poll() is None:
                proc.kill()
    stderr.join()
    assert stderr.text().count("published 0; held 1 (") == 2  # once while running (unchanged after), once at the end
