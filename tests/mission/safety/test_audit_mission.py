"""Whole missions against the mock fleet, then :func:`mission.safety.audit.audit_mission` on their
``.tlog`` files: no setpoint broke the fence or the separation, thousands were checked.

Five missions (N = 5 or 6, CVT, lock-step), each flown once per module: a plain ``swarmseek run``
(PX4 personality, UDP) and the same with the ArduPilot personality (TCP, NAV_TAKEOFF);
one where vehicle 3 crashes at the second iteration (loss, re-formation for five); one with the
source outside the geofence (the centre is held at the fence: ``stopped_at_fence``); one where a
planner fault steers vehicle 1 at vehicle 2 for 3 s (the envelope holds them apart).

The speed check once failed on every mission: the setpoints sent were a resampling, by the
``SetpointStreamer`` (10 Hz on an absolute schedule), of the ``SafetyGate`` (its own 10 Hz loop),
so a streamer tick could carry a full ramp step (0.37 m) in 0.07 s (5.4 m/s for a 3 m/s limit).
The streamer is now the last speed gate before the wire (``max_speed_m_s``), and the test holds.
"""
from __future__ import annotations

import dataclasses
import json
import threading

import numpy as np
import pytest

from mission.safety.audit import audit_mission
from mission.cli import main as cli_main
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.telemetry.mission_log import read_mission_log
from mission.core.plan_types import GeofencePlan
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from mission.sim.lockstep import VirtualClock
from tests.support.fly_helpers import run_with_saboteur

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

_MISSIONS = ["plain", "ardupilot", "crash", "source_outside_fence", "steered_into_neighbour"]


class _SteerIntoNeighbour:
    """A planner fault: from the third seeking move on, for ``steps`` ramp ticks, the ramp steers
    vehicle ``a`` at vehicle ``b``'s current setpoint (the mission's own goals are untouched
    and used again afterwards). Without the envelope's separation hold, ``a`` flies into ``b``."""

    def __init__(self, a=1, b=2, after_moves=3, steps=30):
        from mission.flight.faults.responses import FaultResponses
        from mission.safety.gate import SafetyGate

        self.a, self.b, self.after_moves, self.left = a, b, after_moves, steps
        self.moves, self.t_start_s = 0, None
        self._formation, self._ramp_cls = FaultResponses, SafetyGate  # the seek's moves go through it
        self._move, self._step = FaultResponses.move_and_wait, SafetyGate.step

    def __enter__(self):
        fault = self

        async def move_and_wait(formation, *args, **kwargs):
            fault.moves += 1
            return await fault._move(formation, *args, **kwargs)

        def step(ramp, dt_s):
            if fault.moves < fault.after_moves or fault.left <= 0 or not {fault.a, fault.b} <= set(ramp.sysids):
                return fault._step(ramp, dt_s)
            fault.left -= 1
            fault.t_start_s = fault.t_start_s if fault.t_start_s is not None else ramp.clock.time()
            legit = ramp.goal(fault.a)
            ramp.set_goal(fault.a, ramp.setpoint(fault.b))
            try:
                return fault._step(ramp, dt_s)
            finally:
                ramp.set_goal(fault.a, legit)

        self._formation.move_and_wait, self._ramp_cls.step = move_and_wait, step
        return self

    def __exit__(self, *exc):
        self._formation.move_and_wait, self._ramp_cls.step = self._move, self._step


class _CrashAt(threading.Thread):
    """Crashes ``sysid`` once the mission log shows ``k`` iterations (polled, generous timeout)."""

    def __init__(self, fleet, log_path, k, sysid):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.k, self.sysid = fleet, log_path, k, sysid
        self.done = threading.Event()
        self.injected = threading.Event()

    def run(self):
        deadline = self.fleet.clock.time() + 900.0
        while not self.done.is_set() and self.fleet.clock.time() < deadline:
            if self.log_path.exists() and self.log_path.read_text().count('"type":"iteration"') >= self.k:
                self.fleet.set_fault(self.sysid, "crashed", True)
                self.injected.set()
                return
            self.done.wait(0.05)


def _fly_against_mock(log_dir, n, source, start_enu_m=(0.0, 0.0, 11.0), plan_changes=None, crash=None):
    ports = fleet_ports(n, "px4")
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=11, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=0.005)
    plan = embedded_plan(n, ports, start_enu_m=start_enu_m, eps=default_eps(sigma2(source)), max_iterations=50)
    if plan_changes:
        plan = dataclasses.replace(plan, **plan_changes)
    saboteur = _CrashAt(fleet, log_dir / "mission.jsonl", *crash) if crash else None
    result = run_with_saboteur(plan, fleet, log_dir, saboteur)
    return result, saboteur


def _fly_mission(name, log_dir):
    """Fly one of the missions into ``log_dir``; returns its outcome."""
    if name in ("plain", "ardupilot"):
        personality = "px4" if name == "plain" else "ardupilot"
        code = cli_main(["run", "--n", "5", "--formation", "cvt", "--seed", "3", "--json",
                         "--personality", personality,
                         "--noise", "0.005", "--source=6,-4,13", "--start=-2,1,11", "--max-iterations", "50",
                         "--log-dir", str(log_dir)])
        records = read_mission_log(log_dir / "mission.jsonl")
        outcome = next(r for r in records if r["type"] == "summary")["outcome"]
        assert code in (0, 1)
    elif name == "steered_into_neighbour":
        with _SteerIntoNeighbour() as fault:
            result, _ = _fly_against_mock(log_dir, 5, np.array([6.0, -4.0, 13.0]), start_enu_m=(-2.0, 1.0, 11.0))
        assert fault.left == 0 and fault.t_start_s is not None, "the fault was never injected"
        assert result.separation_interventions > 0, result.message
        outcome = result.outcome
    elif name == "crash":
        result, saboteur = _fly_against_mock(log_dir, 6, np.array([14.0, 10.0, 13.0]), crash=(2, 3))
        assert saboteur.injected.is_set(), "the crash was never injected"
        assert [x["sysid"] for x in result.lost] == [3], result.message
        messages = [r.get("message", "") for r in read_mission_log(log_dir / "mission.jsonl")]
        assert any(m.startswith("re-forming for 5 vehicles") for m in messages), messages[-10:]
        outcome = result.outcome
    else:
        # the source is 24 m east; the fence stops at 16 m east (homes up to 10 m east), so the
        # centre may go to 16 - D = 12 m; the formation starts at 8 m east
        fence = GeofencePlan(polygon_en_m=((-40.0, -40.0), (16.0, -40.0), (16.0, 40.0), (-40.0, 40.0)),
                             min_alt_m=2.0, max_alt_m=40.0)
        result, _ = _fly_against_mock(log_dir, 5, np.array([24.0, 2.0, 13.0]), start_enu_m=(8.0, 2.0, 11.0),
                                      plan_changes={"geofence": fence})
        outcome = result.outcome
        assert outcome == "stopped_at_fence", result.message
    return outcome


@pytest.fixture(scope="module")
def missions(tmp_path_factory):
    """``get(name) -> (name, log_dir, outcome, report)``, each mission flown at most once."""
    cache = {}

    def get(name):
        if name not in cache:
            log_dir = tmp_path_factory.mktemp(name)
            outcome = _fly_mission(name, log_dir)
            cache[name] = (name, log_dir, outcome, audit_mission(log_dir))
        return cache[name]

    return get


@pytest.fixture(params=_MISSIONS)
def flown(request, missions):
    """``(name, log_dir, outcome, report)`` of each mission in turn."""
    return missions(request.param)


def test_no_setpoint_broke_the_fence_or_the_separation(flown):
    name, _, outcome, report = flown
    counts = {k: v for k, v in report.violation_counts.items() if k != "speed"}
    assert counts == {}, report.format_text()
    assert report.setpoints_checked >= 1500, report.format_text()
    assert report.setpoints_skipped == 0
    # every pair of vehicles is checked at every setpoint instant of either: with n >= 5 vehicles
    # that is at least (n - 1) / 2 >= 2 pair-segments per setpoint (lock-step stamps every
    # vehicle's setpoint at the same instant; on the wall clock the stamps interleave, twice that)
    assert report.separation_segments_checked >= 1.5 * report.setpoints_checked, report.format_text()
    assert report.min_separation_seen_m >= report.limits["min_separation_m"] - report.limits["separation_tol_m"]
    assert report.min_fence_margin_m >= -report.limits["fence_tol_m"]
    assert all(v["homes"] > 0 for v in report.per_vehicle.values())


def test_the_fast_audit_reports_what_the_plain_one_does(flown):
    # the numpy reader and the pair pruning (docs/audit.md, "Log sizes and audit speed") on a flown mission
    _, log_dir, _, report = flown
    assert report.to_dict() == audit_mission(log_dir, fast=False).to_dict()


def test_separation_interventions_are_reported_as_a_number(flown):
    # the envelope holds vehicles that would come too close; the summary (--json) counts them
    _, log_dir, _, _ = flown
    records = read_mission_log(log_dir / "mission.jsonl")
    summary = next(r for r in records if r["type"] == "summary")
    count = summary["separation_interventions"]
    assert isinstance(count, int) and count >= 0, summary
    held = [r for r in records if str(r.get("message", "")).startswith("separation enforced")]
    assert bool(held) == (count > 0)


def test_a_vehicle_steered_into_its_neighbour_is_held(missions):
    _, log_dir, outcome, report = missions("steered_into_neighbour")
    assert outcome == "converged", outcome
    records = read_mission_log(log_dir / "mission.jsonl")
    summary = next(r for r in records if r["type"] == "summary")
    messages = [str(r.get("message", "")) for r in records]
    started = [m for m in messages if m.startswith("separation enforced")]
    over = [m for m in messages if m.startswith("separation enforcement over")]
    assert started and len(started) == len(over) <= 3, messages   # per episode, not per tick
    assert f"{summary['separation_interventions']} in the mission so far" in over[-1]
    assert report.min_separation_seen_m >= report.limits["min_separation_m"] - report.limits["separation_tol_m"]


def test_source_outside_fence_pushes_setpoints_to_the_fence(missions):
    _, _, outcome, report = missions("source_outside_fence")
    assert outcome == "stopped_at_fence"
    # the centre was held at the fence shrunk by the radius: a slot lies within 1 m of the edge
    assert report.min_fence_margin_m < 1.0, report.format_text()


def test_speed_over_one_second_windows_is_bounded_by_the_ramp(flown):
    # the ramp moves a target by at most max_speed * dt with dt capped at 5 periods (0.5 s), so
    # over any window of >= 1 s the sent setpoints move at most max_speed * (1 + 0.5) per second
    # (measured: 3.2 to 3.3 m/s for 3 m/s)
    _, _, _, report = flown
    limit = report.limits["max_speed_m_s"]
    assert report.max_speed_seen_m_s <= limit * 1.5, report.format_text()


def test_no_setpoint_step_exceeds_the_speed_limit(flown):
    _, _, _, report = flown
    assert report.violation_counts.get("speed", 0) == 0, report.format_text()


def test_cli_audit_of_a_flown_mission(missions, capsys):
    _, log_dir, _, report = missions("plain")
    code = cli_main(["audit", str(log_dir), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == (0 if report.ok else 1)
    assert out["setpoints_checked"] == report.setpoints_checked
