"""Never abandon an airborne vehicle: every mission path ends with each vehicle the
ground station armed down, under a confirmed RTL/LAND, or reported loudly (``airborne_left``).

Each mission flies a mock fleet in lock-step; ``fly_helpers.run_fleet`` checks the invariant
against the fleet's ground truth (:mod:`invariants`) after every one of them."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from mission.flight.phases import assemble, return_home, seek, takeoff
from mission.flight.coordinator import Coordinator
from mission.flight.state import MissionError
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import MissionLog, read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import fly, run_fleet
from tests.support.invariants import abandoned, reported_airborne

pytestmark = pytest.mark.timeout(300)

SOURCE = np.array([4.0, 3.0, 12.0])


def _setup(personality="ardupilot", n=4, return_behaviour="rtl", max_iterations=3, seed=3):
    ports = fleet_ports(n, personality)
    fleet = MockFleet(n=n, personality=personality, field=sigma2(SOURCE), origin=DEFAULT_ORIGIN,
                      clock=VirtualClock(), seed=seed, udp_base_port=ports.get("udp_base_port", 0),
                      udp_bind_base_port=ports.get("udp_bind_base_port", 0),
                      tcp_base_port=ports.get("tcp_base_port", 0), fleet_name="swarmseek",
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    if personality == "px4":  # PX4's RTL climbs to RTL_RETURN_ALT (60 m) first: 15 m as ArduPilot's RTL_ALT, for CPU
        for v in fleet.vehicles:
            v.autopilot.params.set("RTL_RETURN_ALT", 15.0)
    plan = embedded_plan(n, ports, personality=personality, start_enu_m=(0.0, 0.0, 12.0),
                         eps=default_eps(sigma2(SOURCE)), return_behaviour=return_behaviour,
                         max_iterations=max_iterations)
    return plan, fleet


async def _fly_with(plan, fleet, log_path, action, world):
    """Fly ``plan``; ``action(co, task)`` runs beside the mission (it may cancel ``task``).
    Returns the coordinator (its ``state.final_result`` is the result on every path)."""
    import zenoh

    session = zenoh.open(plan.zenoh.to_config())
    log = MissionLog(log_path, fleet.clock)
    try:
        co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log)
        world.store = co.store
        task = asyncio.get_running_loop().create_task(co.run())
        helper = asyncio.get_running_loop().create_task(action(co, task))
        try:
            await task
        except asyncio.CancelledError:
            pass
        helper.cancel()
        await asyncio.gather(helper, return_exceptions=True)
        return co
    finally:
        log.close()
        session.close()


async def _wait_phase(co, name, extra_s=0.0, timeout_s=400.0):
    deadline = co.clock.time() + timeout_s
    while co.state.phase != name:
        assert co.clock.time() < deadline, f"phase {name} never came (phase {co.state.phase})"
        await co.clock.sleep(0.1)
    await co.clock.sleep(extra_s)


def _records(path, kind):
    return [r for r in read_mission_log(path) if r["type"] == kind]


@pytest.mark.parametrize("personality, behaviour", [("ardupilot", "rtl"), ("ardupilot", "land"),
                                                     ("px4", "rtl")])
def test_a_second_mission_after_a_landing_by_rtl_or_land_flies(tmp_path, personality, behaviour):
    """Item 1: ArduPilot stays in RTL (or LAND) after it landed; the next mission must accept
    the landed, disarmed vehicles and fly, not declare them lost to a 'failsafe'."""
    plan, fleet = _setup(personality, return_behaviour=behaviour)
    try:
        results = []
        for k in range(2):
            results.append(run_fleet(fleet, lambda world, k=k: fly(plan, fleet, tmp_path / f"m{k}.jsonl",
                                                                   world=world)))
            modes = {v.mode_name for v in fleet.vehicles}
            assert all(v.autopilot.mc.landed for v in fleet.vehicles)
            assert modes <= {"RTL", "LAND", "AUTO.RTL", "AUTO.LAND"}, modes
            run_fleet(fleet, lambda world: _settle(fleet, 30.0))  # the autopilots disarm
    finally:
        fleet.stop()
    for r in results:
        assert r.outcome in ("converged", "max_iterations"), r.message
        assert r.iterations >= 1 and not r.lost and not r.airborne_left
    ready = [x for x in results[1].readiness if x["ready"]]
    assert len(ready) == 4


def _failing(orig, after_s, exc, clock):
    """``orig`` (a phase's ``run``) cut after ``after_s`` of mission time (``clock``) by ``exc``."""
    async def phase(*args, **kwargs):
        task = asyncio.ensure_future(orig(*args, **kwargs))
        deadline = clock.time() + after_s
        while not task.done() and clock.time() < deadline:
            await clock.sleep(0.1)
        if task.done():
            return task.result()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        raise exc
    return phase


@pytest.mark.parametrize("where, after_s, exc", [
    ("takeoff", 2.0, MissionError("injected abort in the takeoff")),
    ("assemble", 3.0, MissionError("injected abort in the assembly")),
    ("seek", 0.5, RuntimeError("injected bug in the seek")),
    ("return", 4.0, MissionError("injected failure of the return")),
])
def test_an_abort_in_any_phase_brings_every_vehicle_down(tmp_path, monkeypatch, where, after_s, exc):
    target = {"takeoff": (takeoff.Takeoff, "run"), "assemble": (assemble.Assemble, "run"), "seek": (seek.Seek, "run"),
              "return": (return_home.ReturnHome, "run")}[where]
    plan, fleet = _setup("ardupilot", return_behaviour="land")
    monkeypatch.setattr(*target, _failing(getattr(*target), after_s, exc, fleet.clock))
    log_path = tmp_path / "m.jsonl"
    try:
        result = run_fleet(fleet, lambda world: fly(plan, fleet, log_path, world=world))
        run_fleet(fleet, lambda world: _settle(fleet, 120.0))
        assert not any(v.armed for v in fleet.vehicles), [v.mode_name for v in fleet.vehicles]
    finally:
        fleet.stop()
    events = [r["message"] for r in _records(log_path, "event")]
    if where == "return":  # the mission had ended; the failed return lands everyone where they are
        assert result.outcome == "max_iterations"
        assert any(str(exc) in m and "landing every vehicle where it is" in m for m in events)
    else:
        assert result.outcome == "aborted" and str(exc) in result.message
    assert not result.airborne_left
    assert _records(log_path, "summary") and _records(log_path, "phase")[-1]["phase"] == "done"


async def _settle(fleet, timeout_s):
    """Let the fleet fly without a ground station until every vehicle disarmed (or timeout)."""
    deadline = fleet.clock.time() + timeout_s
    while any(v.armed for v in fleet.vehicles) and fleet.clock.time() < deadline:
        await fleet.clock.sleep(0.5)
    return None


@pytest.mark.parametrize("phase, interrupts", [("takeoff", 1), ("seek", 1), ("seek", 2), ("return", 1),
                                               ("return", 2), ("return", 3)])
def test_interrupts_return_or_land_and_always_summarise(tmp_path, phase, interrupts):
    """One interrupt: controlled return; another during the return: LAND where they are; a
    third: stop waiting. The log always ends with the phase ``done`` and a summary.

    A 40-iteration seek keeps the mission seeking when an interrupt in the takeoff or the seek comes;
    one interrupted in its return first ends its seek after 3 iterations (sooner there, for CPU)."""
    plan, fleet = _setup("ardupilot", return_behaviour="rtl", max_iterations=3 if phase == "return" else 40)
    log_path = tmp_path / "m.jsonl"

    async def action(co, task):
        await _wait_phase(co, phase, 0.5)
        co.state.note_interrupt("SIGINT")
        task.cancel()
        for i in range(interrupts - 1):
            if i == 0:
                await _wait_phase(co, "return", 1.0)
            co.state.note_interrupt("SIGINT")
            task.cancel()
            await co.clock.sleep(0.3)

    try:
        co = run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, action, world))
        run_fleet(fleet, lambda world: _settle(fleet, 120.0))
        assert not any(v.armed for v in fleet.vehicles), [v.mode_name for v in fleet.vehicles]
    finally:
        fleet.stop()
    result = co.state.final_result
    assert result is not None and result.interrupted_by == ["SIGINT"] * interrupts
    summary = _records(log_path, "summary")
    assert len(summary) == 1 and summary[0]["interrupted_by"] == ["SIGINT"] * interrupts
    assert _records(log_path, "phase")[-1]["phase"] == "done"
    events = [r["message"] for r in _records(log_path, "event")]
    landed_now = any("LANDING every airborne vehicle where it is" in m for m in events)
    assert landed_now == (interrupts >= 2)
    if interrupts < 3:
        assert not result.airborne_left
    else:  # the operator stopped the wait for the LAND confirmations: what was unconfirmed is reported
        assert reported_airborne(log_path) == {e["sysid"] for e in result.airborne_left}


def test_a_ground_station_that_just_stops_reports_the_vehicles_it_leaves(tmp_path):
    """``return_on_interrupt = False`` (the ground station stops, the autopilots carry on): the
    vehicles hovering in GUIDED are named loudly in an ``airborne_left`` record, with where they are."""
    plan, fleet = _setup("ardupilot", return_behaviour="land", max_iterations=40)
    log_path = tmp_path / "m.jsonl"

    async def action(co, task):
        co.return_on_interrupt = False
        await _wait_phase(co, "seek", 2.0)
        task.cancel()

    try:
        co = run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, action, world))
        assert len(abandoned(fleet)) == 4  # without the log's record, each would be abandoned
    finally:
        fleet.stop()
    left = _records(log_path, "airborne_left")
    assert len(left) == 1 and reported_airborne(log_path) == {1, 2, 3, 4}
    for v in left[0]["vehicles"]:
        assert v["mode"] == "GUIDED" and v["armed"] and v["lat_deg"] is not None and v["relative_alt_m"] > 5
    assert "swarmseek resume" in left[0]["advice"]
    assert [e["sysid"] for e in co.state.final_result.airborne_left] == [1, 2, 3, 4]


def test_a_vehicle_that_stops_obeying_is_reported_airborne(tmp_path):
    """A vehicle still heard but no longer reachable (uplink dead) cannot be landed by this
    ground station: it is reported, the others come down. (2 iterations, the fault coming during the
    second: each one after the fault waits out the settle timeout for vehicle 5, 21 s of mission.)"""
    plan, fleet = _setup("ardupilot", n=5, return_behaviour="land", max_iterations=2)
    log_path = tmp_path / "m.jsonl"

    async def action(co, task):
        await _wait_phase(co, "seek", 1.0)
        fleet.set_fault(5, "loss_uplink", 1.0)

    try:
        co = run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, action, world))
        still = [v.sysid for v in fleet.vehicles if v.armed and not v.autopilot.mc.landed]
    finally:
        fleet.stop()
    assert still == [5]
    assert reported_airborne(log_path) == {5}
    assert [e["sysid"] for e in co.state.final_result.airborne_left] == [5]


def test_a_lost_vehicle_not_heard_is_reported(tmp_path):
    """A vehicle whose link is cut while flying GUIDED (no GCS failsafe) is lost; at the end it
    is reported as airborne (last state armed in GUIDED), the survivors land."""
    plan, fleet = _setup("ardupilot", n=5, return_behaviour="land", max_iterations=4)
    log_path = tmp_path / "m.jsonl"

    async def action(co, task):
        await _wait_phase(co, "seek", 1.0)
        fleet.set_fault(2, "link_cut", True)

    try:
        co = run_fleet(fleet, lambda world: _fly_with(plan, fleet, log_path, action, world))
        armed = [v.sysid for v in fleet.vehicles if v.armed and not v.autopilot.mc.landed]
    finally:
        fleet.stop()
    assert armed == [2]
    left = co.state.final_result.airborne_left
    assert [e["sysid"] for e in left] == [2] and "not heard" in left[0]["state"]
