"""MAVSDK 4.x (an independent MAVLink client) flies the PX4 personality.

Connect, read telemetry, arm, take off, start offboard with position setpoints, see the vehicle
move, stop offboard, land. The mock runs on the wall clock at 2x while MAVSDK streams offboard
setpoints at 20 Hz of wall time. PX4's default offboard-loss timeout (``COM_OF_LOSS_T`` 1 s) is
then half a wall second: on a loaded host (CI runs the suite with ``-n 2`` on 2 cores) a stall of
the setpoint stream that long is ordinary, and the autopilot rightly falls back to Hold
(``AUTO.LOITER``) before the test asked for it. These tests are about MAVSDK's interoperability,
not that failsafe (tests/sitl_mock/test_mock_autopilot.py covers it), so the PX4 vehicle gets a loss timeout
a loaded host can meet, and the test checks that no failsafe fired.

Every wait is a condition poll with a generous wall-clock timeout (:data:`WAIT_S`): the mock's
simulated time, hence its progress, slows down with the host.
"""
from __future__ import annotations


import pytest
from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.offboard import Offboard, PositionNedYaw
from mavsdk.plugins.telemetry import FlightMode, Telemetry

from sitl_mock.fleet import MockFleet
from tests.support.wait_helpers import wait_until
from mission.sim.embedded import free_port_block

#: wall seconds for any one condition (a loaded 2-core host, the simulation at 2x)
WAIT_S = 90.0
#: PX4 offboard-loss timeout for these tests: 10 simulated s = 5 wall s at 2x (PX4 allows 0-60)
OFFBOARD_LOSS_T_S = 10.0


def _free_udp_port() -> int:
    return free_port_block(1, kinds=("udp",))


@pytest.mark.slow
def test_mavsdk_px4_connect_telemetry_arm_takeoff_offboard():
    send_port, bind_port = _free_udp_port(), _free_udp_port()
    fleet = MockFleet(1, personality="px4", speedup=2.0, udp_base_port=send_port,
                      udp_bind_base_port=bind_port, tcp_base_port=0,
                      params={"MIS_TAKEOFF_ALT": 5.0, "COM_OF_LOSS_T": OFFBOARD_LOSS_T_S})
    with fleet:
        vehicle = fleet.vehicles[0]
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"udpin://127.0.0.1:{send_port}") == ConnectionResult.SUCCESS
            system = sdk.first_autopilot(WAIT_S)
            assert system is not None
            telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)
            wait_until(lambda: telemetry.health().is_global_position_ok
                       and telemetry.health().is_home_position_ok, WAIT_S, "health ok")
            pos = telemetry.position()
            assert pos.latitude_deg == pytest.approx(vehicle.home_geodetic[0], abs=1e-6)
            assert pos.absolute_altitude_m == pytest.approx(vehicle.home_geodetic[2], abs=0.1)
            action.arm()
            wait_until(telemetry.armed, WAIT_S, "armed")
            action.takeoff()
            wait_until(lambda: telemetry.position().relative_altitude_m > 4.5, WAIT_S, "takeoff to 5 m")
            offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -5.0, 0.0))
            offboard.start()
            wait_until(lambda: telemetry.flight_mode() == FlightMode.OFFBOARD, WAIT_S, "offboard mode")
            offboard.set_position_ned(PositionNedYaw(8.0, -4.0, -6.0, 0.0))

            def arrived():
                p = telemetry.position_velocity_ned().position
                return abs(p.north_m - 8.0) < 0.5 and abs(p.east_m + 4.0) < 0.5
            wait_until(arrived, WAIT_S, "vehicle to reach the offboard setpoint")
            assert (vehicle.mode_name, vehicle.autopilot.failsafe) == ("OFFBOARD", None)
            offboard.stop()  # MAVSDK stops the setpoints and commands Hold
            assert (vehicle.mode_name, vehicle.autopilot.failsafe) == ("AUTO.LOITER", None)
            assert not offboard.is_active()
            action.land()
            wait_until(lambda: not telemetry.armed(), WAIT_S, "landing and disarm")
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
            system = sdk.first_autopilot(WAIT_S)
            assert system is not None
            telemetry, action = Telemetry(system), Action(system)
            wait_until(lambda: telemetry.health().is_global_position_ok
                       and telemetry.health().is_home_position_ok, WAIT_S, "health ok")
            action.set_takeoff_altitude(6.0)
            action.arm()
            wait_until(telemetry.armed, WAIT_S, "armed")
            action.takeoff()  # MAVSDK switches ArduCopter to GUIDED, then NAV_TAKEOFF
            wait_until(lambda: telemetry.position().relative_altitude_m > 5.5, WAIT_S, "takeoff to 6 m")
            assert vehicle.mode_name == "GUIDED"
            p = telemetry.position()
            action.goto_location(p.latitude_deg + 5e-5, p.longitude_deg, p.absolute_altitude_m, 0.0)
            wait_until(lambda: vehicle.true_position_ned()[0] > 5.0, WAIT_S, "goto to move north")
            action.land()
            wait_until(lambda: not telemetry.armed(), WAIT_S, "landing and disarm")
            assert vehicle.mode_name == "LAND" and vehicle.dynamics.landed
        finally:
            sdk.destroy()
    assert fleet.errors == []
