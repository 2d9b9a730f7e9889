"""mission.vehicle.vehicle_link against the small fake autopilot: commands, sequences, frames, streaming."""
from __future__ import annotations

import asyncio
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from formation.geodesy import enu_to_geodetic, enu_to_ned, geodetic_to_enu
from mission.core.clock import WallClock, wait_on_clock
from mission.link.endpoint import MavEndpoint
from mission.vehicle.streamer import SetpointStreamer
from mission.vehicle.state import CommandError, command_name
from mission.vehicle.vehicle_link import VehicleLink
from tests.support.fake_autopilot import FakeAutopilot, FakeUdpVehicle
from mission.vehicle.frames import MissionToLocal, mode_name, resolve_mode
from tests.support.wait_helpers import wait_until_async

ORIGIN = (45.0, 5.0, 200.0)
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM


def _run(coro, timeout_s: float = 60.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


async def _with_vehicles(aps, body, *, telemetry_hz: float = 5.0, **link_kwargs):
    """Run ``body(vehicles, aps)`` with one fake UDP socket per autopilot."""
    clock = WallClock()
    ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock)
    fakes = [await FakeUdpVehicle([ap], ep.local_address, telemetry_hz=telemetry_hz).start() for ap in aps]
    try:
        vehicles = [await VehicleLink.create(ep, ap.sysid, clock=clock, mission_origin=ORIGIN, **link_kwargs)
                    for ap in aps]
        return await body(vehicles, aps)
    finally:
        for fake in fakes:
            await fake.stop()
        await ep.close()


@pytest.mark.parametrize("drops", [0, 1, 2])
def test_command_retries_increment_confirmation_until_acked(drops):
    async def body(vehicles, aps):
        result = await vehicles[0].command_long(ARM, 1, timeout_s=1.0, retries=3)
        assert result == mavlink.MAV_RESULT_ACCEPTED
        assert [c.confirmation for c in aps[0].commands] == list(range(drops + 1))
        assert aps[0].armed
    _run(_with_vehicles([FakeAutopilot(1, drop_first={ARM: drops})], body))


def test_command_timeout_names_vehicle_and_command():
    async def body(vehicles, aps):
        with pytest.raises(CommandError, match=r"vehicle 1 \(ardupilot on udpin:127.0.0.1:0\): "
                                               r"MAV_CMD_COMPONENT_ARM_DISARM not acknowledged after 3 attempts") as info:
            await vehicles[0].command_long(ARM, 1, timeout_s=0.2, retries=2)
        assert (info.value.sysid, info.value.command, info.value.result) == (1, ARM, None)
        assert len(aps[0].commands) == 3
    _run(_with_vehicles([FakeAutopilot(1, drop_first={ARM: 99})], body))


@pytest.mark.parametrize("result, name", [
    (mavlink.MAV_RESULT_DENIED, "DENIED"),
    (mavlink.MAV_RESULT_UNSUPPORTED, "UNSUPPORTED"),
    (mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "TEMPORARILY_REJECTED"),
])
def test_command_refusal_is_reported_once_without_retry(result, name):
    async def body(vehicles, aps):
        with pytest.raises(CommandError, match=f"vehicle 2 .*MAV_CMD_COMPONENT_ARM_DISARM failed: {name}") as info:
            await vehicles[0].arm()
        assert info.value.result == result
        assert len(aps[0].commands) == 1
        assert await vehicles[0].command_long(ARM, 1, accept=(result,)) == result
    _run(_with_vehicles([FakeAutopilot(2, results={ARM: result})], body))


def test_in_progress_extends_the_wait_without_resending():
    async def body(vehicles, aps):
        # the final ACK comes 1.5 s after IN_PROGRESS, well after timeout_s
        result = await vehicles[0].command_long(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5,
                                                timeout_s=0.5, retries=3)
        assert result == mavlink.MAV_RESULT_ACCEPTED
        assert len(aps[0].commands) == 1
    ap = FakeAutopilot(3, in_progress={mavlink.MAV_CMD_NAV_TAKEOFF}, in_progress_delay_s=1.5)
    _run(_with_vehicles([ap], body))


def test_too_many_params_is_a_value_error():
    async def body(vehicles, aps):
        with pytest.raises(ValueError, match="at most 7 parameters, got 8"):
            await vehicles[0].command_long(ARM, *range(8))
    _run(_with_vehicles([FakeAutopilot(1)], body))


@pytest.mark.parametrize("flavour, expected", [
    ("ardupilot", [(mavlink.MAV_CMD_DO_SET_MODE, 4.0), (ARM, 1.0), (mavlink.MAV_CMD_NAV_TAKEOFF, 0.0)]),
    ("px4", [(mavlink.MAV_CMD_DO_SET_MODE, 6.0), (ARM, 1.0)]),
])
def test_takeoff_sequence_per_flavour(flavour, expected):
    async def body(vehicles, aps):
        v, ap = vehicles[0], aps[0]
        await v.wait_home(10.0)
        await wait_until_async(lambda: v.position_enu_m() is not None, what="position")
        await v.takeoff(12.0)
        got = [(c.command, c.param2 if c.command == mavlink.MAV_CMD_DO_SET_MODE else c.param1) for c in ap.commands
               if c.command != mavlink.MAV_CMD_REQUEST_MESSAGE]
        assert got == expected
        await wait_until_async(lambda: v.state.armed, what="armed in telemetry")
        if flavour == "px4":
            # setpoints at the current position, 12 m up, streamed before OFFBOARD was asked for
            assert ap.setpoints and ap.setpoints[0].z == pytest.approx(-12.0, abs=1e-3)
            assert v.state.mode == "OFFBOARD"
            n_before = ap.setpoint_count
            await wait_until_async(lambda: ap.setpoint_count >= n_before + 3, what="hold stream")
            assert v.hold_streaming
            # a streamer taking over ends the hold stream
            for _ in range(100):
                v.send_position_enu([0.0, 0.0, 12.0])
                await asyncio.sleep(0.05)
                if not v.hold_streaming:
                    break
            assert not v.hold_streaming
            await v.land()
            assert ap.custom_mode == (4 << 16) | (6 << 24)
        else:
            assert ap.commands[-1].param7 == pytest.approx(12.0)
            assert v.state.mode == "GUIDED"
            await v.rtl()
            assert ap.custom_mode == 6
    _run(_with_vehicles([FakeAutopilot(4, flavour=flavour)], body))


@pytest.mark.parametrize("flavour, name, custom_mode", [
    ("ardupilot", "GUIDED", 4), ("ardupilot", "hold", 5), ("ardupilot", "LAND", 9),
    ("px4", "OFFBOARD", 6 << 16), ("px4", "HOLD", (4 << 16) | (3 << 24)), ("px4", "RTL", (4 << 16) | (5 << 24)),
])
def test_mode_names_round_trip(flavour, name, custom_mode):
    canonical, p2, p3 = resolve_mode(flavour, name)
    packed = int(p2) if flavour == "ardupilot" else (int(p2) << 16) | (int(p3) << 24)
    assert packed == custom_mode
    assert mode_name(flavour, custom_mode) == canonical


@pytest.mark.parametrize("flavour, name, match", [
    ("ardupilot", "OFFBOARD", "unknown ardupilot mode 'OFFBOARD'"),
    ("px4", "GUIDED", "unknown px4 mode 'GUIDED'"),
    ("generic", "LAND", "cannot set modes on a 'generic' autopilot"),
])
def test_unknown_modes_are_rejected(flavour, name, match):
    with pytest.raises(ValueError, match=match):
        resolve_mode(flavour, name)


def test_set_mode_unknown_name_is_a_command_error_without_sending():
    async def body(vehicles, aps):
        with pytest.raises(CommandError, match="vehicle 1 .*unknown ardupilot mode 'WARP'"):
            await vehicles[0].set_mode("WARP")
        assert aps[0].commands == []
    _run(_with_vehicles([FakeAutopilot(1)], body))


@settings(max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(-3000, 3000)] * 2, st.floats(-50, 500)),
       st.tuples(st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(-30, 30)))
def test_mission_to_local_matches_exact_geodesy(p_enu, home_offset_enu):
    home = tuple(float(v) for v in enu_to_geodetic(np.array(home_offset_enu), ORIGIN))
    fmap = MissionToLocal(ORIGIN, home)
    n, e, d = fmap.mission_enu_to_local_ned(*p_enu)
    exact = enu_to_ned(geodetic_to_enu(*enu_to_geodetic(np.array(p_enu), ORIGIN), home))
    assert np.allclose([n, e, d], exact, atol=1e-6)
    assert np.allclose(fmap.local_ned_to_mission_enu(n, e, d), p_enu, atol=1e-6)


@pytest.mark.parametrize("frame", ["local_ned", "global_int"])
def test_setpoints_land_in_each_vehicles_own_frame_when_homes_differ(frame):
    homes_enu = [(0.0, 0.0, 0.0), (40.0, -25.0, 3.0)]
    homes = [tuple(float(v) for v in enu_to_geodetic(np.array(h), ORIGIN)) for h in homes_enu]
    aps = [FakeAutopilot(1, home=homes[0]), FakeAutopilot(2, home=homes[1])]
    target = np.array([10.0, 20.0, 15.0])

    async def body(vehicles, aps):
        for v in vehicles:
            await v.wait_home(10.0)
            v.send_position_enu(target, yaw_rad=math.pi / 2)
        await wait_until_async(lambda: all(ap.setpoints for ap in aps), what="setpoints")
        for ap, home_enu in zip(aps, homes_enu):
            sp = ap.setpoints[0]
            assert sp.yaw == pytest.approx(math.pi / 2)
            if frame == "local_ned":
                # HOME_POSITION carries 1e-7 deg and mm: the home is known to about 1 cm
                assert np.allclose([sp.x, sp.y, sp.z], enu_to_ned(target - np.array(home_enu)), atol=0.015)
            else:
                got = geodetic_to_enu(sp.lat_int * 1e-7, sp.lon_int * 1e-7, sp.alt, ORIGIN)
                assert np.allclose(got, target, atol=0.02)
        # the fakes apply LOCAL_NED setpoints at once: telemetry then puts both at the target
        if frame == "local_ned":
            await wait_until_async(lambda: all(v.position_fresh()
                                               and np.allclose(v.position_enu_m(), target, atol=0.02)
                                               for v in vehicles), what="telemetry at the target")
    _run(_with_vehicles(aps, body, setpoint_frame=frame))


def test_setpoint_before_home_is_a_clear_error():
    async def body(vehicles, aps):
        with pytest.raises(CommandError, match="vehicle 1 .*no home yet"):
            vehicles[0].send_position_enu([0.0, 0.0, 5.0])
    _run(_with_vehicles([FakeAutopilot(1)], body))


def test_telemetry_fills_the_state_and_message_rates_are_requested():
    async def body(vehicles, aps):
        v = vehicles[0]
        await v.wait_for(lambda s: s.landed is not None and s.position_ok and s.battery_remaining_pct is not None,
                         10.0, "telemetry")
        snap = v.state.snapshot()
        assert (snap.sysid, snap.flavour, snap.armed, snap.landed) == (8, "px4", False, True)
        assert snap.battery_remaining_pct == 87.0 and snap.lat_deg == pytest.approx(ORIGIN[0])
        assert v.link_age_s() < 5.0
        await v.set_message_rates({"GLOBAL_POSITION_INT": 5, "SYS_STATUS": 0})
        sent = [(c.command, int(c.param1), c.param2) for c in aps[0].commands]
        assert sent == [(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 200000.0),
                        (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 1, -1.0)]
        with pytest.raises(ValueError, match="unknown MAVLink message 'NOT_A_MESSAGE'"):
            await v.set_message_rates({"NOT_A_MESSAGE": 1})
        with pytest.raises(CommandError, match="vehicle 8 .*timed out after 0.2 s waiting for flying"):
            await v.wait_for(lambda s: s.landed is False, 0.2, "flying")
    _run(_with_vehicles([FakeAutopilot(8, flavour="px4")], body))


def test_autopilot_version_uid():
    async def body(vehicles, aps):
        assert await vehicles[0].request_autopilot_version() == 0xABCDEF
        assert vehicles[0].uid == 0xABCDEF
    _run(_with_vehicles([FakeAutopilot(1, uid=0xABCDEF)], body))


def test_streamer_feeds_every_vehicle_and_reports_stats():
    aps = [FakeAutopilot(s) for s in (1, 2, 3)]

    async def body(vehicles, aps):
        for v in vehicles[:2]:
            await v.wait_home(10.0)
        streamer = SetpointStreamer(vehicles, rate_hz=20.0, clock=WallClock())
        for v in vehicles:   # vehicle 3 has no home yet: counted errors, the others unaffected
            streamer.set_target(v.sysid, [1.0, 2.0, 3.0])
        await streamer.start()
        try:
            await wait_until_async(lambda: all(ap.setpoint_count >= 10 for ap in aps[:2]), what="streamed setpoints")
            streamer.remove(2)
            count_2 = aps[1].setpoint_count
            await wait_until_async(lambda: aps[0].setpoint_count >= 20, what="more setpoints")
        finally:
            await streamer.stop()
        assert aps[1].setpoint_count <= count_2 + 1
        assert aps[2].setpoint_count == 0
        stats = streamer.stats(1)
        assert stats["sent"] >= 20 and stats["errors"] == 0
        assert 0.0 < stats["p50_interval_s"] <= stats["p99_interval_s"]
        assert streamer.stats(3)["errors"] >= 1 and "no home yet" in streamer.stats(3)["last_error"]
        with pytest.raises(KeyError, match="vehicle 42 is not in this streamer"):
            streamer.set_target(42, [0, 0, 0])
        with pytest.raises(ValueError, match="must be finite"):
            streamer.set_target(1, [0, float("nan"), 0])
    _run(_with_vehicles(aps, body))


def test_command_name():
    assert command_name(mavlink.MAV_CMD_NAV_TAKEOFF) == "MAV_CMD_NAV_TAKEOFF"
    assert command_name(65000) == "MAV_CMD(65000)"


def test_wait_on_clock_returns_result_or_times_out():
    async def scenario():
        assert await wait_on_clock(asyncio.sleep(0, result=5), 1.0, WallClock()) == 5
        with pytest.raises(TimeoutError, match="timed out after 0.05 s"):
            await wait_on_clock(asyncio.Event().wait(), 0.05, WallClock())
    _run(scenario())


def _attached(clock=None):
    """An endpoint (transport not opened) with an ArduPilot vehicle 3 heard and attached."""
    from mission.core.uri import parse_connection

    clock = clock or WallClock()
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=clock, heartbeat_hz=0)
    ap = FakeAutopilot(3)
    ep.receive_datagram(ap.encode(ap.heartbeat()), ("127.0.0.1", 9))
    v = VehicleLink(ep, 3, ep.last_heartbeat(3), clock=clock, mission_origin=ORIGIN)
    ep.attach(3, v._on_message, v._on_link_error)
    return ep, v, ap


@pytest.mark.parametrize("bad, name", [
    (mavlink.MAVLink_local_position_ned_message(0, math.nan, 0, -10, 0, 0, 0), "LOCAL_POSITION_NED"),
    (mavlink.MAVLink_local_position_ned_message(0, 1e9, 0, -10, 0, 0, 0), "LOCAL_POSITION_NED"),
    (mavlink.MAVLink_local_position_ned_message(0, 1, 0, -10, math.inf, 0, 0), "LOCAL_POSITION_NED"),
    (mavlink.MAVLink_home_position_message(451900000, 57200000, 230000, 1e30, 0, 0, [1, 0, 0, 0], 0, 0, 0),
     "HOME_POSITION"),
    (mavlink.MAVLink_home_position_message(451900000, 57200000, 230000, math.nan, 0, 0, [1, 0, 0, 0], 0, 0, 0),
     "HOME_POSITION"),
    (mavlink.MAVLink_home_position_message(951900000, 57200000, 230000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0),
     "HOME_POSITION"),
    (mavlink.MAVLink_global_position_int_message(0, 951900000, 57200000, 230000, 0, 0, 0, 0, 0),
     "GLOBAL_POSITION_INT"),
])
def test_impossible_telemetry_is_rejected_and_counted(bad, name):
    ep, v, ap = _attached()
    good_home = ap.home_position()
    ep.receive_datagram(ap.encode(good_home) + ap.encode(mavlink.MAVLink_local_position_ned_message(0, 1, 2, -10, 0, 0, 0)),
                        ("127.0.0.1", 9))
    before = (v.position_enu_m().copy(), v.state.home, v.frame_map)
    ep.receive_datagram(ap.encode(bad), ("127.0.0.1", 9))
    assert v.rejected == {name: 1} and name in v.last_rejection
    assert np.array_equal(v.position_enu_m(), before[0]) and np.all(np.isfinite(v.position_enu_m()))
    assert (v.state.home, v.frame_map) == before[1:]
    assert ep.counters["frames_in"] == 4 and ep.counters["handler_errors"] == 0


def test_a_raising_handler_is_counted_and_the_link_goes_on():
    ep, v, ap = _attached()

    def broken(msg):
        raise RuntimeError("boom")

    v._handlers[mavlink.MAVLINK_MSG_ID_SYS_STATUS] = broken
    ep.receive_datagram(b"".join(ap.encode(m) for m in ap.slow_telemetry()), ("127.0.0.1", 9))
    assert ep.counters["handler_errors"] == 1 and "SYS_STATUS from 3: RuntimeError: boom" in ep.last_handler_error
    assert v.state.landed is True          # EXTENDED_SYS_STATE after the broken one still arrived


def test_position_is_converted_once_per_message_and_callers_cannot_corrupt_it():
    ep, v, ap = _attached()
    ep.receive_datagram(ap.encode(ap.home_position()) + ap.encode(mavlink.MAVLink_local_position_ned_message(0, 1, 2, -10, 0, 0, 0)),
                        ("127.0.0.1", 9))
    first = v.position_enu_m()
    expected = v.frame_map.local_ned_to_mission_enu(1.0, 2.0, -10.0)
    assert np.allclose(first, expected, atol=1e-12)
    first += 100.0  # a caller's in-place change must not leak into the next answer
    assert np.allclose(v.position_enu_m(), expected, atol=1e-12)
    ep.receive_datagram(ap.encode(mavlink.MAVLink_local_position_ned_message(0, 4, -3, -12, 0, 0, 0)), ("127.0.0.1", 9))
    assert np.allclose(v.position_enu_m(), v.frame_map.local_ned_to_mission_enu(4.0, -3.0, -12.0), atol=1e-12)
    assert not np.allclose(v.position_enu_m(), expected)


class _SetClock:
    """A clock that stays where the test puts it."""

    def __init__(self, t_s: float) -> None:
        self.t_s = t_s

    def time(self) -> float:
        return self.t_s


def test_setpoint_time_boot_ms_is_the_injected_clocks_time_since_the_link_opened():
    clock = _SetClock(1_767_225_600.0)
    ep, v, ap = _attached(clock)
    ep.receive_datagram(ap.encode(ap.home_position()), ("127.0.0.1", 9))
    sent = []
    ep.send_setpoint = lambda sysid, framer, t_ms, *fields: sent.append(framer.frame(0, t_ms, *fields)) or True
    for elapsed_s in (0.0, 2.5, 3600.25):
        clock.t_s = 1_767_225_600.0 + elapsed_s
        v.send_position_enu([0.0, 0.0, 5.0])
    stamps_ms = [struct.unpack_from("<I", frame, 10)[0] for frame in sent]
    assert stamps_ms == [0, 2500, 3600250]
