"""Full takeoff / setpoints / land against the real mock fleet (sitl_mock.fleet.MockFleet), both
personalities, over UDP with the shared poller (PX4 SITL style ports) and TCP (ArduPilot SITL
style), with homes several metres apart."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

import sitl_mock.clock as clock_mod
import sitl_mock.fleet as fleet_mod
from mission.link.endpoint import MavEndpoint
from mission.link.endpoint_registry import SysidRegistry
from mission.sim.embedded import free_port_block
from mission.link.poller import UdpPoller
from mission.vehicle.streamer import SetpointStreamer
from mission.vehicle.vehicle_link import DEFAULT_RATES_HZ, VehicleLink

SPEEDUP = 4.0
HOMES_ENU = [(0.0, 0.0, 0.0), (12.0, -7.0, 0.0)]


async def _fly(fleet, clock, transport: str, tmp_path) -> dict:
    registry = SysidRegistry()
    poller = UdpPoller() if transport == "udp-polled" else None
    endpoints, vehicles = [], []
    try:
        for i, mv in enumerate(fleet.vehicles):
            uri = (f"udpin:127.0.0.1:{mv.udp_send_port}" if transport.startswith("udp")
                   else f"tcp:127.0.0.1:{mv.tcp_port}")
            ep = await MavEndpoint.open(uri, clock=clock, registry=registry, tlog_dir=tmp_path, poller=poller)
            endpoints.append(ep)
            vehicles.append(await VehicleLink.create(ep, mv.sysid, clock=clock, mission_origin=fleet.origin))
        for v in vehicles:
            await v.set_message_rates(DEFAULT_RATES_HZ)
            await v.wait_home(20.0)
            assert np.allclose(v.home_enu_m(), HOMES_ENU[v.sysid - 1], atol=0.02)
            await v.wait_for(lambda s: s.position_ok and s.landed, 30.0, "position estimate on the ground")
            # the mock refuses to arm until its position estimate is ready: it says so in
            # SYS_STATUS (GPS and pre-arm health bits), so the first takeoff must be accepted
            await v.wait_for(lambda s: s.gps_healthy, 30.0, "GPS / pre-arm health in SYS_STATUS")
        for v in vehicles:
            await v.takeoff(6.0)
        for v in vehicles:
            await v.wait_for(lambda s: s.armed and (s.relative_alt_m or 0.0) > 5.0, 60.0, "climb to 6 m")
        streamer = SetpointStreamer(vehicles, rate_hz=10.0, clock=clock)
        targets = {v.sysid: np.array([8.0 + 4.0 * v.sysid, 6.0, 8.0]) for v in vehicles}
        for sysid, target in targets.items():
            streamer.set_target(sysid, target)
        await streamer.start()
        for v in vehicles:
            target = targets[v.sysid]
            await v.wait_for(lambda s, v=v, t=target: np.linalg.norm(v.position_enu_m() - t) < 0.3, 60.0,
                             "the setpoint")
            true_enu = fleet.vehicle(v.sysid).true_position_enu()
            assert np.linalg.norm(true_enu - target) < 0.5   # the mission frame is right for every home
        for v in vehicles:
            streamer.remove(v.sysid)
            await v.land()
        await streamer.stop()
        for v in vehicles:
            await v.wait_for(lambda s: s.landed and not s.armed, 90.0, "landed and disarmed")
        stats = {v.sysid: streamer.stats(v.sysid) for v in vehicles}
        return {"stats": stats, "modes": [v.state.mode for v in vehicles],
                "counters": [dict(ep.counters) for ep in endpoints]}
    finally:
        for v in vehicles:
            await v.close()
        for ep in endpoints:
            await ep.close()
        if poller is not None:
            await poller.close()


@pytest.mark.slow
@pytest.mark.parametrize("personality, transport", [("ardupilot", "tcp"), ("px4", "udp-polled")])
def test_takeoff_setpoints_land_against_mock_fleet(personality, transport, tmp_path):
    base = free_port_block(60, kinds=("udp", "tcp"))
    clock = clock_mod.SimClock(SPEEDUP)
    fleet = fleet_mod.MockFleet(n=2, personality=personality, clock=clock, home_offsets_enu=HOMES_ENU,
                                udp_base_port=base, udp_bind_base_port=base + 10, tcp_base_port=base + 20,
                                zenoh=False)
    fleet.start()
    try:
        result = asyncio.run(asyncio.wait_for(_fly(fleet, clock, transport, tmp_path), 240.0))
    finally:
        fleet.stop()
    landed_mode = "LAND" if personality == "ardupilot" else "AUTO.LAND"
    assert result["modes"] == [landed_mode, landed_mode]
    for stats in result["stats"].values():
        assert stats["sent"] > 10 and stats["errors"] == 0
        assert 0.05 < stats["p50_interval_s"] < 0.2   # 10 Hz on the simulated clock
    for counters in result["counters"]:
        assert counters["bad_crc"] == counters["malformed"] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["vehicle-1.tlog", "vehicle-2.tlog"]
