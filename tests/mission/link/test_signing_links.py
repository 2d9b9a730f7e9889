"""Signing end to end through the ground station's links (``mission.link.endpoint`` + ``mission.vehicle.vehicle_link``)
and the mock fleet: SETUP_SIGNING provisioning, and forged, unsigned and replayed telemetry
injected at the ground station's port change nothing and are counted.
"""
from __future__ import annotations

import asyncio
import socket

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.link.endpoint_registry import LinkError
from mission.link.endpoint import MavEndpoint
from mission.core.signing_config import SigningConfig
from mission.link.signing import apply_signing
from mission.vehicle.vehicle_link import VehicleLink
from sitl_mock.fleet import MockFleet
from sitl_mock.transport import make_parser
from tests.support.wait_helpers import wait_until_async

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
GCS_REJECTIONS = ("unsigned", "bad_signature", "replayed")
MOCK_REJECTIONS = ("rx_unsigned", "rx_bad_signature", "rx_replayed")


def _free_udp_ports(count: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(count)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _fleet(signing_key):
    gcs_port, bind_port = _free_udp_ports(2)
    return MockFleet(1, personality="ardupilot", speedup=2.0, udp_base_port=gcs_port,
                     udp_bind_base_port=bind_port, tcp_base_port=0, signing_key=signing_key)


async def _connect(fleet):
    v0 = fleet.vehicles[0]
    ep = await MavEndpoint.open(f"udpin:127.0.0.1:{v0.udp_send_port}", clock=fleet.clock,
                                signing=SigningConfig(KEY))
    vehicle = await VehicleLink.create(ep, 1, clock=fleet.clock, mission_origin=fleet.origin,
                                       heartbeat_timeout_s=30.0)
    return ep, vehicle


def test_ground_station_provisions_an_unsigned_vehicle_and_flies_it_signed():
    fleet = _fleet(signing_key=None)

    async def main():
        ep, v = await _connect(fleet)
        try:
            ap = fleet.vehicles[0].autopilot
            assert ap.signing.enabled and ap.counters["signing_setup_accepted"] == 1
            assert ep.counters["setup_signing_sent"] >= 1 and ep.counters["unsigned"] >= 1
            await wait_until_async(lambda: ap.position_ready(fleet.clock.time()), what="position estimate")
            await v.set_mode("GUIDED")
            await v.arm()
            assert ap.armed and ap.mode_name == "GUIDED"
            assert {k: ap.counters[k] for k in MOCK_REJECTIONS} == dict.fromkeys(MOCK_REJECTIONS, 0)
            assert ep.counters["bad_signature"] == ep.counters["replayed"] == 0
        finally:
            await v.close()
            await ep.close()

    with fleet:
        asyncio.run(main())
    assert fleet.errors == []


def test_forged_unsigned_and_replayed_telemetry_change_nothing():
    fleet = _fleet(signing_key=KEY)

    async def main():
        ep, v = await _connect(fleet)
        sniffer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sniffer.bind(("127.0.0.1", 0))
        sniffer.setblocking(False)
        try:
            v0 = fleet.vehicles[0]
            sniffer.sendto(b"\x00", ("127.0.0.1", v0.udp_bind_port))  # now a peer of the mock
            parser = make_parser()
            captured: list[bytes] = []

            def sniff():
                while True:
                    try:
                        data = sniffer.recv(65536)
                    except BlockingIOError:
                        break
                    captured.extend(bytes(m.get_msgbuf()) for m in parser.parse_buffer(data) or []
                                    if m.get_type() == "HEARTBEAT")
                return len(captured) >= 2

            await wait_until_async(sniff, what="signed heartbeats captured by the sniffer")
            boot_mode = v.state.mode
            await wait_until_async(lambda: v0.autopilot.position_ready(fleet.clock.time()), what="position estimate")
            await v.set_mode("GUIDED")
            await wait_until_async(lambda: v.state.mode == "GUIDED", what="GUIDED in telemetry")
            assert boot_mode != "GUIDED"

            hb_args = (mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                       mav.MAV_MODE_FLAG_SAFETY_ARMED | 1, 0, mav.MAV_STATE_ACTIVE, 3)
            pos_args = (0, 100.0, 100.0, -50.0, 0.0, 0.0, 0.0)
            intruder = apply_signing(mav.MAVLink(None, 1, 1), SigningConfig(OTHER_KEY).new_state(
                fleet.clock.time() + 1.0))
            unsigned = mav.MAVLink(None, 1, 1)
            frames = captured[:2] + [
                intruder.heartbeat_encode(*hb_args).pack(intruder),
                intruder.local_position_ned_encode(*pos_args).pack(intruder),
                unsigned.heartbeat_encode(*hb_args).pack(unsigned),
                unsigned.local_position_ned_encode(*pos_args).pack(unsigned)]
            before = {k: ep.counters[k] for k in GCS_REJECTIONS}
            for frame in frames:
                sniffer.sendto(frame, ("127.0.0.1", v0.udp_send_port))
            expected = {"replayed": 2, "bad_signature": 2, "unsigned": 2}
            await wait_until_async(lambda: all(ep.counters[k] - before[k] >= n for k, n in expected.items()),
                                   what="the injected frames to be counted")
            # genuine telemetry (a heartbeat and a position) received after the injection: the
            # counts below then also show that genuine frames were not rejected
            counted_at = fleet.clock.time()
            await wait_until_async(lambda: v.state.last_heartbeat_s > counted_at
                                   and (v.state.last_position_s or -1.0) > counted_at,
                                   what="genuine telemetry after the injection")
            assert {k: ep.counters[k] - before[k] for k in GCS_REJECTIONS} == expected
            assert v.state.mode == "GUIDED" and not v.state.armed
            assert abs(v.state.position_ned_m[0]) < 5.0
            assert v.errors == [] and ep.errors == []  # no "duplicate system id" from the intruder
        finally:
            sniffer.close()
            await v.close()
            await ep.close()

    with fleet:
        asyncio.run(main())
    assert fleet.errors == []


@pytest.mark.parametrize("vehicle_key,setup,match", [
    (OTHER_KEY, True, "signed with another key"),
    (None, False, "sends unsigned frames"),
], ids=["other_key", "unsigned_without_setup"])
def test_a_vehicle_that_never_signs_with_our_key_is_a_clear_error(vehicle_key, setup, match):
    fleet = _fleet(signing_key=vehicle_key)

    async def main():
        v0 = fleet.vehicles[0]
        config = SigningConfig(KEY, send_setup=setup)
        ep = await MavEndpoint.open(f"udpin:127.0.0.1:{v0.udp_send_port}", clock=fleet.clock,
                                    signing=config)
        try:
            with pytest.raises(LinkError, match=match):
                await VehicleLink.create(ep, 1, clock=fleet.clock, mission_origin=fleet.origin,
                                         heartbeat_timeout_s=4.0)
            assert ep.counters["setup_signing_sent"] == 0
            assert not v0.armed and v0.autopilot.counters["signing_setup_accepted"] == 0
        finally:
            await ep.close()

    with fleet:
        asyncio.run(main())
