"""Lossy links: 20 % packet loss each way and 50 ms latency on every vehicle, from connection to
landing. The mission completes, every command is acknowledged (``command_long`` retries, then
the coordinator's rounds of retries), and no vehicle leaves OFFBOARD for lack of setpoints.

Speed-up 4: PX4's offboard-loss timeout (COM_OF_LOSS_T = 1 s of the mission clock) is then
250 ms of wall time, so an event-loop stall of a loaded 2-core machine cannot pass for setpoint
starvation, while the setpoint stream (10 Hz mission clock, 40 Hz wall) would need ten frames in a
row lost (0.2 ** 10 = 1e-7) to starve a vehicle; the parameter is left at its default.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from mission.sim.lockstep import VirtualClock
from tests.support.fly_helpers import fly as _fly, run_fleet




@pytest.mark.slow
@pytest.mark.timeout(400)
def test_lossy_slow_links_mission_completes_without_offboard_loss(tmp_path):
    n = 5
    ports = fleet_ports(n, "px4")
    source = np.array([5.0, 4.0, 13.0])
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=3, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    for sysid in range(1, n + 1):
        for name, value in (("loss_uplink", 0.2), ("loss_downlink", 0.2),
                            ("latency_uplink_s", 0.05), ("latency_downlink_s", 0.05)):
            fleet.set_fault(sysid, name, value)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)))
    log_path = tmp_path / "m.jsonl"
    # watch the autopilots' side: any airborne vehicle out of OFFBOARD before the return
    left: list[tuple[int, str]] = []
    stop = threading.Event()

    def watch():
        while not stop.is_set():
            text = log_path.read_text() if log_path.exists() else ""
            if '"phase":"return"' in text:
                return
            if '"phase":"assemble"' in text:
                left.extend((v.sysid, v.mode_name) for v in fleet.vehicles
                            if v.armed and v.mode_name != "OFFBOARD")
            fleet.clock.sleep_blocking(0.5)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        result = run_fleet(fleet, lambda world: _fly(plan, fleet, log_path, world=world))
        dropped = {k: sum(v.counters.get(k, 0) for v in fleet.vehicles)
                   for k in ("rx_dropped_loss", "tx_dropped_loss")}
    finally:
        stop.set()
        watcher.join(timeout=30)
        fleet.stop()
    events = [r for r in read_mission_log(log_path) if r["type"] == "event"]
    messages = [e["message"] for e in events]
    assert result.outcome == "converged", (result.message, [m for m in messages if "vehicle" in m][-10:])
    assert result.reengaged == {}, result.reengaged           # no failsafe exit to re-engage
    assert not any("left OFFBOARD" in m for m in messages)
    assert left == [], left[:5]
    assert result.lost == []
    landed = [e for e in events if e["message"].endswith("landed")]
    assert len(landed) == n
    assert dropped["rx_dropped_loss"] > 100 and dropped["tx_dropped_loss"] > 100, dropped  # faults acted
