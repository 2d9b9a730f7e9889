"""MAVSDK 4.x (an independent MAVLink client) flies the PX4 personality.

Connect, read telemetry, arm, take off, start offboard with position setpoints, see the vehicle
move. The mock runs on the wall clock at 2x (MAVSDK streams offboard setpoints on the wall clock,
fast enough for PX4's offboard-loss timeout at that speed-up).
"""
from __future__ import annotations

import socket

import pytest
from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.offboard import Offboard, PositionNedYaw
from mavsdk.plugins.telemetry import FlightMode, Telemetry

from sitl_mock.fleet import MockFleet
from wait_helpers import wait_until


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.slow
def test_mavsdk_px4_connect_telemetry_arm_takeoff_offboard():
    send_port, bind_port = _free_udp_port(), _free_udp_port()
    fleet = MockFleet(1, personality="px4", speedup=2.0, udp_base_port=send_port,
                      udp_bind_base_port=bind_port, tcp_base_port=0,
                      params={"MIS_TAKEOFF_ALT": 5.0})
    with fleet:
        vehicle = fleet.vehicles[0]
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"udpin://127.0.0.1:{send_port}") == ConnectionResult.SUCCESS
            system = sdk.first_autopilot(15.0)
            assert system is not None
            telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)
            wait_until(lambda: telemetry.health().is_global_position_ok
                       and telemetry.health().is_home_position_ok, 20.0, "health ok")
            pos = telemetry.position()
            assert pos.latitude_deg == pytest.approx(vehicle.home_geodetic[0], abs=1e-6)
            assert pos.absolute_altitude_m == pytest.approx(vehicle.home_geodetic[2], abs=0.1)
            action.arm()
            wait_until(telemetry.armed, 10.0, "armed")
            action.takeoff()
            wait_until(lambda: telemetry.position().relative_altitude_m > 4.5, 20.0, "takeoff to 5 m")
            offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -5.0, 0.0))
            offboard.start()
            wait_until(lambda: telemetry.flight_mode() == FlightMode.OFFBOARD, 10.0, "offboard mode")
            offboard.set_position_ned(PositionNedYaw(8.0, -4.0, -6.0, 0.0))

            def arrived():
                p = telemetry.position_velocity_ned().position
                return abs(p.north_m - 8.0) < 0.5 and abs(p.east_m + 4.0) < 0.5
            wait_until(arrived, 30.0, "vehicle to reach the offboard setpoint")
            assert vehicle.mode_name == "OFFBOARD"
            offboard.stop()
            action.land()
            wait_until(lambda: not telemetry.armed(), 40.0, "landing and disarm")
        finally:
            sdk.destroy()
    assert fleet.errors == []


@pytest.mark.slow
def test_mavsdk_ardupilot_connect_arm_takeoff_goto_land():
    send_port, bind_port = _free_udp_port(), _free_udp_port()
    fleet = MockFleet(1, personality="ardupilot", speedup=2.0, udp_base_port=send_port,
                      udp_bind_base_port=bind_port, tcp_base_port=0)
    with fleet:
        vehicle = fleet.vehicles[0]
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"udpin://127.0.0.1:{send_port}") == ConnectionResult.SUCCESS
            system = sdk.first_autopilot(15.0)
            assert system is not None
            telemetry, action = Telemetry(system), Action(system)
            wait_until(lambda: telemetry.health().is_global_position_ok
                       and telemetry.health().is_home_position_ok, 20.0, "health ok")
            action.set_takeoff_altitude(6.0)
            action.arm()
            wait_until(telemetry.armed, 10.0, "armed")
            action.takeoff()  # MAVSDK switches ArduCopter to GUIDED, then NAV_TAKEOFF
            wait_until(lambda: telemetry.position().relative_altitude_m > 5.5, 20.0, "takeoff to 6 m")
            assert vehicle.mode_name == "GUIDED"
            p = telemetry.position()
            action.goto_location(p.latitude_deg + 5e-5, p.longitude_deg, p.absolute_altitude_m, 0.0)
            wait_until(lambda: vehicle.true_position_ned()[0] > 5.0, 20.0, "goto to move north")
            action.land()
            wait_until(lambda: not telemetry.armed(), 40.0, "landing and disarm")
            assert vehicle.mode_name == "LAND" and vehicle.dynamics.landed
        finally:
            sdk.destroy()
    assert fleet.errors == []
