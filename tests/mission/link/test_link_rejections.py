"""The MAVLink frames the links refuse are shown to the operator.

A signed lock-step mission (n = 4) flies while an intruder's UDP socket sends, every half
simulated second during the seek, to the coordinator's ``udpin`` ports: an unsigned HEARTBEAT
posing as vehicle 1, a LOCAL_POSITION_NED signed with a wrong key posing as vehicle 2, a frame of
vehicle 3's stream signed with the right key but an old timestamp (a replay), a frame with a
broken CRC and bytes that are not MAVLink; once, a correctly signed HEARTBEAT from system id 77
(not in the plan); and to vehicle 1's own port a command signed with a wrong key. The counts
must appear, exact and of the right kind, in the ``--json`` summary, the mission log (status
records, a warning event, the summary), the state publication and the live display; the mock
vehicle's own count in ``vehicle_rejections``.
"""
from __future__ import annotations

import io
import json
import socket
import time

import numpy as np
import pytest
import zenoh
from tests.support.fly_helpers import run_fleet
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.core.plan_types import replace_plan
from mission.flight.coordinator import Coordinator
from mission.flight.result import MissionResult
from mission.core.signing_config import SigningConfig
from mission.link.signing import apply_signing
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.fleet_report import vehicle_rejections
from mission.sim.lockstep import VirtualClock
from mission.telemetry.display import Display, format_summary, format_table
from mission.telemetry.link_report import (
    format_rejections,
    link_rejections,
    rejection_increase,
)
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.telemetry.state_pub import state_key
from sitl_mock.fields_config import make_field
from sitl_mock.fleet import MockFleet

KEY = bytes(range(1, 33))
WRONG_KEY = bytes(range(101, 133))
BURSTS = 6
GARBAGE = b"\x00\x01swarmseek garbage\xff" * 3


class Intruder:
    """Sends forged, unsigned, replayed, damaged and foreign frames from its own UDP socket."""

    def __init__(self, clock, gcs_ports: list[int], vehicle_port: int):
        self.clock = clock
        self.gcs_ports = gcs_ports
        self.vehicle_port = vehicle_port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.first_s: float | None = None
        self.sent = 0

    def _send(self, port: int, frame: bytes) -> None:
        self.sock.sendto(frame, ("127.0.0.1", port))
        self.sent += 1

    def burst(self, k: int) -> None:
        now = self.clock.time()
        plain = mav.MAVLink(None, 1, 1)
        self._send(self.gcs_ports[0], plain.heartbeat_encode(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0, mav.MAV_STATE_ACTIVE, 3).pack(plain))
        forger = apply_signing(mav.MAVLink(None, 2, 1), SigningConfig(WRONG_KEY).new_state(now))
        self._send(self.gcs_ports[1], forger.local_position_ned_encode(
            0, 100.0, 100.0, -50.0, 0, 0, 0).pack(forger))
        stale = apply_signing(mav.MAVLink(None, 3, 1), SigningConfig(KEY).new_state(now - 3600 + k))
        self._send(self.gcs_ports[2], stale.attitude_encode(0, 0, 0, 0, 0, 0, 0).pack(stale))
        damaged = bytearray(plain.heartbeat_encode(2, 12, 0, 0, 3, 3).pack(plain))
        damaged[-1] ^= 0xFF
        self._send(self.gcs_ports[3], bytes(damaged))
        self._send(self.gcs_ports[3], GARBAGE)
        cmd = forger.command_long_encode(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196,
                                         0, 0, 0, 0, 0)
        self._send(self.vehicle_port, cmd.pack(forger))
        if k == 0:
            insider = apply_signing(mav.MAVLink(None, 77, 1), SigningConfig(KEY).new_state(now))
            self._send(self.gcs_ports[0], insider.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0, mav.MAV_STATE_ACTIVE, 3).pack(insider))
            self.first_s = now

    async def run(self, co, bursts: int, period_s: float = 0.5) -> None:
        while co.state.phase != "seek":
            await self.clock.sleep(0.1)
        try:
            for k in range(bursts):
                self.burst(k)
                await self.clock.sleep(period_s)
        finally:
            self.sock.close()


def _fly(tmp_path, bursts: int, max_iterations: int = 10, start_offset_m=(-3.0, 2.0, -1.0), n: int = 4):
    source = np.array([6.0, -4.0, 13.0])
    start = source + np.asarray(start_offset_m, dtype=float)
    field = make_field("sigma2", source)
    ports = fleet_ports(n, "px4")
    plan = replace_plan(embedded_plan(n, ports, start_enu_m=start, eps=default_eps(field), max_iterations=max_iterations,
                                      origin=DEFAULT_ORIGIN), security=SigningConfig(KEY))
    fleet = MockFleet(n=n, personality="px4", field=field, origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=3, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0,
                      fleet_name=plan.fleet, sensor_noise_std=0.005,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"], signing_key=KEY)
    intruder = Intruder(fleet.clock, [ports["udp_base_port"] + i for i in range(4)],
                        fleet.vehicles[0].udp_bind_port)
    states: list[dict] = []
    screen = io.StringIO()

    async def main(world):
        session = zenoh.open(plan.zenoh.to_config())
        sub = session.declare_subscriber(state_key(plan.fleet),
                                         lambda s: states.append(json.loads(s.payload.to_bytes())))
        log = MissionLog(tmp_path / "mission.jsonl", fleet.clock)
        try:
            co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log,
                             display=Display(stream=screen, tty=False, min_interval_s=0.0))
            world.store = co.store
            attack = None
            if bursts:
                import asyncio

                attack = asyncio.ensure_future(intruder.run(co, bursts))
            result = await co.run()
            if attack is not None:
                await attack
            return result
        finally:
            log.close()
            time.sleep(0.2)  # the last state publications reach the subscriber
            sub.undeclare()
            session.close()

    try:
        result = run_fleet(fleet, main)
        rejected_by_vehicles = vehicle_rejections(fleet)
    finally:
        fleet.stop()
    error_m = None if result.estimate_enu is None else float(np.linalg.norm(np.asarray(result.estimate_enu) - source))
    return result, rejected_by_vehicles, states, screen.getvalue(), intruder, error_m


@pytest.fixture(scope="module")
def attacked(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("attacked")
    return tmp_path, *_fly(tmp_path, BURSTS)


# the one correctly signed heartbeat of sysid 77 is refused too: not a system id of the plan
EXPECTED = {"unsigned": BURSTS, "bad_signature": BURSTS, "replayed": BURSTS, "bad_crc": BURSTS,
            "malformed": BURSTS, "unplanned_sysid": 1}


def test_the_mission_flies_on_and_its_summary_counts_every_rejection(attacked):
    tmp_path, result, by_vehicles, states, screen, intruder, error_m = attacked
    assert intruder.first_s is not None and intruder.sent == 6 * BURSTS + 1
    assert result.outcome in ("converged", "max_iterations"), result.message
    assert not result.lost
    summary = json.loads(json.dumps(result.to_json()))  # what --json prints
    assert summary["link_rejections"] == EXPECTED
    assert summary["unknown_sysids"] == [77]
    lines = "\n".join(format_summary(summary))
    assert "MAVLink frames rejected by the ground station: unsigned 6, bad_signature 6, replayed 6" in lines
    assert "[77]" in lines


def test_the_mission_log_shows_the_rejections_as_they_happen(attacked):
    tmp_path, result, by_vehicles, states, screen, intruder, error_m = attacked
    records = read_mission_log(tmp_path / "mission.jsonl")
    warnings = [r for r in records if r["type"] == "event" and r["message"].startswith("MAVLink frames rejected")]
    assert warnings and warnings[-1]["link_rejections"] == EXPECTED
    detect_s = warnings[0]["t_s"] - intruder.first_s  # both simulated Unix seconds
    assert 0.0 <= detect_s <= 0.2  # the watchdog's period (0.1 s) and a tick of slack
    assert any("77" in r["message"] for r in records if r["type"] == "event" and "not in the plan" in r["message"])
    status = [r for r in records if r["type"] == "status"]
    assert status[-1]["link_rejections"] == EXPECTED and status[-1]["unknown_sysids"] == [77]
    assert not status[0]["link_rejections"]  # nothing before the intruder
    assert next(r for r in records if r["type"] == "summary")["link_rejections"] == EXPECTED


def test_the_state_publication_and_the_display_show_them(attacked):
    tmp_path, result, by_vehicles, states, screen, intruder, error_m = attacked
    assert states and not states[0]["link_rejections"]
    assert states[-1]["link_rejections"] == EXPECTED and states[-1]["unknown_sysids"] == [77]
    assert "mavlink_rejected=unsigned" in screen and "MAVLink frames rejected: " in screen
    table = "\n".join(format_table(states[-1]))
    assert "MAVLink rejected unsigned 6, bad_signature 6, replayed 6, bad_crc 6, malformed 6" in table


def test_the_vehicle_counts_what_it_refused(attacked):
    tmp_path, result, by_vehicles, states, screen, intruder, error_m = attacked
    assert by_vehicles == {1: {"rx_bad_signature": BURSTS}}
    lines = "\n".join(format_summary(MissionResult("converged", vehicle_rejections=by_vehicles).to_json()))
    assert "frames rejected by vehicle 1: rx_bad_signature 6" in lines


# --------------------------------------------------------------------------- the pieces
class _Ep:
    def __init__(self, counters, seen=()):
        self.counters = counters
        self._seen = set(seen)

    def sysids_seen(self):
        return self._seen


def test_link_rejections_add_up_the_refusing_kinds_only():
    eps = [_Ep({"unsigned": 2, "frames_in": 100, "bad_crc": 0}), _Ep({"unsigned": 1, "replayed": 4})]
    assert link_rejections(eps) == {"unsigned": 3, "replayed": 4}
    assert rejection_increase({"unsigned": 3}, {"unsigned": 5, "replayed": 1}) == {"unsigned": 2, "replayed": 1}
    assert format_rejections({}) == "0" and format_rejections({"a": 0, "b": 2}) == "b 2"


def test_a_quiet_table_says_zero():
    assert "MAVLink rejected 0" in "\n".join(format_table({"phase": "seek"}))


def test_swarmseek_run_json_has_the_rejection_fields(tmp_path, capsys):
    from mission.cli import main as cli_main

    cli_main(["run", "--n", "4", "--max-iterations", "2", "--json", "--no-tlog", "--log-dir", str(tmp_path)])
    summary = json.loads(capsys.readouterr().out)
    assert summary["link_rejections"] == {} and summary["unknown_sysids"] == []
    assert summary["vehicle_rejections"] == {}
    truth = next(r for r in read_mission_log(tmp_path / "mission.jsonl") if r["type"] == "truth")
    assert truth["vehicle_rejections"] == {}


def test_steady_refused_traffic_is_reported_at_doubling_intervals():
    """A companion's forwarded frames refused every second: reported at 1, 2, 4 ... s, up to 60 s;
    a new kind is reported at once and resets the interval."""
    from mission.flight.faults.watchdog import RejectionReport

    class _Links:  # the links, the clock and the events in one fake

        def __init__(self):
            self.t, self.counts, self.events = 0.0, {"unplanned_sysid": 0}, []

        def time(self):
            return self.t

        def link_rejections(self):
            return dict(self.counts)

        def unknown_sysids(self):
            return [255]

        def event(self, message, level="info", **fields):
            self.events.append((self.t, message))

    co = _Links()
    report = RejectionReport(co, co, co, status_period_s=1.0)
    for step in range(400):  # 200 s, 2 checks a second, 1 refused frame a second
        co.t = step * 0.5
        if step % 2 == 0:
            co.counts["unplanned_sysid"] += 1
        if step == 300:
            co.counts["bad_signature"] = 1
        report.check()
    times = [t for t, m in co.events if m.startswith("MAVLink frames rejected")]
    gaps = np.diff(times)
    assert list(gaps[:6]) == [1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
    assert max(gaps) <= 60.0
    assert 150.0 in times and "bad_signature" in dict(co.events)[150.0]  # a new kind: at once
    assert sum(1 for t, m in co.events if "not in the plan" in m) == 1
