"""Coordinator outcomes other than success, against the mock fleet over real sockets:
a failed preflight arms nothing; a source outside the geofence stops the mission at the fence."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mission.flight.coordinator import Coordinator
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.core.plan_types import GeofencePlan
from mission.sim.lockstep import VirtualClock
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import run_fleet


def _fleet(n, ports, source, **kw):
    return MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                     seed=7, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                     tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                     **kw)


async def _fly(plan, fleet, log_path, states=None, world=None):
    import json

    import zenoh

    from mission.telemetry.state_pub import state_key

    session = zenoh.open(plan.zenoh.to_config())
    log = MissionLog(log_path, fleet.clock)
    if states is not None:  # a watcher of the published state (same session: local delivery)
        session.declare_subscriber(state_key(plan.fleet), lambda s: states.append(json.loads(s.payload.to_bytes())))
    try:
        co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log, tlog_dir=None)
        if world is not None:
            world.store = co.store
        return await co.run()
    finally:
        log.close()
        session.close()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("zenoh_elsewhere", [False, True])
def test_failed_preflight_aborts_and_arms_nothing(tmp_path, zenoh_elsewhere):
    """... and warns when no sensor reading arrives (zenoh connected elsewhere: as silent as a
    refused TLS handshake or login)."""
    from mission.sim.embedded import free_port_block
    from mission.core.zenoh_config import ZenohPlan

    n = 4
    ports = fleet_ports(n, "px4")
    source = np.array([5.0, 5.0, 12.0])
    fleet = _fleet(n, ports, source)
    fleet.set_fault(3, "battery_low", True)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 12.0), eps=50.0)
    if zenoh_elsewhere:  # nobody listens there
        nowhere = free_port_block(1, kinds=("tcp",))
        plan = dataclasses.replace(plan, zenoh=ZenohPlan(mode="peer", connect=(f"tcp/127.0.0.1:{nowhere}",)))
    try:
        result = run_fleet(fleet, lambda world: _fly(plan, fleet, tmp_path / "m.jsonl", world=world))
        armed = [v.armed for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert result.outcome == "aborted" and not result.ok
    assert "preflight failed" in result.message and "vehicle 3" in result.message
    assert "battery" in result.message
    assert not any(armed)
    by_sysid = {r["sysid"]: r for r in result.readiness}
    assert by_sysid[3]["checks"]["battery"] is False
    # without readings no vehicle is ready to seek ([preflight] require_readings)
    assert all(by_sysid[s]["ready"] != zenoh_elsewhere for s in (1, 2, 4))
    records = read_mission_log(tmp_path / "m.jsonl")
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    assert "takeoff" not in phases and "aborted" in phases
    warned = [r for r in records if r["type"] == "event" and r.get("check") == "readings"
              and "no sensor reading accepted" in r.get("message", "")]
    if zenoh_elsewhere:
        assert len(warned) == 1 and "vehicles [1, 2, 3, 4]" in warned[0]["message"]
        assert "TLS handshake or login" in warned[0]["message"]
        assert "no sensor reading" in result.message and not by_sysid[1]["checks"]["reading"]
    else:
        assert warned == []


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_source_outside_the_fence_stops_at_the_boundary(tmp_path):
    n = 6
    ports = fleet_ports(n, "px4")
    source = np.array([25.0, 2.0, 12.0])  # the fence ends at east 15 m; the centre may go to 11 m
    fleet = _fleet(n, ports, source)
    plan = embedded_plan(n, ports, start_enu_m=(2.0, 2.0, 12.0), eps=default_eps(sigma2(source)),
                         max_iterations=80)
    plan = dataclasses.replace(plan, geofence=GeofencePlan(
        polygon_en_m=((-15.0, -15.0), (15.0, -15.0), (15.0, 15.0), (-15.0, 15.0)), min_alt_m=2.0, max_alt_m=40.0))
    states: list[dict] = []
    try:
        result = run_fleet(fleet, lambda world: _fly(plan, fleet, tmp_path / "m.jsonl", states, world))
    finally:
        fleet.stop()
    assert result.outcome == "stopped_at_fence", result.message
    seen = [st["phase"] for st in states]
    assert {"takeoff", "assemble", "seek", "return"} <= set(seen), seen
    seeking = [st for st in states if st["phase"] == "seek" and st["gradient"] is not None]
    assert seeking and len(seeking[-1]["vehicles"]) == n and len(seeking[-1]["centre_enu"]) == 3
    assert "outside the fence" in result.message
    records = read_mission_log(tmp_path / "m.jsonl")
    centres = np.array([r["new_centre_enu"] for r in records if r["type"] == "iteration"])
    assert centres[:, 0].max() <= 11.0 + 1e-6  # the fence shrunk by the 4 m radius
    assert centres[-1, 0] == pytest.approx(11.0, abs=0.05)
    # every vehicle position seen stayed inside the fence
    for r in records:
        if r["type"] == "status":
            for v in r["vehicles"]:
                p = v.get("position_enu")
                if p is not None:
                    assert abs(p[0]) <= 15.0 and abs(p[1]) <= 15.0
    landed = [r for r in records if r["type"] == "event" and r["message"].endswith("landed")]
    assert len(landed) == n


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_offboard_loss_is_reengaged_and_the_mission_goes_on(tmp_path):
    """Vehicle 1's uplink is cut during the seek until PX4 leaves OFFBOARD (offboard-loss
    failsafe after 1 s); the coordinator switches it back once the link returns and converges."""
    import json
    import threading

    n = 6
    ports = fleet_ports(n, "px4")
    source = np.array([4.0, 6.0, 12.0])
    fleet = _fleet(n, ports, source)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)))
    log_path = tmp_path / "m.jsonl"
    left_offboard = threading.Event()
    done = threading.Event()

    def saboteur():
        # wait (polling the mission log, generous timeout) for the seek phase, then cut the uplink
        deadline = fleet.clock.time() + 600
        while not done.is_set() and fleet.clock.time() < deadline:
            if log_path.exists() and '"phase":"seek"' in log_path.read_text():
                break
            fleet.clock.sleep_blocking(0.5)
        fleet.set_fault(1, "loss_uplink", 1.0)
        # keep the uplink cut until the failsafe has acted (at most 30 s of simulated time), then
        # one more second, so that the outcome does not depend on the machine's load
        t_end = fleet.clock.time() + 30.0
        while fleet.clock.time() < t_end and not left_offboard.is_set():
            if fleet.vehicle(1).mode_name != "OFFBOARD":
                left_offboard.set()
            fleet.clock.sleep_blocking(0.1)
        fleet.clock.sleep_blocking(1.0)
        fleet.set_fault(1, "loss_uplink", 0.0)

    thread = threading.Thread(target=saboteur, daemon=True)
    thread.start()
    try:
        result = run_fleet(fleet, lambda world: _fly(plan, fleet, log_path, world=world))
    finally:
        done.set()
        thread.join(timeout=30)
        fleet.stop()
    assert left_offboard.is_set(), "the fault did not trigger the offboard-loss failsafe"
    events = [json.loads(line) for line in log_path.read_text().splitlines() if '"type":"event"' in line]
    warnings = [e["message"] for e in events if e["level"] != "info"]
    assert result.outcome == "converged", (result.message, warnings)
    assert result.reengaged.get(1, 0) >= 1, warnings
    assert any("vehicle 1 left OFFBOARD" in e["message"] for e in events)
