"""Operator commands (mission.flight.control) on whole missions in lock-step: pause then
continue, land, abort, return then RTL; and the rules of which command applies when."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from tests.support.wait_helpers import wait_until_async
from tests.support.fly_helpers import fly, run_fleet
from mission.flight.control import COMMANDS, MissionControl, OperatorStop
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

pytestmark = pytest.mark.timeout(300)

ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND
SOURCE = np.array([8.0, -6.0, 13.0])


class _Clock:
    def __init__(self):
        self.t = 0.0

    def time(self):
        return self.t


class _Log:
    def __init__(self):
        self.records = []

    def write(self, kind, **fields):
        self.records.append({"type": kind, **fields})


# ------------------------------------------------------------------------------ the rules
def test_rules_of_each_command_by_phase():
    log = _Log()
    c = MissionControl(_Clock(), log)
    assert not c.submit("continue", "op1", "seek").accepted            # not paused
    assert c.submit("pause", "op1", "seek").accepted and c.paused
    second = c.submit("pause", "op2", "seek")
    assert not second.accepted and "already paused (by op1)" in second.reason
    assert c.submit("continue", "op2", "seek").accepted and not c.paused
    assert not c.submit("jump", "op1", "seek").accepted
    bad = c.submit("pause", "op 1; rm -rf", "seek")
    assert not bad.accepted and "invalid sender" in bad.reason
    assert not c.submit("pause", "op1", "return").accepted            # already returning
    assert not c.submit("abort", "op1", "done").accepted              # nothing in flight
    assert [r["accepted"] for r in log.records] == [False, True, False, True, False, False, False, False]
    assert all(r["type"] == "command" and "reason" in r and "sender" in r for r in log.records)


def test_stops_raise_in_phases_before_the_return_only():
    c = MissionControl(_Clock())
    c.check("seek")                                                   # nothing ordered: no raise
    assert c.submit("abort", "op", "assemble").accepted
    assert not c.submit("return", "op", "assemble").accepted          # already ending
    with pytest.raises(OperatorStop, match="operator op aborted"):
        c.check("assemble")
    with pytest.raises(OperatorStop):                                 # again at the next wait
        c.check("seek")
    c.check("return")                                                 # the return is not interrupted
    assert c.submit("rtl", "op", "return").accepted and c.landing == "rtl"
    assert c.submit("land", "op2", "return").accepted and c.landing == "land"   # LAND overrides RTL
    assert not c.submit("rtl", "op", "return").accepted                         # not the reverse
    assert set(COMMANDS) == {"pause", "continue", "abort", "land", "rtl", "return"}


def test_pause_is_lifted_by_a_stop():
    c = MissionControl(_Clock())
    assert c.submit("pause", "op", "seek").accepted
    assert c.submit("land", "op", "seek").accepted
    assert not c.paused and c.stop == "land"


# ------------------------------------------------------------------------------ whole missions
def _setup(n=4, return_behaviour="land", max_iterations=80):
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(SOURCE), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=5, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 11.0), eps=default_eps(sigma2(SOURCE)),
                         max_iterations=max_iterations, return_behaviour=return_behaviour)
    return fleet, plan


def _fly_with_operator(fleet, plan, log_path, operator):
    """Fly ``plan``; ``operator(co)`` runs beside the coordinator on the same loop."""
    async def main(world):
        coordinators = []
        mission = asyncio.ensure_future(fly(plan, fleet, log_path, world=world, coordinators=coordinators))
        await wait_until_async(lambda: coordinators or mission.done(), 30.0, "the coordinator", poll_s=0.1)
        op = asyncio.ensure_future(operator(coordinators[0]))
        result = await mission
        seen = await op
        return result, seen

    try:
        return run_fleet(fleet, main)
    finally:
        fleet.stop()


def test_pause_holds_the_formation_then_continue_converges(tmp_path):
    fleet, plan = _setup()

    async def operator(co):
        await wait_until_async(lambda: co.state.phase == "seek" and co.state.iteration >= 3, 400.0, "iteration 3", poll_s=0.1)
        ack = co.command("pause", "alice@ops")
        assert ack["accepted"], ack
        await wait_until_async(lambda: co.control.holding, 30.0, "the pause to hold", poll_s=0.1)
        k, centre = co.state.iteration, np.array(co.state.centre_enu)
        setpoints = {s: co.gate.setpoint(s).copy() for s in co.gate.sysids}
        t0 = asyncio.get_running_loop().time()
        await asyncio.sleep(20.0)  # simulated: the mission must not step while paused
        held = (co.state.iteration, np.array(co.state.centre_enu), {s: co.gate.setpoint(s) for s in co.gate.sysids})
        positions = {s: co.telemetry_position(s) for s in setpoints}
        assert co.command("continue", "bob@ops")["accepted"]
        return k, centre, setpoints, held, positions, asyncio.get_running_loop().time() - t0

    result, (k, centre, setpoints, held, positions, paused_s) = _fly_with_operator(
        fleet, plan, tmp_path / "m.jsonl", operator)
    assert result.outcome == "converged", result.message
    assert held[0] == k and np.allclose(held[1], centre)
    assert all(np.allclose(held[2][s], setpoints[s]) for s in setpoints)
    assert all(np.linalg.norm(positions[s] - setpoints[s]) < 0.5 for s in setpoints)   # holding there
    assert result.iterations > k
    records = read_mission_log(tmp_path / "m.jsonl")
    commands = [r for r in records if r["type"] == "command"]
    assert [(c["command"], c["sender"], c["accepted"]) for c in commands] == [
        ("pause", "alice@ops", True), ("continue", "bob@ops", True)]
    continued = next(r for r in records if r["type"] == "event" and r["message"].startswith("continued after"))
    assert continued["paused_s"] >= paused_s - 0.5
    # no iteration was logged while paused
    t_pause = next(r["t_s"] for r in records if r["type"] == "event" and "paused by alice" in r["message"])
    assert not [r for r in records if r["type"] == "iteration" and t_pause < r["t_s"] < continued["t_s"]]


def _down_events(records):
    return {r["sysid"] for r in records if r["type"] == "event" and r["message"].endswith(" landed")}


def test_land_during_the_seek_lands_every_vehicle_where_it_is(tmp_path):
    fleet, plan = _setup()

    async def operator(co):
        await wait_until_async(lambda: co.state.phase == "seek" and co.state.iteration >= 2, 400.0, "iteration 2", poll_s=0.1)
        where = {s: fleet.vehicle(s).true_position_ned().copy() for s in co.vehicles}
        assert co.command("land", "carol")["accepted"]
        await wait_until_async(lambda: all(fleet.vehicle(s).mode_name == "AUTO.LAND" for s in where), 30.0, "AUTO.LAND", poll_s=0.1)
        return where

    result, where = _fly_with_operator(fleet, plan, tmp_path / "m.jsonl", operator)
    assert result.outcome == "aborted" and "operator carol ordered every vehicle to LAND" in result.message
    records = read_mission_log(tmp_path / "m.jsonl")
    assert _down_events(records) == {1, 2, 3, 4}
    phases = [r for r in records if r["type"] == "phase" and r["phase"] == "return"]
    assert [p["behaviour"] for p in phases] == ["land (operator)"]
    warnings = [r["message"] for r in records if r["type"] == "event" and r["level"] == "warning"]
    assert not [m for m in warnings if "operator" in m]             # the stop is not taken for a phase's timeout
    for s, p in where.items():      # landed below where they were, not flown back home first
        down = fleet.vehicle(s).true_position_ned()
        assert np.linalg.norm(down[:2] - p[:2]) < 1.5 and down[2] > -0.5, (s, p, down)
    assert all(fleet.vehicle(s).autopilot.landed_state() == ON_GROUND for s in range(1, 5))


def test_abort_during_the_assembly_brings_every_vehicle_home(tmp_path):
    fleet, plan = _setup()

    async def operator(co):
        await wait_until_async(lambda: co.state.phase == "assemble", 300.0, "the assembly", poll_s=0.1)
        ack = co.command("abort", "dave")
        late = co.command("pause", "erin")   # the mission is ending: refused
        return ack, late

    result, (ack, late) = _fly_with_operator(fleet, plan, tmp_path / "m.jsonl", operator)
    assert ack["accepted"] and ack["phase"] == "assemble"
    assert not late["accepted"] and "already ending" in late["reason"]
    assert result.outcome == "aborted" and "operator dave aborted" in result.message
    records = read_mission_log(tmp_path / "m.jsonl")
    assert not [r for r in records if r["type"] == "iteration"]
    assert [r["behaviour"] for r in records if r["type"] == "phase" and r["phase"] == "return"] == ["land"]
    assert _down_events(records) == {1, 2, 3, 4}
    assert all(fleet.vehicle(s).autopilot.landed_state() == ON_GROUND for s in range(1, 5))


def test_rtl_during_the_mission_return_hands_every_vehicle_to_the_autopilot(tmp_path):
    fleet, plan = _setup()
    modes = set()

    async def operator(co):
        await wait_until_async(lambda: co.state.phase == "seek" and co.state.iteration >= 2, 400.0, "iteration 2", poll_s=0.1)
        assert co.command("return", "frank")["accepted"]
        await wait_until_async(lambda: co.state.phase == "return", 60.0, "the return", poll_s=0.1)
        ack = co.command("rtl", "frank")
        await wait_until_async(lambda: all(fleet.vehicle(s).mode_name == "AUTO.RTL" or not fleet.vehicle(s).armed
                                 for s in range(1, 5)), 60.0, "every vehicle in RTL", poll_s=0.1)
        modes.update(fleet.vehicle(s).mode_name for s in range(1, 5))
        return ack

    result, ack = _fly_with_operator(fleet, plan, tmp_path / "m.jsonl", operator)
    assert ack["accepted"] and ack["phase"] == "return"
    assert "AUTO.RTL" in modes
    assert result.outcome == "aborted" and "operator frank ended the seek" in result.message
    records = read_mission_log(tmp_path / "m.jsonl")
    behaviours = [r["behaviour"] for r in records if r["type"] == "phase" and r["phase"] == "return"]
    assert behaviours == ["land", "rtl (operator)"]
    assert _down_events(records) == {1, 2, 3, 4}
    assert all(fleet.vehicle(s).autopilot.landed_state() == ON_GROUND for s in range(1, 5))
