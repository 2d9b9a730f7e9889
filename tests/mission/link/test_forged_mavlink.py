"""Forged MAVLink with signing off (the default): a local process cannot steer the mission.

Whole lock-step missions (PX4 personality) while a separate UDP socket -- not a patched function
-- sends forged frames to the coordinator's ``udpin`` ports:

* forged HEARTBEATs for a real vehicle's system id (PX4 ``AUTO.LAND``, and "disarmed"), and a
  forged AUTOPILOT_VERSION: no vehicle is declared lost, the mission converges, every forged
  frame is counted ``foreign_address``, and the forger's socket receives nothing (no setpoint,
  no GCS heartbeat is ever routed to it);
* a burst of 2,400 forged "disarmed" heartbeats with random system ids: the mission is
  unaffected, they are counted, they all go to one quarantine log under its cap, the vehicles
  keep one ``.tlog`` each and the audit sees only the mission's vehicles.

And against one endpoint over a real socket: the quarantine log's size cap (drops counted).
``-s`` prints the figures of the README's "Faults survived" rows.
"""
from __future__ import annotations

import asyncio
import random
import socket
import threading

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.fly_helpers import run_with_saboteur
from mission.core.clock import WallClock
from mission.core.uri import parse_connection
from mission.link.endpoint import MavEndpoint
from mission.link.endpoint_registry import SysidRegistry
from mission.link.tlog import read_tlog_records
from mission.safety.audit import audit_mission
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from tests.support.wait_helpers import wait_until_async

pytestmark = [pytest.mark.timeout(600)]

_M = mavlink
_ARMED = _M.MAV_MODE_FLAG_SAFETY_ARMED | _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
_PX4_AUTO_LAND = (4 << 16) | (6 << 24)
_PX4_OFFBOARD = 6 << 16
_SOURCE = np.array([8.0, -5.0, 13.0])


def _encode(msg, sysid: int, compid: int = 1) -> bytes:
    return msg.pack(_M.MAVLink(None, srcSystem=sysid, srcComponent=compid))


def _px4_heartbeat(base_mode: int, custom_mode: int):
    return _M.MAVLink_heartbeat_message(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_PX4, base_mode, custom_mode,
                                        _M.MAV_STATE_ACTIVE, 3)


def _land_heartbeat(sysid: int) -> bytes:
    return _encode(_px4_heartbeat(_ARMED, _PX4_AUTO_LAND), sysid)


def _disarmed_heartbeat(sysid: int) -> bytes:
    return _encode(_px4_heartbeat(_M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, _PX4_OFFBOARD), sysid)


def _fleet_and_plan(n: int):
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(_SOURCE), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=11, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(_SOURCE)),
                         max_iterations=60)
    return fleet, plan


def _port(plan, sysid: int) -> int:
    return parse_connection(next(v.connection for v in plan.vehicles if v.sysid == sysid)).port


class _Forger(threading.Thread):
    """A separate UDP socket that sends ``batches`` (lists of ``(frame, port)``), one every
    ``period_s`` of the mission clock, from the mission log's ``after_iterations``-th iteration;
    records what it sent, when, when the coordinator first counted it, and anything it received."""

    def __init__(self, fleet, log_path, batches, period_s: float, coordinators, after_iterations: int = 2):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.batches, self.period_s = fleet, log_path, batches, period_s
        self.coordinators, self.after_iterations = coordinators, after_iterations
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.done = threading.Event()
        self.sent = 0
        self.first_sent_s: float | None = None
        self.first_counted_s: float | None = None
        self.received: list[bytes] = []

    def _iterations(self) -> int:
        return self.log_path.read_text().count('"type":"iteration"') if self.log_path.exists() else 0

    def counted(self) -> int:
        """Forged frames the coordinator's endpoints refused so far."""
        if not self.coordinators:
            return 0
        return sum(ep.counters.get("foreign_address", 0) + ep.counters.get("unplanned_sysid", 0)
                   for ep in list(self.coordinators[0].endpoints.values()))

    def _drain(self) -> None:
        while True:
            try:
                self.received.append(self.sock.recv(65536))
            except (BlockingIOError, OSError):
                return

    def _note_counted(self) -> None:
        if self.first_counted_s is None and self.counted() > 0:
            self.first_counted_s = self.fleet.clock.time()

    def run(self) -> None:
        clock = self.fleet.clock
        deadline = clock.time() + 900.0
        while not self.done.is_set() and self._iterations() < self.after_iterations and clock.time() < deadline:
            clock.sleep_blocking(0.2)
        for batch in self.batches:
            if self.done.is_set():
                break
            for frame, port in batch:
                self.sock.sendto(frame, ("127.0.0.1", port))
                self.sent += 1
            if self.first_sent_s is None:
                self.first_sent_s = clock.time()
            for _ in range(10):
                clock.sleep_blocking(self.period_s / 10)
                self._note_counted()
            self._drain()
        for _ in range(50):   # a few more seconds: anything routed to the forger would show up
            if self.done.is_set():
                break
            clock.sleep_blocking(0.1)
            self._note_counted()
            self._drain()

    def close(self) -> None:
        self._drain()
        self.sock.close()


def _fly(tmp_path, n: int, make_batches, period_s: float):
    fleet, plan = _fleet_and_plan(n)
    coordinators: list = []
    forger = _Forger(fleet, tmp_path / "mission.jsonl", make_batches(plan), period_s, coordinators)
    try:
        result = run_with_saboteur(plan, fleet, tmp_path, forger, coordinators)
    finally:
        forger.close()
    records = read_mission_log(tmp_path / "mission.jsonl")
    return result, forger, coordinators[0], records


def _error_m(result) -> float:
    return float(np.linalg.norm(np.asarray(result.estimate_enu) - _SOURCE))


@pytest.mark.slow
def test_forged_land_and_disarmed_heartbeats_for_a_real_vehicle_change_nothing(tmp_path):
    n, victim = 4, 2

    def batches(plan):
        port = _port(plan, victim)
        uid_forgery = _encode(_M.MAVLink_autopilot_version_message(
            _M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0xBAD), victim)
        out = [[(uid_forgery, port)]]
        for k in range(20):   # 4 s of mission clock, alternately "AUTO.LAND" and "disarmed"
            out.append([((_land_heartbeat if k % 2 == 0 else _disarmed_heartbeat)(victim), port)])
        return out

    result, forger, co, records = _fly(tmp_path, n, batches, period_s=0.2)
    messages = [r.get("message", "") for r in records if r["type"] == "event"]
    assert result.lost == [], (result.message, [m for m in messages if "lost" in m])
    assert result.outcome == "converged", (result.message, messages[-10:])
    assert forger.sent == 21, "the forgery was never sent"
    ep = co.endpoints[next(v.connection for v in co.plan.vehicles if v.sysid == victim)]
    assert ep.counters["foreign_address"] == forger.sent
    assert ep.counters["duplicate_sysid"] == 0 and ep.errors == []
    assert ep.counters["quarantined"] == forger.sent
    assert forger.received == [], f"{len(forger.received)} datagrams were sent to the forger's address"
    detect_s = forger.first_counted_s - forger.first_sent_s
    print(f"\nforged heartbeats: {forger.sent} sent, {ep.counters['foreign_address']} counted foreign_address, "
          f"0 lost, {result.outcome}; detect {detect_s:.2f} s; final error {_error_m(result):.2f} m; "
          f"forger received {len(forger.received)}")


@pytest.mark.slow
def test_a_burst_of_random_sysid_heartbeats_goes_to_one_capped_quarantine_log(tmp_path):
    n = 4
    rnd = random.Random(7)

    def batches(plan):
        ports = [_port(plan, s) for s in range(1, n + 1)]
        frames = [(_disarmed_heartbeat(rnd.randrange(1, 256)), rnd.choice(ports)) for _ in range(2400)]
        return [frames[i:i + 100] for i in range(0, len(frames), 100)]   # 100 every 0.1 s

    result, forger, co, records = _fly(tmp_path, n, batches, period_s=0.1)
    messages = [r.get("message", "") for r in records if r["type"] == "event"]
    assert result.lost == [], (result.message, [m for m in messages if "lost" in m])
    assert result.outcome == "converged", (result.message, messages[-10:])
    assert forger.sent == 2400
    assert forger.counted() == 2400, [ep.suspect_counters for ep in co.endpoints.values()]
    assert forger.received == []
    tdir = tmp_path / "tlogs"
    quarantine = sorted(p.name for p in tdir.glob("quarantine*.tlog"))
    assert quarantine == ["quarantine.tlog"]
    size = (tdir / "quarantine.tlog").stat().st_size
    q = next(iter(co.endpoints.values())).quarantine
    assert size == q.counters["bytes"] <= q.max_bytes == 5_000_000
    assert len(read_tlog_records(tdir / "quarantine.tlog")) == q.counters["records"]
    assert q.counters["records"] >= 2400 and q.counters["dropped"] == 0
    assert sorted(p.name for p in tdir.glob("*.tlog")) == ["quarantine.tlog"] + [
        f"vehicle-{s}.tlog" for s in range(1, n + 1)]
    report = audit_mission(tmp_path)
    assert sorted(report.per_vehicle) == list(range(1, n + 1))
    detect_s = forger.first_counted_s - forger.first_sent_s
    print(f"\nrandom-sysid burst: {forger.sent} sent, {forger.counted()} counted, quarantine "
          f"{q.counters['records']} records / {size} bytes, 0 lost, {result.outcome}; detect {detect_s:.2f} s; "
          f"final error {_error_m(result):.2f} m; audit vehicles {sorted(report.per_vehicle)}")


def test_the_quarantine_log_stops_at_its_cap_and_counts_the_drops(tmp_path):
    """Real socket: a vehicle pinned, then 300 forged frames from another socket (its system id,
    and unplanned ones): all counted, the file never above the cap, the rest counted as dropped."""
    async def scenario():
        clock = WallClock()
        registry = SysidRegistry(quarantine_max_bytes=2000)
        ep = await MavEndpoint.open("udpin:127.0.0.1:0", clock=clock, heartbeat_hz=0, tlog_dir=tmp_path,
                                    registry=registry, planned_sysids=[3])
        vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        vehicle.bind(("127.0.0.1", 0))
        forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            vehicle.sendto(_disarmed_heartbeat(3), ep.local_address)
            await ep.wait_heartbeat(3, 10.0)
            for k in range(300):
                forger.sendto(_land_heartbeat(3 if k % 2 else 50 + k % 7), ep.local_address)
                if k % 50 == 49:
                    await wait_until_async(lambda: ep.counters["foreign_address"] + ep.counters["unplanned_sysid"]
                                           == k + 1, 10.0, "forged frames counted")
            c = ep.counters
            assert (c["foreign_address"], c["unplanned_sysid"]) == (150, 150)
            assert c["quarantined"] + c["quarantine_dropped"] == 300 and c["quarantine_dropped"] > 0
            assert ep.pinned_address(3) == vehicle.getsockname()
            assert ep.last_heartbeat(3).custom_mode == _PX4_OFFBOARD   # the vehicle's own, still
        finally:
            vehicle.close()
            forger.close()
            await ep.close()
        return ep

    ep = asyncio.run(asyncio.wait_for(scenario(), 60.0))
    assert (tmp_path / "quarantine.tlog").stat().st_size == ep.quarantine.counters["bytes"] <= 2000
    assert sorted(p.name for p in tmp_path.glob("*.tlog")) == ["quarantine.tlog", "vehicle-3.tlog"]


def test_a_mode_change_counts_only_when_the_vehicles_own_stream_repeats_it():
    """From the pinned address too, one AUTO.LAND heartbeat is "unconfirmed" (the coordinator asks
    for a heartbeat); the vehicle's next one decides."""
    from tests.support.fuzz_helpers import FakeClock
    from mission.flight.faults.loss import classify_loss
    from mission.vehicle.vehicle_link import VehicleLink

    clock = FakeClock()
    peer = ("127.0.0.1", 14583)
    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=clock, heartbeat_hz=0, planned_sysids=[3])
    offboard = _encode(_px4_heartbeat(_ARMED, _PX4_OFFBOARD), 3)
    ep.receive_datagram(offboard, peer)
    vl = VehicleLink(ep, 3, ep.last_heartbeat(3), clock=clock, mission_origin=DEFAULT_ORIGIN)
    ep.attach(3, vl._on_message, vl._on_link_error)
    sent = []
    ep._transport = type("T", (), {"send": lambda self, p, f: sent.append(p) or True,
                                   "default_peer": lambda self: None})()

    def verdict():
        found = classify_loss(vl, clock.time(), 1.0, commanded=False, seen_armed=True)
        return None if found is None else found[0]

    ep.receive_datagram(_land_heartbeat(3), peer)
    assert vl.state.mode == "AUTO.LAND" and vl.status_heartbeats == 1 and verdict() == "unconfirmed"
    assert vl.request_heartbeat() and not vl.request_heartbeat() and sent == [peer]  # rate-limited
    ep.receive_datagram(offboard, peer)          # the vehicle's own answer: still OFFBOARD
    assert verdict() is None
    ep.receive_datagram(_land_heartbeat(3) + _land_heartbeat(3), peer)
    assert vl.status_heartbeats == 2 and verdict() == "left"
    ep.receive_datagram(_disarmed_heartbeat(3), ("127.0.0.1", 9))   # another address: refused
    assert ep.counters["foreign_address"] == 1 and vl.state.armed


def test_a_planned_vehicles_frames_before_its_heartbeat_wait_for_its_pin(tmp_path):
    """Telemetry may come before the first HEARTBEAT: held, then logged in the vehicle's tlog if it
    came from the pinned address, quarantined (``foreign_address``) if not."""
    from tests.support.fuzz_helpers import FakeClock

    ep = MavEndpoint(parse_connection("udpin:127.0.0.1:0"), clock=FakeClock(), heartbeat_hz=0,
                     tlog_dir=tmp_path, planned_sysids=[3])
    vehicle, forger = ("127.0.0.1", 14583), ("127.0.0.1", 9)
    position = _encode(_M.MAVLink_global_position_int_message(0, 451900000, 57200000, 230000, 0, 0, 0, 0, 0), 3)
    heartbeat = _encode(_px4_heartbeat(_ARMED, _PX4_OFFBOARD), 3)
    try:
        ep.receive_datagram(position, vehicle)
        ep.receive_datagram(position, forger)
        assert ep.tlogs.paths() == {} and ep.counters["foreign_address"] == 0
        ep.receive_datagram(heartbeat, vehicle)
        assert ep.pinned_address(3) == vehicle and ep.counters["foreign_address"] == 1
        ep.tlogs.flush()
        ep.quarantine.flush()
        assert [f for _, f in read_tlog_records(ep.tlogs.path(3))] == [position, heartbeat]
        assert [f for _, f in read_tlog_records(tmp_path / "quarantine.tlog")] == [position]
    finally:
        ep.tlogs.close()
        ep.registry.release(ep)
