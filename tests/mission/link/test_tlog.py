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


class _StuckFile:
    """A tlog file whose writes block until released (a loaded host's disk: dirty-page throttling)."""

    def __init__(self, fh, release):
        self.fh, self.release, self.entered = fh, release, __import__("threading").Event()

    def write(self, data):
        self.entered.set()
        self.release.wait(60)
        return self.fh.write(data)

    def flush(self):
        self.fh.flush()

    def close(self):
        self.fh.close()


def _stuck_files(monkeypatch, release):
    stuck = []
    real_open = TlogSet._open

    def open_stuck(self, sysid):
        fh = _StuckFile(real_open(self, sysid), release)
        self._files[sysid] = fh
        stuck.append(fh)
        return fh

    monkeypatch.setattr(TlogSet, "_open", open_stuck)
    return stuck


@pytest.mark.timeout(120)
def test_a_stuck_tlog_disk_blocks_neither_the_writes_nor_the_heartbeat(tmp_path, monkeypatch):
    """The disk write stalls (the writer thread inside a write that does not return): frames are
    still queued at once and the endpoint's GCS heartbeat keeps going (before, its 1 Hz
    housekeeping flushed every tlog on the event loop, so a stalled disk stalled the heartbeat);
    once the disk moves again every record is written, in order."""
    import threading

    release = threading.Event()
    stuck = _stuck_files(monkeypatch, release)
    # the disk moves again after 45 s whatever happens (a heartbeat stuck with the disk fails the
    # test below instead of hanging it)
    unstick = threading.Timer(45.0, release.set)
    unstick.start()

    async def scenario():
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=WallClock(), tlog_dir=tmp_path, heartbeat_hz=20.0)
        fake = FakeAutopilot(1)
        vehicle = await FakeUdpVehicle([fake], ep.local_address).start()
        try:
            await VehicleLink.create(ep, 1, clock=WallClock(), mission_origin=ORIGIN)
            # the writer thread takes its first record and stays inside the stuck write
            await wait_until_async(lambda: bool(stuck) and stuck[0].entered.is_set(), 30.0, "the writer stuck")
            before = fake.gcs_heartbeats
            await wait_until_async(lambda: fake.gcs_heartbeats >= before + 10, 60.0,
                                   "10 more GCS heartbeats")
            assert not release.is_set(), "the heartbeat waited for the stuck tlog disk"
            assert ep.tlogs.records_written > 10
        finally:
            release.set()
            unstick.cancel()
            await vehicle.stop()
            await ep.close()
        return ep

    ep = asyncio.run(asyncio.wait_for(scenario(), 90))
    records = read_tlog_records(ep.tlogs.path(1))
    assert len(records) == ep.tlogs.records_written and ep.tlogs.error is None
    stamps = [t for t, _ in records]
    assert stamps == sorted(stamps)


def test_tlog_writes_are_queued_while_the_disk_is_stuck_then_written_in_order(tmp_path, monkeypatch):
    import threading

    release = threading.Event()
    stuck = _stuck_files(monkeypatch, release)
    enc = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    frames = [mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, k % 8, 3).pack(enc) for k in range(200)]
    tlogs = TlogSet(tmp_path, flush_interval_s=0.01)
    tlogs.write(4, frames[0], t_s=1.0)
    assert stuck[0].entered.wait(30), "the writer thread never wrote"
    for k, frame in enumerate(frames[1:], start=1):   # the writer is stuck: these only queue
        tlogs.write(4, frame, t_s=1.0 + k)
    assert tlogs.records_written == 200
    release.set()
    tlogs.close()
    assert [f for _, f in read_tlog_records(tlogs.path(4))] == frames
    assert [t for t, _ in read_tlog_records(tlogs.path(4))] == [1.0 + k for k in range(200)]
