"""``swarmseek sensor`` against a tiny in-test pymavlink autopilot over TCP on 127.0.0.1."""
from __future__ import annotations

import json
import queue
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zenoh
from pymavlink.dialects.v20 import common as mavlink2

from formation.geodesy import enu_to_geodetic, geodetic_to_enu
from mission.cli import main as swarmseek
from sitl_mock.fields_config import make_field
from companion.sensor_wire import sensor_key
from wire.zenoh_config import zenoh_config
from mission.sim.embedded import free_port_block

TIMEOUT_S = 60.0
ORIGIN = (45.19, 5.72, 200.0)


def _free_tcp_port() -> int:
    return free_port_block(1, kinds=("tcp",))


class _TinyAutopilot:
    """Just enough MAVLink: HEARTBEAT at 4 Hz, GLOBAL_POSITION_INT at 25 Hz (lat = lon = 0 for the
    first few, like an autopilot without a fix), and records what it receives. Over TCP it is a
    server (``connection`` is ``tcp:...``); over UDP it streams to ``udp_peer_port`` (the sensor
    listens with ``udpin:...``)."""

    def __init__(self, sysid: int = 7, no_fix_messages: int = 5, udp_peer_port: int | None = None):
        self.sysid = sysid
        self.no_fix_messages = no_fix_messages
        self.udp_peer = None if udp_peer_port is None else ("127.0.0.1", udp_peer_port)
        self.sock = socket.socket(type=socket.SOCK_STREAM if self.udp_peer is None else socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        if self.udp_peer is None:
            self.sock.listen(1)
            self.sock.settimeout(0.2)
            self.connection = f"tcp:127.0.0.1:{self.sock.getsockname()[1]}"
        else:
            self.sock.settimeout(0.0)
            self.connection = f"udpin:127.0.0.1:{udp_peer_port}"
        self.received: list = []
        self.sent_fixes: list[tuple[int, int, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *_exc):
        self._stop.set()
        self._thread.join(10.0)
        self.sock.close()

    def _serve(self):
        out = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        gcs = mavlink2.MAVLink(None, srcSystem=200, srcComponent=190)  # another ground station
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        if self.udp_peer is not None:
            self._talk(self.sock, out, gcs, parser)
            return
        while not self._stop.is_set():
            try:
                client, _ = self.sock.accept()
            except OSError:
                continue
            client.settimeout(0.0)
            with client:
                self._talk(client, out, gcs, parser)

    def _frames(self, tick, out, gcs):
        frames = []
        if tick % 6 == 0:
            frames.append(gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs))
            frames.append(out.heartbeat_encode(2, 3, 0, 4, 4).pack(out))
        lat = lon = alt = 0
        if tick >= self.no_fix_messages:
            enu = np.array([3.0 * np.cos(0.1 * tick), 2.0 + 0.2 * tick, 10.0 + 0.05 * tick])
            glat, glon, galt = enu_to_geodetic(enu, ORIGIN)
            lat, lon, alt = int(round(glat * 1e7)), int(round(glon * 1e7)), int(round(galt * 1e3))
            self.sent_fixes.append((lat, lon, alt))
        frames.append(out.global_position_int_encode(tick * 40, lat, lon, alt, alt, 0, 0, 0, 0).pack(out))
        return frames

    def _talk(self, sock, out, gcs, parser):
        tick = 0
        while not self._stop.wait(0.04):
            frames = self._frames(tick, out, gcs)
            tick += 1
            try:
                if self.udp_peer is None:
                    sock.sendall(b"".join(frames))
                else:
                    for frame in frames:
                        sock.sendto(frame, self.udp_peer)
            except ConnectionRefusedError:
                pass  # UDP: the sensor is not listening yet
            except OSError:
                return
            while True:
                try:
                    data = sock.recv(4096)
                except (BlockingIOError, ConnectionRefusedError):
                    break
                except OSError:
                    return
                if not data:
                    return
                self.received.extend(parser.parse_buffer(data) or [])


def _free_udp_port() -> int:
    with socket.socket(type=socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def zenoh_listener():
    port = _free_tcp_port()
    session = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{port}"))
    try:
        yield session, f"tcp/127.0.0.1:{port}"
    finally:
        session.close()


@pytest.mark.parametrize("transport,field_name,source,rate_hz", [
    ("tcp", "sigma1", "0,0,0", 10.0),
    ("tcp", "sigma2", "=-5,3,12", 20.0),
    ("udp", "sigma1", "=-5,3,12", 10.0),
])
def test_publishes_readings_of_the_autopilot_position(zenoh_listener, transport, field_name, source, rate_hz,
                                                      capsys):
    session, endpoint = zenoh_listener
    readings: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("swarmseek/field/vehicle/*/sensor",
                                     lambda s: readings.put((str(s.key_expr), s.payload.to_bytes())))
    source_arg = ["--source" + source] if source.startswith("=") else ["--source", source]
    try:
        udp_port = _free_udp_port() if transport == "udp" else None
        with _TinyAutopilot(sysid=7, udp_peer_port=udp_port) as ap:
            t_before = time.time()
            rc = swarmseek([
                "sensor", "--connect", ap.connection, "--field", field_name, *source_arg,
                "--origin", ",".join(map(str, ORIGIN)), "--rate", str(rate_hz), "--fleet", "field",
                "--zenoh-connect", endpoint, "--count", "5", "--wait-subscriber", "20", "--timeout", "30",
            ])
            t_after = time.time()
            got = [readings.get(timeout=TIMEOUT_S) for _ in range(5)]
            requests = [m for m in ap.received if m.get_type() == "COMMAND_LONG"]
            fixes = set(ap.sent_fixes)
    finally:
        sub.undeclare()
    assert rc == 0
    assert "published 5 readings" in capsys.readouterr().err
    field = make_field(field_name, [float(v) for v in source.lstrip("=").split(",")])
    for i, (key, payload) in enumerate(got):
        r = json.loads(payload)
        assert key == sensor_key("field", 7)
        assert (r["schema"], r["fleet"], r["sysid"], r["seq"]) == ("swarmseek.sensor.v1", "field", 7, i)
        assert t_before <= r["time_s"] <= t_after  # Unix time
        assert (round(r["lat_deg"] * 1e7), round(r["lon_deg"] * 1e7), round(r["alt_m"] * 1e3)) in fixes
        enu = geodetic_to_enu(r["lat_deg"], r["lon_deg"], r["alt_m"], ORIGIN)
        assert r["value"] == pytest.approx(float(field.value(enu)), rel=1e-9)
    # it asked for GLOBAL_POSITION_INT (id 33) at its rate, addressed to the autopilot
    assert any(m.command == 511 and m.param1 == 33 and m.param2 == pytest.approx(1e6 / rate_hz)
               and m.target_system == 7 for m in requests)


def test_wrong_sysid_times_out_with_a_clear_message(zenoh_listener, capsys):
    _, endpoint = zenoh_listener
    with _TinyAutopilot(sysid=7) as ap:
        rc = swarmseek(["sensor", "--connect", ap.connection, "--field", "sigma1",
                        "--origin", "45,5,200", "--sysid", "9", "--timeout", "1",
                        "--zenoh-connect", endpoint, "--count", "1"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "no heartbeat from autopilot sysid 9 within 1 s" in err
    assert "Traceback" not in err


def test_connection_refused_is_a_clear_error_without_traceback(capsys):
    port = _free_tcp_port()  # nothing listens there
    rc = swarmseek(["sensor", "--connect", f"tcp:127.0.0.1:{port}", "--field", "sigma1",
                    "--origin", "45,5,200", "--retries", "1", "--zenoh-connect", "tcp/127.0.0.1:1"])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"cannot open MAVLink connection 'tcp:127.0.0.1:{port}'" in err
    assert "Traceback" not in err


_GOOD = ["--connect", "tcp:127.0.0.1:5762", "--field", "sigma1", "--origin", "45,5,200",
         "--zenoh-connect", "tcp/127.0.0.1:7447"]


def _replace(flag, value):
    args = list(_GOOD)
    if flag in args:
        i = args.index(flag)
        del args[i:i + 2]
    return args + [flag, value]


@pytest.mark.parametrize("argv,match", [
    (_replace("--field", "sigma3"), "invalid choice"),
    (_replace("--origin", "45,5"), "LAT,LON,ALT"),
    (_replace("--origin", "95,5,0"), "latitude"),
    (_replace("--source", "1,2,nan"), "E,N,U"),
    (_replace("--noise", "-1"), ">= 0"),
    (_replace("--rate", "0"), "positive"),
    (_replace("--sysid", "300"), "1..255"),
    (_replace("--count", "0"), "positive integer"),
    (_replace("--seed", "-3"), "positive integer"),
    (_replace("--connect", "tcp:127.0.0.1"), "HOST:PORT"),
    (_replace("--zenoh-connect", "127.0.0.1:7447"), "PROTO/ADDRESS"),
    (_replace("--fleet", "a/b"), "fleet"),
    ([a for a in _GOOD if a not in ("--origin", "45,5,200")], "--origin"),
])
def test_bad_flags_are_argparse_errors(argv, match, capsys):
    with pytest.raises(SystemExit) as exc:
        swarmseek(["sensor", *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    assert match in err
    assert "Traceback" not in err


def test_missing_zenoh_endpoint_exits_2_with_a_message(capsys):
    args = [a for a in _GOOD if a not in ("--zenoh-connect", "tcp/127.0.0.1:7447")]
    assert swarmseek(["sensor", *args]) == 2
    assert "--zenoh-listen and/or --zenoh-connect" in capsys.readouterr().err


def test_command_line_entry_point_runs_without_traceback():
    port = _free_tcp_port()
    proc = subprocess.run(
        [sys.executable, "-m", "mission", "sensor", "--connect", f"tcp:127.0.0.1:{port}", "--field", "sigma2",
         "--origin", "45,5,200", "--retries", "1", "--zenoh-connect", "tcp/127.0.0.1:1"],
        capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 1
    assert "cannot open MAVLink connection" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


def test_autopilot_going_away_ends_with_a_clear_error(zenoh_listener, capsys):
    session, endpoint = zenoh_listener
    readings: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("swarmseek/swarmseek/vehicle/*/sensor", lambda s: readings.put(1))
    result: dict = {}
    try:
        with _TinyAutopilot(sysid=4) as ap:
            runner = threading.Thread(target=lambda: result.setdefault("rc", swarmseek([
                "sensor", "--connect", ap.connection, "--field", "sigma1", "--origin", "45.19,5.72,200",
                "--retries", "1", "--zenoh-connect", endpoint, "--wait-subscriber", "20"])), daemon=True)
            runner.start()
            readings.get(timeout=TIMEOUT_S)  # it runs; now the autopilot disappears
        runner.join(TIMEOUT_S)
    finally:
        sub.undeclare()
    err = capsys.readouterr().err
    assert not runner.is_alive()
    assert result["rc"] == 1
    assert "lost the MAVLink connection" in err
    assert "Traceback" not in err


def test_duration_stops_the_sensor_by_itself(zenoh_listener, capsys):
    _, endpoint = zenoh_listener
    with _TinyAutopilot(sysid=2) as ap:
        t0 = time.monotonic()
        rc = swarmseek(["sensor", "--connect", ap.connection, "--field", "sigma2", "--origin", "45.19,5.72,200",
                        "--duration", "1.5", "--wait-subscriber", "0", "--zenoh-connect", endpoint])
        elapsed = time.monotonic() - t0
    err = capsys.readouterr().err
    assert rc == 0
    assert elapsed >= 1.5
    assert "publishing swarmseek/swarmseek/vehicle/2/sensor" in err
    assert "published" in err
