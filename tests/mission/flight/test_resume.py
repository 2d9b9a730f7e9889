"""The ground station stops mid-mission: each vehicle does what its autopilot does (PX4 offboard
loss -> hold or land per COM_OBL_RC_ACT; ArduPilot GUIDED holds, or RTLs with FS_GCS_ENABLE);
``swarmseek resume`` then goes on from the mission log and converges."""
from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest

from mission.flight.coordinator import Coordinator
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.flight.phases.resume import ResumeError, load_resume_state, plan_from_json
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from mission.sim.lockstep import VirtualClock

from tests.support.fly_helpers import run_fleet

pytestmark = pytest.mark.timeout(400)


async def _fly_then_stop(plan, fleet, log_path, stop_after: int, world=None):
    """Fly until ``stop_after`` iterations, then stop the coordinator like a crashed ground
    station (no return): its task is cancelled and its links closed."""
    import zenoh

    session = zenoh.open(plan.zenoh.to_config())
    log = MissionLog(log_path, fleet.clock)
    try:
        co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log, tlog_dir=None)
        if world is not None:
            world.store = co.store
        co.return_on_interrupt = False
        task = asyncio.get_running_loop().create_task(co.run())
        deadline = fleet.clock.time() + 600.0
        while co.state.iteration < stop_after and not task.done() and fleet.clock.time() < deadline:
            await fleet.clock.sleep(0.2)
        assert not task.done(), task.result().message
        assert co.state.iteration >= stop_after, f"only {co.state.iteration} iterations before the deadline"
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return co
    finally:
        log.close()
        session.close()


def _wait(fleet, predicate, timeout_s):
    """Let the fleet fly on its own (no ground station) until ``predicate()`` or ``timeout_s``
    of fleet time; returns ``predicate()``."""
    async def watch(_world):
        deadline = fleet.clock.time() + timeout_s
        while not predicate() and fleet.clock.time() < deadline:
            await fleet.clock.sleep(0.2)
        return predicate()

    return run_fleet(fleet, watch)


@pytest.mark.slow
def test_gcs_stop_each_vehicle_does_what_its_autopilot_does(tmp_path):
    n = 4
    ports = fleet_ports(n, "px4")
    tcp_base = fleet_ports(n, "ardupilot")["tcp_base_port"]
    personalities = ["px4", "px4", "ardupilot", "ardupilot"]
    params = [{}, {"COM_OBL_RC_ACT": 4}, {}, {"FS_GCS_ENABLE": 2}]
    source = np.array([12.0, 8.0, 13.0])
    fleet = MockFleet(n=n, personality=personalities, field=sigma2(source), origin=DEFAULT_ORIGIN,
                      clock=VirtualClock(), seed=5, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=tcp_base,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"], params=params,
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)))
    vehicles = tuple(dataclasses.replace(v, connection=f"tcp:127.0.0.1:{tcp_base + 10 * i}")
                     if personalities[i] == "ardupilot" else v for i, v in enumerate(plan.vehicles))
    plan = dataclasses.replace(plan, vehicles=vehicles)
    try:
        run_fleet(fleet, lambda world: _fly_then_stop(plan, fleet, tmp_path / "m.jsonl", stop_after=2, world=world))
        t_stop = fleet.clock.time()
        where3 = fleet.vehicle(3).true_position_enu()
        v = {s: fleet.vehicle(s) for s in range(1, n + 1)}
        ok = _wait(fleet, lambda: (v[1].mode_name == "POSCTL" and v[2].mode_name in ("AUTO.LAND",)
                                   and v[4].mode_name == "RTL"), 30.0)
        modes = {s: v[s].mode_name for s in v}
        assert ok, modes
        _wait(fleet, lambda: False, 2.0)
        modes = {s: (v[s].mode_name, v[s].armed) for s in v}
        drift3 = float(np.linalg.norm(fleet.vehicle(3).true_position_enu() - where3))
        elapsed = fleet.clock.time() - t_stop
    finally:
        fleet.stop()
    assert modes[1] == ("POSCTL", True)  # PX4, COM_OBL_RC_ACT = 0: position mode (the mode real PX4 SIH reports)
    assert modes[3] == ("GUIDED", True)         # ArduPilot GUIDED without setpoints: holds
    assert drift3 < 1.0, (drift3, elapsed)
    assert modes[2][0] == "AUTO.LAND"           # PX4, COM_OBL_RC_ACT = 4: land
    assert modes[4][0] == "RTL"                 # ArduPilot, FS_GCS_ENABLE = 2: RTL


@pytest.mark.slow
def test_resume_after_a_gcs_stop_goes_on_and_converges(tmp_path):
    from mission.cli.cmd_resume import resume

    n = 6
    ports = fleet_ports(n, "px4")
    source = np.array([8.0, -5.0, 13.0])
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=9, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(source)))
    log_path = tmp_path / "m.jsonl"
    try:
        run_fleet(fleet, lambda world: _fly_then_stop(plan, fleet, log_path, stop_after=4, world=world))
        assert _wait(fleet, lambda: all(v.mode_name == "POSCTL" for v in fleet.vehicles), 30.0), \
            [v.mode_name for v in fleet.vehicles]
        state = load_resume_state(log_path)
        assert state.iteration >= 4 and len(state.slot_offsets) == n
        worlds = []

        def resumed(world):
            worlds.append(world)
            return resume(log_path, clock=fleet.clock, tlog=False, world=world)

        result = run_fleet(fleet, resumed)
        # the lock-step world waited for the resumed mission's readings: without its store, simulated
        # time ran ahead of zenoh on a loaded host (an iteration without fresh readings, a gap in the log)
        assert worlds[0].store is not None and worlds[0].waits > 0, (worlds[0].store, worlds[0].waits)
        all_down = _wait(fleet, lambda: not any(v.armed for v in fleet.vehicles), 60.0)
    finally:
        fleet.stop()
    records = read_mission_log(log_path)
    messages = [r["message"] for r in records if r["type"] == "event"]
    assert result.outcome == "converged", (result.message, messages[-10:])
    ks = [r["k"] for r in records if r["type"] == "iteration"]
    assert ks == list(range(1, len(ks) + 1))            # numbered on, nothing repeated
    assert result.iterations == ks[-1] > state.iteration
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    assert phases.count("takeoff") == 1                 # no new takeoff
    assert any(m.startswith(f"resumed at iteration {state.iteration}") for m in messages)
    error_m = float(np.linalg.norm(np.asarray(result.estimate_enu) - source))
    assert error_m < 1.0, error_m                       # N = 6 is unbiased (docs/mission.md)
    assert all_down and result.lost == []


def test_resume_refuses_a_finished_or_foreign_log(tmp_path):
    bad = tmp_path / "x.jsonl"
    bad.write_text("not json\n")
    with pytest.raises(ResumeError, match="not a swarmseek mission log"):
        load_resume_state(bad)
    done = tmp_path / "d.jsonl"
    plan = embedded_plan(4, {"udp_base_port": 15000, "zenoh_port": 7447})
    from mission.flight.coordinator import _plan_json

    import json
    done.write_text("\n".join(json.dumps(r) for r in (
        {"t_s": 0, "type": "plan", "plan": _plan_json(plan)},
        {"t_s": 1, "type": "phase", "phase": "done"})) + "\n")
    with pytest.raises(ResumeError, match="stopped before the takeoff"):
        load_resume_state(done)


def test_plan_round_trips_through_the_log():
    from mission.flight.coordinator import _plan_json

    plan = embedded_plan(5, {"udp_base_port": 15000, "zenoh_port": 7447}, formation="cvt", eps=49.9)
    assert plan_from_json(_plan_json(plan)) == plan


def test_resumed_plan_keeps_the_operator_sections():
    """[control], [forward] and [preflight] come back from the log: a resumed mission is commanded,
    forwarded and read-only exactly as the mission it takes over."""
    import json

    from mission.flight.coordinator import _plan_json
    from mission.telemetry.mission_log import to_jsonable

    plan = embedded_plan(5, {"udp_base_port": 15000, "zenoh_port": 7447}, formation="cvt", eps=49.9)
    plan = dataclasses.replace(
        plan, control=dataclasses.replace(plan.control, remote=False),
        forward=dataclasses.replace(plan.forward, out=("udp:127.0.0.1:14550", "udp:10.0.0.2:14551"),
                                    allow_commands=True),
        preflight=dataclasses.replace(plan.preflight, require_readings=False, readings_timeout_s=30.0))
    record = json.loads(json.dumps(to_jsonable(_plan_json(plan))))  # as written in mission.jsonl
    back = plan_from_json(record)
    assert (back.control, back.forward, back.preflight) == (plan.control, plan.forward, plan.preflight)
    for key in ("control", "forward", "preflight"):  # a log written before these sections existed
        record.pop(key)
    old = plan_from_json(record)
    assert old.control.remote is True and old.forward.out == () and not old.forward.allow_commands
