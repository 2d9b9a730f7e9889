"""Faulty-sensor detection feeds every seeker (mission.flight.sensor_check).

Unit: the detector's exclusions, the readings it keeps, Theorem 2 without the excluded sensor.
Missions (lock-step ``swarmseek run``, vehicle 2's sensor stuck from the start): with every
seeker and the defaults (``faulty_sensor = "retire"``, the formation's estimator) the stuck sensor
is named and excluded, its readings kept from the seeker, and the mission converges near the
source; with ``--faulty-sensor off`` the default model seeker ends metres away; retirement
happens with the model seeker too (``retire_after = 5``).

The missions fly 6 vehicles (:data:`FLEET`; 7 for the gradient seeker, see :data:`FLEET_BY_SEEKER`)
rather than run's default 8, for CPU: each claim holds there as with 8 (measured at seed 0). The gradient
seeker's mission starts nearer the source (:data:`START_BY_SEEKER`), also for CPU.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from formation import cvt_sphere
from mission.cli import cmd_run
from mission.cli import main as cli_main
from mission.core.plan_types import FaultsPlan
from mission.flight.sensor_check import SensorCheck, make_check
from mission.flight.seeking import GradientEstimate
from mission.telemetry.mission_log import read_mission_log

GRAD = np.array([0.3, -0.2, 0.1])
#: the missions' fleet size (``--n``): with vehicle 2 excluded, 5 healthy sensors still fit the
#: model, newton and plume seekers' estimates (errors 0.05-0.6 m measured) and without detection
#: the model seeker still ends far away (15 m measured)
FLEET = "6"
#: the paper's gradient seeker on the CVT estimator needs one more: with 6 vehicles and vehicle 2
#: retired it settles 4.2 m off (measured), with 7 within 0.6 m (0.3 m with 8)
FLEET_BY_SEEKER = {"gradient": "7"}
#: the gradient seeker's 1 m steps make it the slowest: it starts 12.6 m from seed 0's source (5.5, -9.2, 12.2)
#: instead of run's 25 m, for CPU (37 iterations instead of 52, the stuck sensor still named at iteration 6,
#: error 0.24 m measured); the other seekers start where run starts them (nearer took them more iterations)
START_BY_SEEKER = {"gradient": "18,-8,11"}


class _R:
    def __init__(self, sysid, value):
        self.sysid, self.value = sysid, value


def _feed(check, updates, stuck_sysid=None, seed=0):
    rng = np.random.default_rng(seed)
    off = cvt_sphere(len(check.sysids), 2.0, 0)
    for t in range(updates):
        centre = np.array([0.5 * t, 0.0, 10.0])
        pos = centre + off
        values = pos @ GRAD + 0.005 * rng.standard_normal(len(pos))
        if stuck_sysid is not None:
            values[check.sysids.index(stuck_sysid)] = 1.234
        check.update(check.sysids, pos, values, pos.mean(axis=0))
    return pos, values


def test_a_stuck_sensor_is_excluded_once_named_and_its_readings_dropped():
    check = SensorCheck([1, 2, 3, 4, 5, 6, 7, 8])
    seen = []
    rng = np.random.default_rng(1)
    off = cvt_sphere(8, 2.0, 0)
    for t in range(12):
        pos = np.array([0.5 * t, 0.0, 10.0]) + off
        values = pos @ GRAD + 0.005 * rng.standard_normal(8)
        values[2] = 1.234  # sysid 3
        check.update(check.sysids, pos, values, pos.mean(axis=0))
        seen.append(set(check.newly_excluded))
    assert check.excluded == {3}
    assert [s for s in seen if s] == [{3}]  # newly excluded once
    readings = [_R(s, v) for s, v in zip(check.sysids, values)]
    kept, kept_pos = check.keep(readings, pos)
    assert [r.sysid for r in kept] == [1, 2, 4, 5, 6, 7, 8] and kept_pos.shape == (7, 3)
    g = check.gradient(pos, values, check.sysids)
    assert g is not None and np.allclose(g, GRAD, atol=0.02)


def test_no_exclusion_without_a_fault_and_other_vehicles_skip_the_update():
    check = SensorCheck([1, 2, 3, 4, 5, 6])
    _feed(check, 15)
    assert check.excluded == set()
    check.update([1, 2, 3, 4, 5], np.zeros((5, 3)), np.zeros(5), np.zeros(3))
    assert check.failure and "not of every sensing vehicle" in check.failure


def test_the_robust_estimator_is_the_detector_when_it_is_the_plans():
    est = GradientEstimate("robust", 6)
    check = make_check(FaultsPlan(), est, [1, 2, 3, 4, 5, 6])
    assert check.shared and check.robust is est.robust
    assert not make_check(FaultsPlan(), GradientEstimate("cvt", 6), [1, 2, 3, 4, 5, 6]).shared
    assert make_check(FaultsPlan(faulty_sensor="off"), est, [1, 2, 3, 4, 5, 6]) is None


@pytest.fixture
def stuck_fleet(monkeypatch):
    """Vehicle 2's sensor stuck from the start in the `swarmseek run` fleets of this test."""
    real = cmd_run._make_fleet

    def _stuck(*args, **kwargs):
        fleet = real(*args, **kwargs)
        fleet.set_fault(2, "sensor_stuck", True)
        return fleet

    monkeypatch.setattr(cmd_run, "_make_fleet", _stuck)


def _run(tmp_path, capsys, *extra):
    log_dir = tmp_path / "log"
    cli_main(["run", "--json", "--no-tlog", "--log-dir", str(log_dir), *extra])
    return json.loads(capsys.readouterr().out), read_mission_log(log_dir / "mission.jsonl")


def _named_stuck(records) -> bool:
    return any(s["sysid"] == 2 and s["reason"] == "stuck" and s["excluded"]
               for r in records if r["type"] == "iteration" for s in r.get("suspects") or ())


@pytest.mark.parametrize("seeker", ["gradient", "newton", "model", "plume"])
def test_every_seeker_converges_with_a_stuck_sensor_by_default(tmp_path, capsys, stuck_fleet, seeker):
    start = ("--start", START_BY_SEEKER[seeker]) if seeker in START_BY_SEEKER else ()
    summary, records = _run(tmp_path, capsys, "--seeker", seeker, "--n", FLEET_BY_SEEKER.get(seeker, FLEET), *start)
    assert _named_stuck(records)
    assert summary["outcome"] == "converged", summary["message"]
    assert summary["error_m"] < 2.5, summary["error_m"]
    for x in summary["retired"]:  # retired or not (the seek may converge first), never a healthy one
        assert x["sysid"] == 2 and x["reason"] == "stuck"


def test_without_detection_the_model_seeker_is_misled(tmp_path, capsys, stuck_fleet):
    summary, records = _run(tmp_path, capsys, "--faulty-sensor", "off", "--n", FLEET)
    assert not any(r.get("suspects") for r in records if r["type"] == "iteration")
    # 15 m measured with 6 vehicles (8.3 m with 8): the stuck readings shrank the trust region
    assert summary["error_m"] > 4.0


def test_the_model_seeker_retires_the_stuck_sensor(tmp_path, capsys, stuck_fleet, monkeypatch):
    import mission.sim.embedded as embedded

    real = embedded.embedded_plan

    def _plan(*args, **kwargs):
        plan = real(*args, **kwargs)
        return dataclasses.replace(plan, faults=dataclasses.replace(plan.faults, retire_after=5))

    monkeypatch.setattr(embedded, "embedded_plan", _plan)
    summary, records = _run(tmp_path, capsys, "--n", FLEET)
    assert [(x["sysid"], x["reason"]) for x in summary["retired"]] == [(2, "stuck")]
    assert summary["outcome"] == "converged" and summary["error_m"] < 2.5
    parked = [r for r in records if r["type"] == "iteration" and r["k"] > summary["retired"][0]["iteration"]]
    assert parked and all(2 not in {s["sysid"] for s in r.get("suspects") or ()} for r in parked)
