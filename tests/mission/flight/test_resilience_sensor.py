"""A faulty sensor retired during the mission (``[faults] faulty_sensor``, :mod:`mission.flight.faults.retire`).

Unit: the watch maps the rule's pick to a sysid with its reason and noise figures, is only
made for the robust estimator with ``retire`` and while nobody is parked; the goals park the
retired vehicle at the centre; ``mission.flight.phases.resume`` reads the retired sensors back.

Against the mock fleet (N = 8, CVT, D = 2 m, noise 0.005 on seven sensors and 0.025 on vehicle 3,
robust estimator, ``retire_after = 5``, ``retire_min_noise_ratio = 2``: in these missions the
estimator's noise estimate of the 5x sensor is 2-7x the median, often near the rule's default 3x,
see docs/faults.md): vehicle 3's sensor, and only it, is retired as noisy,
the vehicle is parked near the centre and its readings are no longer used; vehicle 6 then
leaves (low battery: RTL failsafe): the 6 sensing vehicles re-form around the parked one, which
stays parked; the mission
converges, everyone else lands, and the ``.tlog`` audit finds no setpoint breaking the fence, the
separation or the speed limit. With ``faulty_sensor = "keep"`` nothing is retired.
"""
from __future__ import annotations

import asyncio
import dataclasses
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from mission.safety.audit import audit_mission
from mission.flight.coordinator import _plan_json
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.telemetry.status_changes import iteration_statuses
from mission.core.plan_types import FaultsPlan
from mission.flight.faults.retire import PARKED_STATUS, RetiredSensor, Retirement, SensorWatch, restore_retired
from mission.flight.motion import GateMotion
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from mission.sim.lockstep import VirtualClock
from tests.support.fly_helpers import run_with_saboteur

_NOISY = 3
_LEAVING = 6
_SOURCE = np.array([20.0, -12.0, 14.0])


# ------------------------------------------------------------------------------------ unit
class _Estimate:
    """Stands for the seek's robust estimator function (suspect codes and noise figures)."""

    def __init__(self, codes, std):
        self.codes, self.std = np.asarray(codes, dtype=np.int8), np.asarray(std, dtype=float)

    def suspect_codes(self):
        return self.codes

    def noise_std(self):
        return self.std


def _co(faults=FaultsPlan(), retired=(), lost=(), under=range(1, 9)):
    state = SimpleNamespace(lost={s: None for s in lost}, retired={s: None for s in retired},
                            slot_offsets={s: np.array([float(s), 0.0, 0.0]) for s in range(1, 9)})
    return SimpleNamespace(plan=SimpleNamespace(faults=faults), gate=SimpleNamespace(sysids=set(under)), state=state)


class _Events:
    def __init__(self):
        self.messages = []

    def event(self, message, level="info", **fields):
        self.messages.append(message)


def _motion(co) -> GateMotion:
    """The mission's :class:`GateMotion` over ``co``'s state and gate (no move is flown in these tests)."""
    return GateMotion(co.state, None, lambda: co.gate, lambda: None, None, _Events(), None,
                      return_behaviour="land", min_separation_m=1.5, max_speed_m_s=3.0, arrival_tol_m=0.35)


def _retirement(co, events=None) -> Retirement:
    """A :class:`Retirement` over ``co``'s state and gate; its motion is :func:`_motion` of the same."""
    return Retirement(co.state, None, co.gate, co.plan.faults, None, _motion(co), events or _Events())


@pytest.mark.parametrize("code, reason", [(4, "noisy"), (1, "stuck")])
def test_watch_names_the_sysid_with_its_reason_and_noise(code, reason):
    sysids = [2, 4, 5, 7, 9]
    watch = SensorWatch(sysids, after_updates=3)
    codes = np.zeros(5, dtype=np.int8)
    codes[3] = code                                   # the 4th sensor: sysid 7
    est = _Estimate(codes, [0.01, 0.01, 0.012, 0.05, 0.011])
    found = [watch.update(est, sysids, k, 10.0 * k) for k in (1, 2, 3)]
    assert found[:2] == [None, None]
    got = found[2]
    assert (got.sysid, got.reason, got.named_for, got.iteration) == (7, reason, 3, 3)
    assert got.noise_std == pytest.approx(0.05) and got.ratio == pytest.approx(0.05 / 0.011)
    assert watch.update(est, sysids, 4, 40.0) is None  # once retired, its streak starts again


@pytest.mark.parametrize("code, std_3", [
    (3, 0.05),      # spiking: each spike is already left out
    (2, 0.01),      # biased: the field's curvature across a large formation looks like one
    (4, 0.025),     # noisy at 2.5x the median: not enough (the rule wants 3x)
])
def test_watch_does_not_retire_for_weak_reasons(code, std_3):
    sysids = [1, 2, 3, 4, 5]
    watch = SensorWatch(sysids, after_updates=2)
    est = _Estimate([0, 0, code, 0, 0], [0.01, 0.01, std_3, 0.01, 0.01])
    assert [watch.update(est, sysids, k, 0.0) for k in range(6)] == [None] * 6


def test_watch_skips_updates_over_other_vehicles():
    sysids = [1, 2, 3, 4, 5]
    watch = SensorWatch(sysids, after_updates=2)
    noisy = _Estimate([0, 0, 4, 0, 0], [0.01, 0.01, 0.05, 0.01, 0.01])
    assert watch.update(noisy, [1, 2, 3, 4], 6, 0.0) is None   # not every sensing vehicle: skipped
    assert watch.update(noisy, sysids, 7, 0.0) is None
    assert watch.update(noisy, sysids, 8, 0.0).sysid == 3


def test_watch_never_leaves_fewer_than_four_sensors():
    sysids = [1, 2, 3, 4]
    watch = SensorWatch(sysids, after_updates=1)
    assert all(watch.update(_Estimate([4, 0, 0, 0], [0.1, 0.01, 0.01, 0.01]), sysids, k, 0.0) is None
               for k in range(5))


@pytest.mark.parametrize("kind, faults, retired, made", [
    ("robust", FaultsPlan(), (), True),
    ("robust", FaultsPlan(retire_after=3, retire_min_noise_ratio=2.0), (), True),
    ("robust", FaultsPlan(faulty_sensor="keep"), (), False),
    ("robust", FaultsPlan(faulty_sensor="off"), (), False),
    ("cvt", FaultsPlan(), (), True),                 # the detector runs whatever the estimator
    ("symmetric", FaultsPlan(), (), True),
    ("cvt", FaultsPlan(faulty_sensor="off"), (), False),
    ("robust", FaultsPlan(), (6,), False),           # one parking place: the centre
])
def test_watch_for_retire_and_a_free_centre_whatever_the_estimator(kind, faults, retired, made):
    from mission.flight.seeking import GradientEstimate
    from mission.flight.sensor_check import make_check

    co = _co(faults, retired)
    sysids = [s for s in range(1, 9) if s not in retired]
    check = make_check(faults, GradientEstimate(kind, len(sysids)), sysids)
    assert (check is None) == (faults.faulty_sensor == "off")
    watch = _retirement(co).make_watch(check, sysids)
    assert (watch is not None) == made
    if made:
        assert watch.rule.after_updates == faults.retire_after
        assert watch.rule.min_noise_ratio == faults.retire_min_noise_ratio


def test_parked_vehicle_goes_to_the_centre_unless_lost():
    centre = np.array([1.0, 2.0, 10.0])
    co = _co(retired=(6,))
    goals = _retirement(co).formation_goals(centre, [1, 2, 3, 4, 5, 7, 8])
    assert sorted(goals) == list(range(1, 9))
    assert np.allclose(goals[6], centre) and np.allclose(goals[2], centre + [2.0, 0.0, 0.0])
    co_lost = _co(retired=(6,), lost=(6,))
    assert _motion(co_lost).parked() == [] and 6 not in _retirement(co_lost).formation_goals(centre, [1, 2, 3, 4, 5, 7, 8])


@pytest.mark.parametrize("sysids, lost, retired, why", [
    ([1, 2, 3, 4, 5], (3,), (), "the vehicle was lost"),
    ([1, 2, 3, 4, 5], (5,), (), "3 other sensing vehicles left, a formation needs 4"),
    ([1, 2, 3, 4, 5, 7], (), (6,), "vehicle 6 is already parked at the centre"),
])
def test_retirement_is_refused_when_things_changed_since_the_estimate(sysids, lost, retired, why):
    co = _co(retired=retired, lost=lost, under=[s for s in range(1, 9) if s not in lost])
    events = _Events()
    info = RetiredSensor(3, "noisy", 0.05, 0.01, 30, 20, 100.0)
    assert asyncio.run(_retirement(co, events).retire_sensor(np.zeros(3), sysids, info)) == sysids
    assert events.messages == [f"vehicle 3's sensor not retired: {why}"] and 3 not in co.state.retired


@pytest.mark.parametrize("climb_m, planned_s, expected_s", [
    (0.0, 1.0, 1.0),        # horizontal 2 m at 2.4 m/s planned in 1 s: the ramp keeps up
    (3.0, 1.0, 3.75),       # a 3 m climb at 0.8 m/s (80 % of 1 m/s) takes 3.75 s, not 1 s
    (3.0, 5.0, 5.0),        # planned slower than the ramp: kept
])
def test_transfer_legs_are_never_faster_than_the_ramp(climb_m, planned_s, expected_s):
    from mission.flight.motion import _ramp_times

    wps = np.zeros((3, 2, 3))
    wps[1, 0] = [2.0, 0.0, climb_m]          # leg 1: vehicle 0 moves, vehicle 1 holds
    wps[2] = wps[1]
    wps[2, 1, 0] = 0.5                       # leg 2: vehicle 1 moves 0.5 m
    times = _ramp_times([0.0, planned_s, planned_s + 0.1], wps, 2.4, 0.8)
    assert times[0] == 0.0 and times[1] == pytest.approx(expected_s)
    assert times[2] - times[1] == pytest.approx(max(0.1, 0.5 / 2.4))


def test_resume_reads_the_retired_sensor_back(tmp_path):
    from mission.flight.phases.resume import load_resume_state

    ports = {"udp_base_port": 20000, "udp_bind_base_port": 20100, "tcp_base_port": 0, "zenoh_port": 20200}
    plan = embedded_plan(6, ports, estimator="robust")
    clock = SimpleNamespace(time=lambda: 1.0)
    offsets = {s: [2.0 * np.cos(s), 2.0 * np.sin(s), 0.5] for s in range(1, 7)}
    with MissionLog(tmp_path / "m.jsonl", clock) as log:
        log.write("plan", plan=_plan_json(plan))
        log.phase("seek")
        log.event("formation cvt, 6 slots", slots=offsets, layers={s: 8.0 + s for s in range(1, 7)})
        log.event("vehicle 4's sensor retired (noisy, std 0.05 = 5.0x the median, named for 10 iterations): "
                  "parked at the formation centre, readings ignored; re-formed for 5 (cvt)", level="warning",
                  sysid=4, reason="noisy", noise_std=0.05, median_std=0.01, iteration=12, named_for=10,
                  retired_s=30.0)
        log.event("re-forming for 5 vehicles (cvt), sensor of 4 retired: transfer direct",
                  slots={**{s: offsets[s] for s in (1, 2, 3, 5, 6)}, 4: [0.0, 0.0, 0.0]})
        log.write("iteration", k=12, new_centre_enu=[1.0, 1.0, 11.0], distance_flown_m=5.0)
    state = load_resume_state(tmp_path / "m.jsonl")
    assert sorted(state.retired) == [4] and state.retired[4]["reason"] == "noisy"
    assert np.allclose(state.slot_offsets[4], 0.0) and sorted(state.slot_offsets) == [1, 2, 3, 4, 5, 6]
    mission_state = SimpleNamespace(retired={}, lost={}, status={})
    restore_retired(mission_state, state.retired)
    assert mission_state.retired[4] == RetiredSensor(4, "noisy", 0.05, 0.01, 12, 10, 30.0)
    assert mission_state.status[4] == PARKED_STATUS


# ------------------------------------------------------------------------ against the mock
class _LeaveAfterRetirement(threading.Thread):
    """Low battery on ``sysid`` (PX4: RTL failsafe, the vehicle leaves the mission) one iteration
    after the log shows a retired sensor (polled, generous timeout)."""

    def __init__(self, fleet, log_path, sysid):
        super().__init__(daemon=True)
        self.fleet, self.log_path, self.sysid = fleet, log_path, sysid
        self.done, self.injected = threading.Event(), threading.Event()

    def run(self):
        deadline = self.fleet.clock.time() + 900.0
        k_leave = None
        while not self.done.is_set() and self.fleet.clock.time() < deadline:
            text = self.log_path.read_text() if self.log_path.exists() else ""
            k = text.count('"type":"iteration"')
            if k_leave is None and "'s sensor retired (" in text:
                k_leave = k + 1
            if k_leave is not None and k >= k_leave:
                self.fleet.set_fault(self.sysid, "battery_low", True)
                self.injected.set()
                return
            self.done.wait(0.05)


def _fly_noisy(log_dir, faulty_sensor: str, max_iterations: int, leave: int | None = None):
    n = 8
    ports = fleet_ports(n, "px4")
    noise = [0.005] * n
    noise[_NOISY - 1] = 0.025
    fleet = MockFleet(n=n, personality="px4", field=sigma2(_SOURCE), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=4, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      sensor_noise_std=noise)
    plan = embedded_plan(n, ports, estimator="robust", radius_m=2.0, start_enu_m=(0.0, 0.0, 11.0),
                         eps=default_eps(sigma2(_SOURCE)), max_iterations=max_iterations, convergence_tol_m=0.5)
    plan = dataclasses.replace(plan, faults=FaultsPlan(faulty_sensor=faulty_sensor, retire_after=5,
                                                      retire_min_noise_ratio=2.0))
    saboteur = _LeaveAfterRetirement(fleet, log_dir / "mission.jsonl", leave) if leave else None
    result = run_with_saboteur(plan, fleet, log_dir, saboteur)
    return plan, result, read_mission_log(log_dir / "mission.jsonl")


@pytest.fixture(scope="module")
def retired_mission(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("retire")
    plan, result, records = _fly_noisy(log_dir, "retire", max_iterations=100, leave=_LEAVING)
    return plan, result, records, audit_mission(log_dir)


def _retire_events(records):
    return [r for r in records if r["type"] == "event" and "'s sensor retired (" in r.get("message", "")]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_noisy_sensor_and_only_it_is_retired_and_the_mission_converges(retired_mission):
    plan, result, records, _ = retired_mission
    messages = [r["message"] for r in records if r["type"] == "event"]
    events = _retire_events(records)
    suspects = [(r["k"], r["suspects"]) for r in records if r["type"] == "iteration"][18:40]
    assert [e["sysid"] for e in events] == [_NOISY], (messages[-20:], suspects)
    ev = events[0]
    assert ev["reason"] == "noisy" and ev["named_for"] >= 5 and ev["ratio"] >= 2.0, ev
    assert "parked at the formation centre" in ev["message"] and "re-formed for 7 (cvt)" in ev["message"]
    assert [x["sysid"] for x in result.retired] == [_NOISY]
    assert [x["sysid"] for x in result.lost] == [_LEAVING]
    assert any(m.startswith("re-forming for 7 vehicles (cvt), sensor of 3 retired: transfer") for m in messages)
    # the loss re-forms the sensing vehicles only; the parked one is part of the transfer, at the centre
    reform = next(r for r in records if r["type"] == "event" and r["message"].startswith("re-forming for 6 "))
    assert reform["parked"] == [_NOISY] and np.allclose(reform["slots"][str(_NOISY)], 0.0), reform
    assert sorted(reform["survivors"]) == [1, 2, 4, 5, 7, 8]
    assert reform["min_separation_m"] >= plan.min_separation_m - 1e-6
    assert result.outcome == "converged", (result.message, messages[-10:])
    error_m = float(np.linalg.norm(np.asarray(result.estimate_enu) - _SOURCE))
    assert error_m < 3.0, error_m   # 6 sensing at D = 2 m: 0.1-2.1 m measured


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_retired_vehicle_is_parked_at_the_centre_and_its_readings_ignored(retired_mission):
    plan, _, records, _ = retired_mission
    k_retired = _retire_events(records)[0]["iteration"]
    its = [r for r in records if r["type"] == "iteration"]
    after = [(r, st) for r, st in zip(its, iteration_statuses(records)) if r["k"] > k_retired]
    assert len(after) >= 5
    for r, statuses in after:
        assert _NOISY not in {x["sysid"] for x in r["readings"]}
        assert len(r["readings"]) in (6, 7)
        pos = np.asarray(r["positions_enu"][str(_NOISY)], dtype=float)
        # the estimate waits for the arrival (arrival_tol_m 0.35 m); the centre is the commanded one
        assert np.linalg.norm(pos - np.asarray(r["centre_enu"])) < 0.75, (r["k"], pos, r["centre_enu"])
        status = statuses[_NOISY]
        assert status["status"] == PARKED_STATUS and status["sensor_retired"] is True
        pts = np.array([p for p in r["positions_enu"].values()], dtype=float)
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + 1e9 * np.eye(len(pts))
        assert d.min() >= 0.8 * plan.min_separation_m
    landed = [r["sysid"] for r in records if r["type"] == "event" and r.get("message", "").endswith("landed")]
    assert sorted(landed) == [s for s in range(1, 9) if s != _LEAVING]   # the parked one came home too


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_tlog_audit_finds_no_violation(retired_mission):
    _, _, _, report = retired_mission
    assert report.violation_counts == {}, report.format_text()
    assert report.setpoints_checked >= 1500 and len(report.per_vehicle) == 8
    assert report.min_separation_seen_m >= report.limits["min_separation_m"] - report.limits["separation_tol_m"]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_keep_retires_nothing(tmp_path):
    _, result, records = _fly_noisy(tmp_path, "keep", max_iterations=40)
    assert _retire_events(records) == [] and result.retired == []
    its = [r for r in records if r["type"] == "iteration"]
    assert all(len(r["readings"]) == 8 for r in its)
    # the estimator did see the noisy sensor (named at most iterations after its warm-up), and
    # it kept its slot, down-weighted
    named = [any(x["sysid"] == _NOISY and x["reason"] == "noisy" for x in r["suspects"]) for r in its[21:]]
    assert len(named) >= 10 and sum(named) >= 0.5 * len(named), [r["suspects"] for r in its[21:]]
