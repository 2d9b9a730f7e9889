"""The autopilots' wind estimate: the mock publishes it (PX4 WIND_COV, ArduPilot WIND) with the
firmware's conventions and rates, the ground station decodes it into the vehicle snapshot, and
:func:`mission.flight.wind_prior.fleet_wind_prior` turns the fleet's estimates into a prior."""
from __future__ import annotations

import asyncio
import math
import types

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

import sitl_mock.clock as clock_mod
import sitl_mock.fleet as fleet_mod
from mission.flight.wind_prior import WindPrior, fleet_wind_prior
from mission.link.endpoint import MavEndpoint
from mission.link.endpoint_registry import SysidRegistry
from wire.fast_decode import FAST_MSG_IDS, decode_single_frame
from mission.sim.embedded import free_port_block
from mission.vehicle.state import VehicleState, VehicleTelemetry
from mission.vehicle.vehicle_link import VehicleLink
from mission.vehicle.wind import WindEstimate, decode_wind, decode_wind_cov, wind_rates_hz
from sitl_mock.ap_wind import (ERROR_STD_M_S, WindEstimateModel, wind_cov_fields, wind_fields,
                               wind_ned_from_met, world_wind_ned_m_s)
from sitl_mock.autopilot import MockAutopilot
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter
from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_plume import GaussianPlume
from sitl_mock.transport import make_parser

ORIGIN = (45.19, 5.72, 230.0)
DT = 0.02
WEST_3 = (270.0, 3.0)   # a wind from the west at 3 m/s: the air moves east


def _roundtrip(msg):
    """Pack with a vehicle's encoder and parse it back as the ground station does (both paths)."""
    frame = msg.pack(mav.MAVLink(None, srcSystem=1, srcComponent=1))
    slow = make_parser().parse_buffer(frame)[0]
    fast = decode_single_frame(frame)
    if FAST_MSG_IDS:   # fastcrc installed: the fast path decodes the wind messages too
        assert fast is not None and fast.to_dict() == slow.to_dict()
    return slow


# ------------------------------------------------------------------ conventions, both ways
def test_a_west_wind_in_each_message():
    ned = wind_ned_from_met(*WEST_3)
    assert ned == pytest.approx((0.0, 3.0, 0.0), abs=1e-12)
    cov = wind_cov_fields(ned, 500.0)
    assert (cov["wind_x"], cov["wind_y"], cov["wind_z"]) == pytest.approx((0.0, 3.0, 0.0), abs=1e-12)
    wind = wind_fields(ned)
    assert wind["direction"] == pytest.approx(-90.0)   # ArduPilot: degrees(atan2(-y, -x)), -180..180
    assert wind["speed"] == pytest.approx(3.0)


@pytest.mark.parametrize("from_deg, speed_m_s", [(270.0, 3.0), (0.0, 2.0), (45.0, 1.0), (180.0, 4.0),
                                                 (359.0, 0.7)])
def test_mock_messages_decode_to_the_true_wind(from_deg, speed_m_s):
    ned = wind_ned_from_met(from_deg, speed_m_s)
    enc = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    cov = wind_cov_fields(ned, 500.0)
    msgs = [enc.wind_cov_encode(0, cov["wind_x"], cov["wind_y"], cov["wind_z"], cov["var_horiz"],
                                cov["var_vert"], cov["wind_alt"], 0.0, 0.0),
            enc.wind_encode(**wind_fields(ned))]
    for msg, decode in zip(msgs, (decode_wind_cov, decode_wind)):
        est = decode(_roundtrip(msg), 12.0)
        assert math.isclose(est.speed_m_s, speed_m_s, rel_tol=1e-6)
        assert abs((est.from_deg - from_deg + 180.0) % 360.0 - 180.0) < 1e-4
        assert 0.0 <= est.from_deg < 360.0 and est.time_s == 12.0


@pytest.mark.parametrize("fields, decode", [
    ({"wind_x": 0.0, "wind_y": 3.0, "wind_z": 0.0}, decode_wind_cov),     # PX4: velocity toward east
    ({"direction": -90.0, "speed": 3.0, "speed_z": 0.0}, decode_wind),     # ArduPilot's -180..180
    ({"direction": 270.0, "speed": 3.0, "speed_z": 0.0}, decode_wind),     # or 0..360
])
def test_ground_station_reads_a_west_wind(fields, decode):
    est = decode(types.SimpleNamespace(**fields), 0.0)
    assert est.from_deg == pytest.approx(270.0) and est.speed_m_s == pytest.approx(3.0)
    assert est.toward_en_m_s() == pytest.approx((3.0, 0.0), abs=1e-12)


def test_wind_speed_is_horizontal_when_ardupilot_sends_the_3d_length():
    est = decode_wind(types.SimpleNamespace(direction=90.0, speed=5.0, speed_z=3.0), 0.0)
    assert est.speed_m_s == pytest.approx(4.0) and est.down_m_s == 3.0


@pytest.mark.parametrize("message, fields", [
    ("WIND_COV", {"wind_x": math.nan, "wind_y": 3.0, "wind_z": 0.0}),
    ("WIND_COV", {"wind_x": 0.0, "wind_y": math.inf, "wind_z": 0.0}),
    ("WIND_COV", {"wind_x": 0.0, "wind_y": 1e6, "wind_z": 0.0}),
    ("WIND", {"direction": math.nan, "speed": 3.0, "speed_z": 0.0}),
    ("WIND", {"direction": 270.0, "speed": -1.0, "speed_z": 0.0}),
    ("WIND", {"direction": 270.0, "speed": 3.0, "speed_z": math.nan}),
    ("WIND", {"direction": 9999.0, "speed": 3.0, "speed_z": 0.0}),
])
def test_bad_wind_frames_are_counted_rejections(message, fields):
    tel = VehicleTelemetry()
    tel.state = VehicleState(sysid=1, flavour="px4")
    tel.clock = types.SimpleNamespace(time=lambda: 5.0)
    tel.rejected, tel.last_rejection = {}, None
    good = WindEstimate(270.0, 3.0, 0.0, 1.0, message)
    tel.state.wind = good
    enc = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    if message == "WIND_COV":
        msg = enc.wind_cov_encode(0, fields["wind_x"], fields["wind_y"], fields["wind_z"], 0, 0, 0, 0, 0)
        tel._on_wind_cov(msg)
    else:
        msg = enc.wind_encode(fields["direction"], fields["speed"], fields["speed_z"])
        tel._on_wind(msg)
    assert tel.rejected == {message: 1}
    assert tel.last_rejection.startswith(message + ":")
    assert tel.state.wind is good   # the last good estimate stays


def test_ground_station_asks_each_autopilot_for_its_own_message():
    assert wind_rates_hz("px4") == {"WIND_COV": 1.0}
    assert wind_rates_hz("ardupilot") == {"WIND": 1.0}
    assert wind_rates_hz("generic") == {}


# ------------------------------------------------------------------ the mock's estimate
def test_estimate_error_has_the_documented_size_and_is_slow():
    model = WindEstimateModel((0.0, 3.0, 0.0), np.random.default_rng(7))
    samples = np.array([model.estimate_ned_m_s(60.0 * k)[:2] for k in range(3000)]) - (0.0, 3.0)
    assert np.std(samples, axis=0) == pytest.approx([ERROR_STD_M_S] * 2, rel=0.1)
    model = WindEstimateModel((0.0, 3.0, 0.0), np.random.default_rng(7))
    a = np.array(model.estimate_ned_m_s(0.0))
    b = np.array(model.estimate_ned_m_s(1.0))
    assert np.linalg.norm(a - b) < 0.2   # an EKF's wind wanders, it does not jitter
    assert model.estimate_ned_m_s(1.0) == tuple(b)   # the same time: the same estimate


@pytest.mark.parametrize("field, expected_ned", [
    (GaussianPlume(wind_from_deg=270.0, wind_speed_m_s=3.0), (0.0, 3.0, 0.0)),
    (FilamentPlume(wind_from_deg=0.0, wind_speed_m_s=2.0), (-2.0, 0.0, 0.0)),
    (None, (1.0, -1.0, 0.0)),
])
def test_world_wind_is_the_fields_else_the_dynamics(field, expected_ned):
    assert world_wind_ned_m_s(field, (1.0, -1.0, 0.0)) == pytest.approx(expected_ned, abs=1e-12)


class _Harness:
    """One autopilot stepped by hand, its frames parsed as a ground station would."""

    def __init__(self, personality: str, wind_from_deg: float = 270.0, wind_speed_m_s: float = 3.0):
        self.mc = Multicopter(DynamicsParams(), np.random.default_rng(1))
        wind = WindEstimateModel(wind_ned_from_met(wind_from_deg, wind_speed_m_s), np.random.default_rng(2))
        self.ap = MockAutopilot(1, personality, self.mc, ORIGIN, 0.0, wind=wind)
        self.gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser, self.uplink = make_parser(), make_parser()
        self.t, self.received = 0.0, []

    def run(self, seconds: float) -> list:
        start = len(self.received)
        for _ in range(int(round(seconds / DT))):
            self.ap.step(self.t, DT)
            self.mc.step(DT)
            self.ap.send_telemetry(self.t)
            self.t += DT
            for frame in self.ap.drain_outbox():
                self.received += self.parser.parse_buffer(frame) or []
        return self.received[start:]

    def set_interval(self, msg_id: int, interval_us: float) -> int:
        msg = self.gcs.command_long_encode(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval_us,
                                           0, 0, 0, 0, 0)
        for parsed in self.uplink.parse_buffer(msg.pack(self.gcs)) or []:
            self.ap.handle_message(parsed, self.t)
        acks = [m for f in self.ap.drain_outbox() for m in self.parser.parse_buffer(f) or []
                if m.get_type() == "COMMAND_ACK"]
        return acks[-1].result


@pytest.mark.parametrize("personality, own, other, default_count, refusal", [
    ("px4", "WIND_COV", "WIND", 5, mav.MAV_RESULT_DENIED),         # PX4 streams it at 0.5 Hz
    ("ardupilot", "WIND", "WIND_COV", 0, mav.MAV_RESULT_FAILED),   # SRx_EXTRA3: off until asked
])
def test_mock_publishes_its_personalitys_wind_message(personality, own, other, default_count, refusal):
    h = _Harness(personality)
    first = h.run(10.0)
    assert abs(sum(m.get_type() == own for m in first) - default_count) <= 1
    own_id, other_id = getattr(mav, f"MAVLINK_MSG_ID_{own}"), getattr(mav, f"MAVLINK_MSG_ID_{other}")
    assert h.set_interval(other_id, 1e6) == refusal
    assert h.set_interval(own_id, 1e6) == mav.MAV_RESULT_ACCEPTED
    later = h.run(10.0)
    winds = [m for m in later if m.get_type() == own]
    assert abs(len(winds) - 10) <= 1   # 1 Hz as asked
    assert not any(m.get_type() == other for m in first + later)
    decode = decode_wind_cov if own == "WIND_COV" else decode_wind
    for m in winds:   # within 4 sigma of the truth
        est = decode(m, 0.0)
        assert abs(est.speed_m_s - 3.0) < 4 * ERROR_STD_M_S
        assert abs((est.from_deg - 270.0 + 180.0) % 360.0 - 180.0) < math.degrees(math.atan(4 * ERROR_STD_M_S / 2.0))


def test_ardupilot_stream_request_all_includes_wind():
    h = _Harness("ardupilot")
    msg = h.gcs.request_data_stream_encode(1, 1, mav.MAV_DATA_STREAM_ALL, 2, 1)
    for parsed in h.uplink.parse_buffer(msg.pack(h.gcs)) or []:
        h.ap.handle_message(parsed, h.t)
    assert abs(sum(m.get_type() == "WIND" for m in h.run(5.0)) - 10) <= 1


def test_fleet_vehicles_estimate_the_plumes_wind_each_with_its_own_error():
    fleet = fleet_mod.MockFleet(n=3, personality=["px4", "ardupilot", "px4"], zenoh=False, seed=4,
                                field=GaussianPlume(wind_from_deg=270.0, wind_speed_m_s=3.0),
                                udp_base_port=0, tcp_base_port=0)
    truths = {v.autopilot.wind.true_wind_ned_m_s for v in fleet.vehicles}
    assert len(truths) == 1 and next(iter(truths)) == pytest.approx((0.0, 3.0, 0.0), abs=1e-12)
    estimates = {v.autopilot.wind.estimate_ned_m_s(0.0) for v in fleet.vehicles}
    assert len(estimates) == 3


# ------------------------------------------------------------------ end to end: mock -> snapshot
async def _read_winds(fleet, clock, tmp_path, n_messages: int) -> dict:
    registry, endpoints, out = SysidRegistry(), [], {}
    try:
        for mv in fleet.vehicles:
            ep = await MavEndpoint.open(f"tcp:127.0.0.1:{mv.tcp_port}", clock=clock, registry=registry,
                                        tlog_dir=tmp_path)
            endpoints.append(ep)
            v = await VehicleLink.create(ep, mv.sysid, clock=clock, mission_origin=fleet.origin)
            assert await v.set_message_rates(wind_rates_hz(v.flavour)) == {}
            times = []
            for _ in range(n_messages):
                last = times[-1] if times else -1.0
                await v.wait_for(lambda s, last=last: s.wind is not None and s.wind.time_s > last, 10.0,
                                 "a wind estimate")
                times.append(v.state.wind.time_s)
            out[v.flavour] = (v.state.snapshot(), np.diff(times), dict(v.rejected))
            await v.close()
    finally:
        for ep in endpoints:
            await ep.close()
    return out


@pytest.mark.slow
def test_ground_station_reads_the_mocks_wind_at_the_asked_rate(tmp_path):
    base = free_port_block(30, kinds=("udp", "tcp"))
    clock = clock_mod.SimClock(4.0)
    fleet = fleet_mod.MockFleet(n=2, personality=["px4", "ardupilot"], clock=clock, zenoh=False,
                                field=GaussianPlume(wind_from_deg=250.0, wind_speed_m_s=2.5),
                                udp_base_port=base, udp_bind_base_port=base + 5, tcp_base_port=base + 10)
    fleet.start()
    try:
        result = asyncio.run(asyncio.wait_for(_read_winds(fleet, clock, tmp_path, 6), 120.0))
    finally:
        fleet.stop()
    assert set(result) == {"px4", "ardupilot"}
    for flavour, (snap, intervals_s, rejected) in result.items():
        assert snap.wind.message == ("WIND_COV" if flavour == "px4" else "WIND")
        assert abs(snap.wind.speed_m_s - 2.5) < 4 * ERROR_STD_M_S
        assert abs((snap.wind.from_deg - 250.0 + 180.0) % 360.0 - 180.0) < 30.0
        assert np.median(intervals_s) == pytest.approx(1.0, abs=0.15)   # simulated seconds
        assert rejected == {}
    prior = fleet_wind_prior([snap for snap, _, _ in result.values()])
    assert prior is not None and prior.n_vehicles == 2
    assert abs((prior.from_deg - 250.0 + 180.0) % 360.0 - 180.0) < 2 * prior.std_deg


# ------------------------------------------------------------------ fleet_wind_prior
def _snap(from_deg, speed_m_s, time_s=100.0):
    state = VehicleState(sysid=1, flavour="px4")
    state.wind = WindEstimate(from_deg, speed_m_s, 0.0, time_s, "WIND_COV")
    return state


@pytest.mark.parametrize("winds, expected_from_deg", [
    ([(268.0, 3.0), (270.0, 3.0), (272.0, 3.0)], 270.0),     # agreement
    ([(355.0, 3.0), (5.0, 3.0)], 0.0),                       # wrap-around at 0/360, not 180
    ([(350.0, 2.0), (20.0, 4.0)], 10.0),                     # weighted by speed (vector mean)
    ([(90.0, 2.5)], 90.0),                                   # one vehicle
])
def test_prior_direction(winds, expected_from_deg):
    prior = fleet_wind_prior([_snap(*w) for w in winds])
    assert isinstance(prior, WindPrior) and prior.n_vehicles == len(winds)
    assert abs((prior.from_deg - expected_from_deg + 180.0) % 360.0 - 180.0) < 1.0
    assert 0.0 <= prior.from_deg < 360.0
    assert prior.std_deg >= 10.0


def test_prior_std_has_a_floor_and_grows_with_the_spread_and_in_weak_wind():
    tight = fleet_wind_prior([_snap(269.0, 4.0), _snap(271.0, 4.0)])
    assert tight.std_deg == 10.0 and tight.spread_deg < 2.0
    spread = fleet_wind_prior([_snap(240.0, 4.0), _snap(300.0, 4.0)])
    assert spread.spread_deg > 25.0 and spread.std_deg >= spread.spread_deg
    weak = fleet_wind_prior([_snap(270.0, 0.8)])
    assert weak.std_deg == pytest.approx(math.degrees(math.atan2(0.5, 0.8)))   # ~32 deg


@pytest.mark.parametrize("snapshots", [
    [],                                                     # nobody reports
    [VehicleState(sysid=1, flavour="px4"), None],           # no estimate yet
    [_snap(270.0, 0.3), _snap(280.0, 0.4)],                 # too weak to have a direction
    [_snap(-180.0 % 360.0, 0.0)],                           # ArduCopter without drag fusion: speed 0
    [_snap(90.0, 3.0), _snap(270.0, 3.0)],                  # estimates that cancel
    [_snap(math.nan, 3.0), _snap(270.0, math.nan)],         # not finite: ignored
])
def test_no_prior(snapshots):
    assert fleet_wind_prior(snapshots) is None


def test_nan_and_stale_estimates_are_left_out_and_counted():
    snaps = [_snap(270.0, 3.0, time_s=100.0), _snap(math.nan, 3.0, time_s=100.0),
             _snap(90.0, 3.0, time_s=80.0)]
    prior = fleet_wind_prior(snaps, now_s=101.0, max_age_s=10.0)
    assert prior.n_vehicles == 1 and prior.n_ignored == 2
    assert prior.from_deg == pytest.approx(270.0)
    assert fleet_wind_prior(snaps[2:], now_s=101.0) is None


def test_something_else_than_snapshots_is_a_clear_error():
    with pytest.raises(TypeError, match="vehicle state snapshots, got int"):
        fleet_wind_prior({1: _snap(270.0, 3.0)})   # a dict's keys, not its values
