"""mission.link.tlog: per-vehicle .tlog files that pymavlink reads back."""
from __future__ import annotations

import asyncio

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.clock import WallClock
from mission.link.endpoint import MavEndpoint
from mission.link.tlog import TlogSet, read_tlog_records, tlog_record
from mission.vehicle.vehicle_link import VehicleLink
from tests.support.fake_autopilot import FakeAutopilot, FakeUdpVehicle
from tests.support.wait_helpers import wait_until_async

ORIGIN = (45.0, 5.0, 200.0)


def _read_with_pymavlink(path):
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    msgs = []
    try:
        while (msg := conn.recv_match()) is not None:
            msgs.append(msg)
    finally:
        conn.close()
    return msgs


def test_endpoint_logs_every_frame_per_vehicle_readable_by_pymavlink(tmp_path):
    async def scenario():
        clock = WallClock()
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, tlog_dir=tmp_path)
        fakes = [await FakeUdpVehicle([FakeAutopilot(s)], ep.local_address).start() for s in (1, 2)]
        try:
            vehicles = [await VehicleLink.create(ep, s, clock=clock, mission_origin=ORIGIN) for s in (1, 2)]
            for v in vehicles:
                await v.wait_home(10.0)
                await v.arm()
                for k in range(3):
                    v.send_position_enu([float(k), 0.0, 10.0])
            await wait_until_async(lambda: all(f.autopilots[0].setpoint_count == 3 for f in fakes), 20.0,
                                   "the setpoints to arrive")
        finally:
            for fake in fakes:
                await fake.stop()
            await ep.close()
        return ep

    ep = asyncio.run(asyncio.wait_for(scenario(), 60))
    paths = ep.tlogs.paths()
    assert sorted(paths) == [1, 2]
    total = 0
    for sysid, path in paths.items():
        msgs = _read_with_pymavlink(path)
        total += len(msgs)
        kinds = [(m.get_type(), m.get_srcSystem()) for m in msgs]
        # received from the vehicle
        assert ("HEARTBEAT", sysid) in kinds and ("HOME_POSITION", sysid) in kinds
        assert ("COMMAND_ACK", sysid) in kinds
        # sent by us (GCS 255), only frames for this vehicle
        ours = [m for m in msgs if m.get_srcSystem() == 255]
        setpoints = [m for m in ours if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
        assert [round(m.y) for m in setpoints] == [0, 1, 2]
        assert all(m.target_system == sysid for m in ours if hasattr(m, "target_system"))
        assert any(m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM for m in ours)
        stamps = [t for t, _ in read_tlog_records(path)]
        assert stamps == sorted(stamps) and abs(stamps[-1] - WallClock().time()) < 600
    assert total == ep.tlogs.records_written
    # one vehicle per peer here, so every frame in or out is logged exactly once
    assert ep.tlogs.records_written == ep.counters["frames_in"] + ep.counters["frames_out"]


def test_tlog_never_overwrites_and_records_round_trip(tmp_path):
    enc = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    frame = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 3, 3).pack(enc)
    first = TlogSet(tmp_path, time_fn=lambda: 1_700_000_000.25)
    first.write(4, frame)
    first.close()
    second = TlogSet(tmp_path)
    second.write(4, frame, t_s=1_700_000_001.5)
    second.write(4, frame, t_s=1_700_000_002.0)
    second.flush()
    assert first.path(4).name == "vehicle-4.tlog" and second.path(4).name == "vehicle-4-2.tlog"
    assert read_tlog_records(first.path(4)) == [(pytest.approx(1_700_000_000.25), frame)]
    assert [t for t, _ in read_tlog_records(second.path(4))] == [pytest.approx(1_700_000_001.5),
                                                                 pytest.approx(1_700_000_002.0)]
    second.close()
    second.write(4, frame)  # after close: ignored, not an error
    assert len(read_tlog_records(second.path(4))) == 2
    assert tlog_record(frame, 1.0)[:8] == (1_000_000).to_bytes(8, "big")


@pytest.mark.parametrize("content, match", [
    (b"\x00" * 8 + b"\x42\x00", "starts with 0x42"),
    (b"\x00" * 8 + b"\xfd\x09\x00", "truncated frame"),
    (b"\x00" * 5, "truncated record"),
])
def test_read_tlog_records_rejects_damaged_files(tmp_path, content, match):
    path = tmp_path / "bad.tlog"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match):
        read_tlog_records(path)
