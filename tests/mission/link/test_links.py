"""mission.link.endpoint: connection strings, demultiplexing, duplicate system ids, robust parsing, transports."""
from __future__ import annotations

import asyncio
import os

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.clock import WallClock
from mission.core.uri import ConnectionSpec, parse_connection
from mission.link.endpoint_registry import LinkError, SysidRegistry
from mission.link.endpoint import MavEndpoint
from mission.link.poller import UdpPoller
from mission.vehicle.vehicle_link import VehicleLink
from tests.support.fake_autopilot import FakeAutopilot, FakeUdpVehicle
from tests.support.wait_helpers import wait_until_async

ORIGIN = (45.0, 5.0, 200.0)


def _run(coro, timeout_s: float = 60.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


@pytest.mark.parametrize("uri, expected", [
    ("udpin:0.0.0.0:14540", ConnectionSpec("udpin:0.0.0.0:14540", "udpin", host="0.0.0.0", port=14540)),
    ("udp:127.0.0.1:14550", ConnectionSpec("udp:127.0.0.1:14550", "udpin", host="127.0.0.1", port=14550)),
    ("udpout:10.0.0.2:14555", ConnectionSpec("udpout:10.0.0.2:14555", "udpout", host="10.0.0.2", port=14555)),
    ("tcp:127.0.0.1:5760", ConnectionSpec("tcp:127.0.0.1:5760", "tcp", host="127.0.0.1", port=5760)),
    ("tcpin:0.0.0.0:5770", ConnectionSpec("tcpin:0.0.0.0:5770", "tcpin", host="0.0.0.0", port=5770)),
    ("tcp:localhost:5760", ConnectionSpec("tcp:localhost:5760", "tcp", host="localhost", port=5760)),
    ("  UDPIN:127.0.0.1:0 ", ConnectionSpec("UDPIN:127.0.0.1:0", "udpin", host="127.0.0.1", port=0)),
    ("serial:/dev/ttyUSB0:921600", ConnectionSpec("serial:/dev/ttyUSB0:921600", "serial", device="/dev/ttyUSB0", baud=921600)),
    ("serial:/dev/ttyACM0", ConnectionSpec("serial:/dev/ttyACM0", "serial", device="/dev/ttyACM0", baud=57600)),
    ("/dev/ttyUSB1,115200", ConnectionSpec("/dev/ttyUSB1,115200", "serial", device="/dev/ttyUSB1", baud=115200)),
    ("/dev/ttyAMA0", ConnectionSpec("/dev/ttyAMA0", "serial", device="/dev/ttyAMA0", baud=57600)),
])
def test_parse_connection_accepts_pymavlink_strings(uri, expected):
    assert parse_connection(uri) == expected


@pytest.mark.parametrize("uri, match", [
    ("", "empty connection string"),
    ("   ", "empty connection string"),
    ("udpin", "unknown scheme"),
    ("http://127.0.0.1:80", "unknown scheme 'http'"),
    ("udpin:127.0.0.1", "expected udpin:HOST:PORT"),
    ("udpin::14540", "expected udpin:HOST:PORT"),
    ("udpout:127.0.0.1:port", "port 'port' is not an integer"),
    ("tcp:127.0.0.1:0", r"port 0 out of range 1\.\.65535"),
    ("udpin:127.0.0.1:70000", "out of range"),
    ("tcp:bad host:5760", "bad host 'bad host'"),
    ("serial:", "serial needs a device"),
    ("serial:/dev/ttyUSB0:fast", "baud rate 'fast' is not an integer"),
    ("/dev/ttyUSB0,-9600", "baud rate must be positive"),
])
def test_parse_connection_rejects_bad_strings(uri, match):
    with pytest.raises(ValueError, match=match):
        parse_connection(uri)


def test_parse_connection_rejects_non_string():
    with pytest.raises(ValueError, match="expected a string"):
        parse_connection(14540)


def test_open_reports_a_taken_port_naming_the_endpoint():
    async def scenario():
        first = await MavEndpoint.open("udpin:127.0.0.1:0", clock=WallClock())
        port = first.local_address[1]
        try:
            with pytest.raises(LinkError, match=f"cannot open 'udpin:127.0.0.1:{port}'"):
                await MavEndpoint.open(f"udpin:127.0.0.1:{port}", clock=WallClock())
        finally:
            await first.close()
    _run(scenario())


async def _fleet(endpoint, sysids, **kwargs):
    fakes = []
    for sysid in sysids:
        fakes.append(await FakeUdpVehicle([FakeAutopilot(sysid, **kwargs)], endpoint.local_address).start())
    return fakes


async def _stop(*things):
    for thing in things:
        await thing.stop() if hasattr(thing, "stop") else await thing.close()


@pytest.mark.parametrize("polled", [False, True], ids=["asyncio", "poller"])
@pytest.mark.parametrize("n_vehicles", [1, 4])
def test_one_udp_socket_demultiplexes_vehicles_and_addresses_each(n_vehicles, polled):
    async def scenario():
        clock = WallClock()
        poller = UdpPoller(0.005) if polled else None
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, poller=poller)
        sysids = list(range(11, 11 + n_vehicles))
        fakes = await _fleet(ep, sysids)
        try:
            vehicles = [await VehicleLink.create(ep, s, clock=clock, mission_origin=ORIGIN) for s in sysids]
            assert ep.sysids_seen() == set(sysids)
            for v in vehicles:
                await v.wait_home(10.0)
                for _ in range(5):
                    v.send_position_enu([float(v.sysid), 0.0, 10.0])
            await wait_until_async(lambda: all(f.autopilots[0].setpoint_count == 5 for f in fakes), what="setpoints")
            # every datagram went only to its own vehicle's socket: the frames each socket saw are
            # its own commands, setpoints and heartbeats only
            for fake, v in zip(fakes, vehicles):
                ap = fake.autopilots[0]
                assert all(m.target_system == ap.sysid for m in ap.setpoints + ap.commands)
                assert fake.frames_in == len(ap.setpoints) + len(ap.commands) + ap.gcs_heartbeats
                assert ap.setpoints[-1].y == pytest.approx(float(v.sysid), abs=1e-3)  # east -> y
            if polled:
                assert poller.datagrams == ep.counters["frames_in"] > 0
        finally:
            await _stop(*fakes, ep)
            if poller is not None:
                await poller.close()
    _run(scenario())


def test_gcs_heartbeat_reaches_every_vehicle():
    async def scenario():
        clock = WallClock()
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, heartbeat_hz=5.0)
        fakes = await _fleet(ep, [1, 2, 3])
        try:
            await wait_until_async(lambda: all(f.autopilots[0].gcs_heartbeats >= 2 for f in fakes), what="GCS heartbeats")
            assert ep.counters["frames_out"] >= 6
        finally:
            await _stop(*fakes, ep)
    _run(scenario())


@pytest.mark.parametrize("polled", [False, True], ids=["asyncio", "poller"])
def test_duplicate_sysid_from_two_addresses_is_an_error_naming_both(polled):
    async def scenario():
        clock = WallClock()
        poller = UdpPoller(0.005) if polled else None
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, poller=poller)
        fakes = await _fleet(ep, [7, 7])
        try:
            await wait_until_async(lambda: ep.errors, what="duplicate detection")
            a, b = (f"{f.address}" for f in fakes)
            message = str(ep.errors[0])
            assert "duplicate MAVLink system id 7" in message and a in message and b in message
            with pytest.raises(LinkError, match="duplicate MAVLink system id 7 on 'udpin:127.0.0.1:0'"):
                await VehicleLink.create(ep, 7, clock=clock, mission_origin=ORIGIN)
            assert ep.counters["duplicate_sysid"] == 1
        finally:
            await _stop(*fakes, ep)
            if poller is not None:
                await poller.close()
    _run(scenario())


def test_duplicate_sysid_behind_one_address_is_caught_by_autopilot_version_uid():
    async def scenario():
        clock = WallClock()
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock)
        twins = [FakeAutopilot(5, uid=0x1111), FakeAutopilot(5, uid=0x2222)]
        fake = await FakeUdpVehicle(twins, ep.local_address).start()
        try:
            vehicle = await VehicleLink.create(ep, 5, clock=clock, mission_origin=ORIGIN)
            with pytest.raises(LinkError, match="duplicate MAVLink system id 5.*uids 0x1111 and 0x2222"):
                await vehicle.request_autopilot_version()
                await wait_until_async(lambda: vehicle.errors, what="uid duplicate")
                await vehicle.arm()
        finally:
            await _stop(fake, ep)
    _run(scenario())


def test_same_sysid_on_two_endpoints_names_both_endpoints():
    async def scenario():
        clock = WallClock()
        registry = SysidRegistry()
        ep1 = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, registry=registry)
        ep2 = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, registry=registry)
        ep1.uri, ep2.uri = f"udpin:127.0.0.1:{ep1.local_address[1]}", f"udpin:127.0.0.1:{ep2.local_address[1]}"
        f1 = await _fleet(ep1, [9])
        try:
            await VehicleLink.create(ep1, 9, clock=clock, mission_origin=ORIGIN)
            f2 = await _fleet(ep2, [9])
            f1 += f2
            with pytest.raises(LinkError, match=f"system id 9: heard on '{ep1.uri}' and on '{ep2.uri}'"):
                await VehicleLink.create(ep2, 9, clock=clock, mission_origin=ORIGIN)
        finally:
            await _stop(*f1, ep1, ep2)
    _run(scenario())


def test_garbage_and_bad_crc_are_counted_and_good_frames_still_arrive():
    async def scenario():
        clock = WallClock()
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, heartbeat_hz=0)
        loop = asyncio.get_running_loop()
        sender, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol, remote_addr=ep.local_address)
        ap = FakeAutopilot(3)
        good = ap.encode(ap.heartbeat())
        bad_crc = bytearray(ap.encode(ap.heartbeat()))
        bad_crc[-1] ^= 0xFF
        try:
            sender.sendto(b"\x00\x01garbage")
            sender.sendto(bytes(bad_crc))
            sender.sendto(good[:7])                    # truncated frame
            sender.sendto(good + b"\x55\x55" + good)   # two good frames around junk
            sysid, heartbeat = await ep.wait_heartbeat(3, 10.0)
            await wait_until_async(lambda: ep.counters["frames_in"] == 2, what="good frames")
            assert (sysid, heartbeat.autopilot) == (3, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
            assert ep.counters["bad_crc"] == 1
            assert ep.counters["malformed"] >= 2
            assert ep.counters["truncated"] == 1
        finally:
            sender.close()
            await ep.close()
    _run(scenario())


def test_heartbeat_timeout_names_the_endpoint_and_sysid():
    async def scenario():
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=WallClock())
        try:
            with pytest.raises(LinkError, match="no autopilot HEARTBEAT from system id 4 on 'udpin:127.0.0.1:0'"):
                await VehicleLink.create(ep, 4, clock=WallClock(), mission_origin=ORIGIN, heartbeat_timeout_s=0.3)
        finally:
            await ep.close()
    _run(scenario())


class _StreamVehicle:
    """A fake autopilot on a byte stream (TCP connection or pty): replies to what it hears."""

    def __init__(self, sysid: int, write) -> None:
        self.ap = FakeAutopilot(sysid)
        self.write = write
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True

    def feed(self, data: bytes) -> None:
        for msg in self.parser.parse_buffer(data) or ():
            for reply in self.ap.handle(msg):
                self.write(self.ap.encode(reply))

    def announce(self) -> None:
        for msg in self.ap.slow_telemetry():
            self.write(self.ap.encode(msg))


async def _exercise_stream_endpoint(ep, fake: _StreamVehicle) -> None:
    clock = ep.clock
    vehicle = await VehicleLink.create(ep, fake.ap.sysid, clock=clock, mission_origin=ORIGIN)
    await vehicle.set_mode("GUIDED")
    await vehicle.arm()
    assert fake.ap.armed and fake.ap.custom_mode == 4
    await wait_until_async(lambda: fake.ap.gcs_heartbeats >= 1, what="GCS heartbeat over the stream")


@pytest.mark.parametrize("server_side", ["vehicle", "ground"])
def test_tcp_client_and_server(server_side):
    async def scenario():
        clock = WallClock()
        holder = {}

        async def serve(reader, writer):
            fake = _StreamVehicle(2, writer.write)
            holder["fake"] = fake
            holder.setdefault("writers", []).append(writer)
            fake.announce()
            try:
                while data := await reader.read(4096):
                    fake.feed(data)
            finally:
                writer.close()

        if server_side == "vehicle":
            server = await asyncio.start_server(serve, "127.0.0.1", 0)
            port = server.sockets[0].getsockname()[1]
            ep = await MavEndpoint.open(f"tcp:127.0.0.1:{port}", clock=clock, heartbeat_hz=5.0)
            announce = None
        else:
            server = None
            ep = await MavEndpoint.open("tcpin:127.0.0.1:0", clock=clock, heartbeat_hz=5.0)
            reader, writer = await asyncio.open_connection(*ep.local_address)
            announce = asyncio.ensure_future(serve(reader, writer))
        try:
            await wait_until_async(lambda: "fake" in holder, what="connection")
            await _exercise_stream_endpoint(ep, holder["fake"])
        finally:
            await ep.close()
            for writer in holder.get("writers", []):
                writer.close()
            if announce is not None:
                announce.cancel()
            if server is not None:
                server.close()
                await server.wait_closed()
    _run(scenario())


def test_serial_line_over_a_pty():
    async def scenario():
        master, slave = os.openpty()
        os.set_blocking(master, False)
        loop = asyncio.get_running_loop()
        fake = _StreamVehicle(6, lambda data: os.write(master, data))
        loop.add_reader(master, lambda: fake.feed(os.read(master, 4096)))
        ep = await MavEndpoint.open(f"serial:{os.ttyname(slave)}:115200", clock=WallClock(), heartbeat_hz=5.0)
        try:
            fake.announce()
            await _exercise_stream_endpoint(ep, fake)
        finally:
            await ep.close()
            loop.remove_reader(master)
            os.close(master)
            os.close(slave)
    _run(scenario())


def test_serial_bad_baud_is_a_link_error():
    async def scenario():
        master, slave = os.openpty()
        try:
            with pytest.raises(LinkError, match="unsupported baud rate 12345"):
                await MavEndpoint.open(f"{os.ttyname(slave)},12345", clock=WallClock())
        finally:
            os.close(master)
            os.close(slave)
    _run(scenario())


@pytest.mark.parametrize("fields", [
    (1234, 1.5, -2.25, -10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0x9F8, 3, 1, 1),
    (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0),          # all truncated
    (7, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0xDF8, 200, 0, 0),   # trailing zeros
])
def test_send_payload_frames_are_identical_to_pymavlink(fields):
    cls = mavlink.MAVLink_set_position_target_local_ned_message

    async def scenario():
        loop = asyncio.get_running_loop()
        got = asyncio.Queue()

        class Sink(asyncio.DatagramProtocol):
            def datagram_received(self, data, addr):
                got.put_nowait(data)

        sink, _ = await loop.create_datagram_endpoint(Sink, local_addr=("127.0.0.1", 0))
        port = sink.get_extra_info("sockname")[1]
        ep = await MavEndpoint.open(f"udpout:127.0.0.1:{port}", clock=WallClock(), heartbeat_hz=0)
        try:
            assert ep.send_payload(3, cls.id, cls.crc_extra, cls.unpacker.pack(*fields))
            frame = await asyncio.wait_for(got.get(), 10)
        finally:
            await ep.close()
            sink.close()
        return frame

    frame = _run(scenario())
    reference = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    wire = dict(zip(cls.ordered_fieldnames, fields))
    assert frame == cls(**{name: wire[name] for name in cls.fieldnames}).pack(reference)
    decoded = mavlink.MAVLink(None).decode(bytearray(frame))
    assert decoded.get_type() == "SET_POSITION_TARGET_LOCAL_NED" and decoded.type_mask == fields[12]


def test_udpout_with_poller_talks_to_a_vehicle_that_waits_to_be_spoken_to():
    async def scenario():
        clock = WallClock()
        poller = UdpPoller(0.005)
        ap = FakeAutopilot(12)
        fake = await FakeUdpVehicle([ap], ("127.0.0.1", 9), telemetry_hz=5.0).start()  # streams nowhere useful
        ep = await MavEndpoint.open(f"udpout:127.0.0.1:{fake.address[1]}", clock=clock, poller=poller,
                                    heartbeat_hz=5.0)
        try:
            # our heartbeat makes the fake add us as a peer; then its telemetry reaches us
            vehicle = await VehicleLink.create(ep, 12, clock=clock, mission_origin=ORIGIN)
            await vehicle.arm()
            assert ap.armed and ap.gcs_heartbeats >= 1
        finally:
            await _stop(fake, ep)
            await poller.close()
    _run(scenario())


def test_poller_rejects_bad_interval():
    with pytest.raises(ValueError, match="interval_s must be > 0"):
        UdpPoller(0)
