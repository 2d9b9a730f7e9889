"""The field flags reach the simulated world: ``swarmseek sensor`` on a plume from a plan's
[field] table, and ``swarmseek mock`` with an intermittent plume, a lag and a floor."""
from __future__ import annotations

import json
import queue
import subprocess
import sys
import time

import numpy as np
import pytest
import zenoh

import sitl_mock.fleet as fleet_mod
from formation.geodesy import geodetic_to_enu
from mission.cli import main as swarmseek
from sitl_mock.fields_config import make_field
from wire.zenoh_config import zenoh_config
from mission.sim.embedded import free_port_block

TIMEOUT_S = 60.0
ORIGIN = (45.19, 5.72, 230.0)
PLUME = dict(wind_from_deg=270.0, wind_speed_m_s=2.0, stability="D", source_radius_m=1.0)


def _free_tcp_port() -> int:
    return free_port_block(1, kinds=("tcp",))


def _listen(session_port: int, fleet: str):
    session = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{session_port}"))
    readings: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(f"swarmseek/{fleet}/vehicle/*/sensor",
                                     lambda s: readings.put(json.loads(s.payload.to_bytes())))
    return session, sub, readings


@pytest.mark.parametrize("floor", [0.0, 10.0])
def test_virtual_sensor_samples_the_plan_plume(floor, tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text('[field]\ntype = "plume"\nsource_enu_m = [0.0, 0.0, 1.0]\n'
                    + "".join(f"{k} = {json.dumps(v)}\n" for k, v in PLUME.items())
                    + f"sensor_detection_floor = {floor}\n")
    zport = _free_tcp_port()
    session, sub, readings = _listen(zport, "plume")
    home = np.array([[8.0, 0.5, 0.0]])  # 8 m downwind of a release 1 m up
    fleet = fleet_mod.MockFleet(n=1, personality="ardupilot", field=None, origin=ORIGIN, home_offsets_enu=home,
                                udp_base_port=0, udp_bind_base_port=0, tcp_base_port=_free_tcp_port(),
                                fleet_name="plume", zenoh=False)
    try:
        fleet.start()
        rc = swarmseek(["sensor", "--connect", f"tcp:127.0.0.1:{fleet.vehicles[0].tcp_port}",
                        "--field-config", str(plan), "--origin", ",".join(map(str, ORIGIN)), "--fleet", "plume",
                        "--rate", "10", "--count", "3", "--zenoh-connect", f"tcp/127.0.0.1:{zport}",
                        "--wait-subscriber", "20", "--timeout", "30"])
        got = [readings.get(timeout=TIMEOUT_S) for _ in range(3)]
    finally:
        fleet.stop()
        sub.undeclare()
        session.close()
    assert rc == 0, capsys.readouterr().err
    field = make_field("plume", (0.0, 0.0, 1.0), **PLUME)
    for r in got:
        enu = geodetic_to_enu(r["lat_deg"], r["lon_deg"], r["alt_m"], ORIGIN)
        expected = float(field.value(enu))
        assert expected > 0.05  # on the plume
        assert r["value"] == (0.0 if floor > expected else pytest.approx(expected, rel=1e-9))


def test_mock_fleet_publishes_intermittent_readings_with_lag_and_floor():
    zport, floor = _free_tcp_port(), 0.05
    session = zenoh.open(zenoh_config(connect=f"tcp/127.0.0.1:{zport}"))
    readings: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("swarmseek/puffs/vehicle/*/sensor",
                                     lambda s: readings.put(json.loads(s.payload.to_bytes())))
    args = [sys.executable, "-m", "mission", "mock", "--vehicles", "2", "--duration", "8", "--fleet", "puffs",
            "--udp-base-port", "0", "--tcp-base-port", "0", "--zenoh-listen", f"tcp/127.0.0.1:{zport}",
            "--field", "intermittent", "--source=-6,0,0.5", "--wind-from", "270", "--field-seed", "5",
            "--sensor-tau", "0.2", "--detection-floor", str(floor), "--speedup", "5"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "field intermittent" in proc.stdout.readline()
        got, deadline = [], time.monotonic() + TIMEOUT_S
        while len(got) < 40 and time.monotonic() < deadline:
            try:
                got.append(readings.get(timeout=1.0))
            except queue.Empty:
                continue
        _out, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        sub.undeclare()
        session.close()
    assert proc.returncode == 0, err
    assert len(got) >= 40
    values = np.array([r["value"] for r in got])
    assert np.all(np.isfinite(values)) and np.all((values == 0.0) | (values >= floor))
