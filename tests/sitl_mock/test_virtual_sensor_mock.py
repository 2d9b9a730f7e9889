"""``swarmseek sensor`` against the project's own mock autopilot (sitl_mock.fleet) over TCP."""
from __future__ import annotations

import json
import queue

import numpy as np
import pytest
import zenoh

import sitl_mock.fleet as fleet_mod
from formation.geodesy import geodetic_to_enu
from mission.cli import main as swarmseek
from sitl_mock.fields_config import make_field
from companion.sensor_wire import sensor_key
from wire.zenoh_config import zenoh_config
from mission.sim.embedded import free_port_block

TIMEOUT_S = 60.0
ORIGIN = (45.19, 5.72, 230.0)


def _free_tcp_port() -> int:
    return free_port_block(1, kinds=("tcp",))


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_virtual_sensor_reads_the_mock_vehicle_position(personality, capsys):
    zport = _free_tcp_port()
    session = zenoh.open(zenoh_config(listen=f"tcp/127.0.0.1:{zport}"))
    readings: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("swarmseek/dry/vehicle/*/sensor",
                                     lambda s: readings.put((str(s.key_expr), s.payload.to_bytes())))
    offset_enu = np.array([[12.0, -7.0, 0.0]])
    fleet = fleet_mod.MockFleet(n=1, personality=personality, field=None, origin=ORIGIN,
                                home_offsets_enu=offset_enu, udp_base_port=0, udp_bind_base_port=0,
                                tcp_base_port=_free_tcp_port(), fleet_name="dry", zenoh=False)
    try:
        fleet.start()
        vehicle = fleet.vehicles[0]
        rc = swarmseek(["sensor", "--connect", f"tcp:127.0.0.1:{vehicle.tcp_port}", "--field", "sigma1",
                        "--source=20,-10,5", "--origin", ",".join(map(str, ORIGIN)), "--fleet", "dry",
                        "--rate", "10", "--count", "3", "--zenoh-connect", f"tcp/127.0.0.1:{zport}",
                        "--wait-subscriber", "20", "--timeout", "30"])
        got = [readings.get(timeout=TIMEOUT_S) for _ in range(3)]
    finally:
        fleet.stop()
        sub.undeclare()
        session.close()
    err = capsys.readouterr().err
    assert rc == 0, err
    field = make_field("sigma1", (20.0, -10.0, 5.0))
    for i, (key, payload) in enumerate(got):
        r = json.loads(payload)
        assert key == sensor_key("dry", 1)
        assert (r["sysid"], r["seq"]) == (1, i)
        enu = geodetic_to_enu(r["lat_deg"], r["lon_deg"], r["alt_m"], ORIGIN)
        np.testing.assert_allclose(enu, offset_enu[0], atol=0.05)  # parked at its home
        assert r["value"] == pytest.approx(float(field.value(enu)), rel=1e-9)
    assert not fleet.errors
