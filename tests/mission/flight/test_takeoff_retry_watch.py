"""The vehicles already in the air stay watched while another vehicle's arming is retried
(``[preflight] autopilot_ready_timeout_s``, the takeoff phase): a link loss or an autopilot
failsafe is a loss as in the seek, an offboard loss is re-engaged, and a takeoff whose losses leave
fewer than 4 vehicles, or an operator's stop, arms nothing more and ends (docs/faults.md, "A vehicle lost while another
one's arming is retried"). Mock PX4 fleet in lock-step; the last vehicle of the takeoff order
refuses to arm (the mock's ``arm_refused`` fault) until a saboteur thread clears it."""
from __future__ import annotations

import asyncio
import threading

import numpy as np
import pytest

from tests.support.wait_helpers import wait_until_async
from tests.support.fly_helpers import fly, run_fleet, run_with_saboteur
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

_SOURCE = np.array([6.0, 4.0, 12.0])
#: the formation's start by N: with N = 5 (the missions that go on) 3 m short of the source (what is checked
#: happens in the takeoff; a short seek keeps the mission cheap), with N = 4 (nothing flown after the takeoff)
#: (0, 0, 11); the start sets the takeoff order
_START = {5: (4.0, 2.0, 11.0), 4: (0.0, 0.0, 11.0)}
#: takeoff order of these fleets from these starts (lowest layer first, seed 3): N = 5: 2, 3, 4, 1, 5;
#: N = 4: 2, 4, 1, 3
_ORDER = {5: [2, 3, 4, 1, 5], 4: [2, 4, 1, 3]}
#: with N = 5 the victim is the first vehicle in the air
_FIRST = _ORDER[5][0]


class _Saboteur(threading.Thread):
    """Once the log shows the refuser's first arming refusal: sets ``fault`` on ``victim`` (cleared
    ``restore_after_s`` later, if given), then clears the refuser's ``arm_refused``
    ``refuse_for_s`` after the injection (never, if None). Mission-clock times of both kept."""

    def __init__(self, fleet, log_path, refuser, victim, fault, refuse_for_s, restore_after_s=None):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.refuser, self.victim = fleet, log_path, refuser, victim
        self.fault, self.refuse_for_s, self.restore_after_s = fault, refuse_for_s, restore_after_s
        self.done = threading.Event()
        self.injected_s = self.cleared_s = None

    def _wait(self, predicate, timeout_s=600.0) -> bool:
        clock = self.fleet.clock
        deadline = clock.time() + timeout_s
        while not self.done.is_set() and not predicate():
            if clock.time() > deadline:
                return False
            clock.sleep_blocking(0.1)
        return not self.done.is_set()

    def _refused(self) -> bool:
        return self.log_path.exists() and f"vehicle {self.refuser}: arming refused" in self.log_path.read_text()

    def run(self) -> None:
        clock = self.fleet.clock
        if not self._wait(self._refused):
            return
        name, value = self.fault
        self.fleet.set_fault(self.victim, name, value)
        t0 = self.injected_s = clock.time()
        if self.restore_after_s is not None:
            if not self._wait(lambda: clock.time() >= t0 + self.restore_after_s):
                return
            self.fleet.set_fault(self.victim, name, type(value)(0))
        if self.refuse_for_s is not None and self._wait(lambda: clock.time() >= t0 + self.refuse_for_s):
            self.fleet.set_fault(self.refuser, "arm_refused", False)
            self.cleared_s = clock.time()


def _fleet_and_plan(n):
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(_SOURCE), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=3, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    refuser = _ORDER[n][-1]
    fleet.set_fault(refuser, "arm_refused", True)
    plan = embedded_plan(n, ports, start_enu_m=_START[n], eps=default_eps(sigma2(_SOURCE)), max_iterations=80,
                         radius_m=2.0)
    return fleet, plan, refuser


def _fly(tmp_path, n, victim, fault, refuse_for_s, restore_after_s=None):
    fleet, plan, refuser = _fleet_and_plan(n)
    sab = _Saboteur(fleet, tmp_path / "mission.jsonl", refuser, victim, fault, refuse_for_s, restore_after_s)
    result = run_with_saboteur(plan, fleet, tmp_path, sab)
    records = read_mission_log(tmp_path / "mission.jsonl")
    events = [r for r in records if r["type"] == "event"]
    assert sab.injected_s is not None, [e["message"] for e in events][-10:]
    return result, events, fleet, sab, refuser


def _first(events, prefix):
    return next((e for e in events if e["message"].startswith(prefix)), None)


def _t(event):
    return float(event["t_s"])


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("fault, reason", [
    (("crashed", True), "link"),        # silent: lost by its link
    (("battery_low", True), "left"),    # PX4's battery failsafe (AUTO.RTL): left the mission
])
def test_vehicle_lost_while_another_arming_is_retried_is_declared_at_once(tmp_path, fault, reason):
    victim = _FIRST
    result, events, fleet, sab, refuser = _fly(tmp_path, 5, victim=victim, fault=fault, refuse_for_s=15.0)
    messages = [e["message"] for e in events]
    lost = _first(events, f"vehicle {victim} lost:")
    assert lost is not None and lost["reason"] == reason, messages[-15:]
    assert "(phase takeoff)" in lost["message"]
    # declared during the retry, well before the refuser armed (1.1 s: the link timeout and a tick)
    took_off = _first(events, f"vehicle {refuser} taking off")
    assert took_off is not None and _t(lost) < _t(took_off), messages[-15:]
    assert _t(lost) - sab.injected_s < 1.5
    assert result.outcome == "converged", (result.message, messages[-12:])
    assert [(x["sysid"], x["reason"]) for x in result.lost] == [(victim, reason)]
    assert any(m.startswith("re-forming for 4 vehicles") for m in messages)  # kept out of the formation
    landed = sorted(e["sysid"] for e in events if e["message"].endswith("landed"))
    assert landed == sorted(s for s in range(1, 6) if s != victim), messages[-12:]
    if reason == "link":  # silent and last seen armed: told loudly, and a script sees exit status 1
        assert [a["sysid"] for a in result.airborne_left] == [victim] and not result.ok


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_offboard_loss_while_another_arming_is_retried_is_reengaged(tmp_path):
    """Every frame to the first vehicle in the air (climbing or holding at its layer) lost for 2.5 s:
    PX4's offboard loss (POSCTL, which descends without RC). Before the fix the watchdog re-engaged only
    from the assembly on: that vehicle descended, landed and disarmed during the retry and was lost."""
    result, events, fleet, sab, refuser = _fly(tmp_path, 5, victim=_FIRST, fault=("loss_uplink", 1.0),
                                               refuse_for_s=15.0, restore_after_s=2.5)
    messages = [e["message"] for e in events]
    took_off = _first(events, f"vehicle {refuser} taking off")
    reengaged = _first(events, f"vehicle {_FIRST} left OFFBOARD")
    assert reengaged is not None and took_off is not None and _t(reengaged) < _t(took_off), messages[-15:]
    assert result.outcome == "converged", (result.message, messages[-12:])
    assert result.lost == [], result.lost
    landed = sorted(e["sysid"] for e in events if e["message"].endswith("landed"))
    assert landed == [1, 2, 3, 4, 5], messages[-12:]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_takeoff_with_too_few_left_arms_nothing_more_and_ends(tmp_path):
    """4 vehicles; the first in the air crashes while the last one's arming is retried (refused for
    good): 3 left, no formation possible. Before the fix the retry went on for the whole
    ``autopilot_ready_timeout_s`` (120 s) with the other two hovering; now the takeoff ends at the
    loss, the refuser is never armed, the two in the air land, the crashed one is reported airborne."""
    result, events, fleet, sab, refuser = _fly(tmp_path, 4, victim=2, fault=("crashed", True), refuse_for_s=None)
    messages = [e["message"] for e in events]
    lost = _first(events, "vehicle 2 lost:")
    assert lost is not None and lost["reason"] == "link", messages[-15:]
    assert result.outcome == "aborted", (result.outcome, result.message)
    assert result.message == f"vehicles [2] lost during the takeoff: 3 left, a formation needs 4; vehicles [{refuser}] not armed"
    aborted = _first(events, "vehicles [2] lost during the takeoff")
    assert aborted is not None and _t(aborted) - _t(lost) < 1.0, messages[-15:]
    assert not fleet.vehicle(refuser).armed and _first(events, f"vehicle {refuser} taking off") is None
    assert not any(m.startswith(f"vehicle {refuser} lost") for m in messages)  # it did not fail: never armed
    landed = sorted(e["sysid"] for e in events if e["message"].endswith("landed"))
    assert landed == [1, 4], messages[-12:]
    assert [a["sysid"] for a in result.airborne_left] == [2] and not result.ok


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_operator_return_during_an_arming_retry_ends_the_takeoff_at_once(tmp_path):
    """4 vehicles, the last refuses to arm for good: an operator's ``return`` while its arming is
    retried ends the takeoff at the next wait (before: only once the retry gave up, 120 s later);
    the refuser is never armed, the three in the air land."""
    fleet, plan, refuser = _fleet_and_plan(4)
    seen = {}

    async def operator(co):
        await wait_until_async(lambda: co.state.phase == "takeoff" and len(co.state.airborne) == 3, 120.0, "three airborne", poll_s=0.1)
        await asyncio.sleep(3.0)  # simulated: the refuser's arming is being retried
        assert co.state.phase == "takeoff" and refuser not in co.state.airborne
        t0 = asyncio.get_running_loop().time()
        assert co.command("return", "op")["accepted"]
        await wait_until_async(lambda: co.state.phase not in ("takeoff",), 60.0, "the takeoff to end", poll_s=0.1)
        seen["after_s"] = asyncio.get_running_loop().time() - t0

    async def main(world):
        coordinators = []
        mission = asyncio.ensure_future(fly(plan, fleet, tmp_path / "mission.jsonl", world=world,
                                            coordinators=coordinators))
        await wait_until_async(lambda: coordinators or mission.done(), 30.0, "the coordinator", poll_s=0.1)
        op = asyncio.ensure_future(operator(coordinators[0]))
        result = await mission
        await op
        return result

    try:
        result = run_fleet(fleet, main)
    finally:
        fleet.stop()
    assert seen["after_s"] < 2.0, seen
    assert result.outcome == "aborted" and "operator op" in result.message, result.message
    assert not fleet.vehicle(refuser).armed
    events = [r for r in read_mission_log(tmp_path / "mission.jsonl") if r["type"] == "event"]
    assert _first(events, f"vehicle {refuser} taking off") is None
    assert not any(e["message"].startswith(f"vehicle {refuser} lost") for e in events)
    landed = sorted(e["sysid"] for e in events if e["message"].endswith("landed"))
    assert landed == sorted(s for s in range(1, 5) if s != refuser), [e["message"] for e in events][-10:]
