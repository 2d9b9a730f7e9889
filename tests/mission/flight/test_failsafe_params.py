"""Preflight reads the ground-station-loss failsafe parameters, says what each vehicle would do,
warns about vehicles that would hover forever and, with ``require_gcs_failsafe``, refuses them.

The mock serves the parameters with the autopilots' own defaults (ArduPilot ``FS_GCS_ENABLE = 0``,
``FS_GCS_TIMEOUT = 5``; PX4 ``COM_OBL_RC_ACT = 0``, ``NAV_DLL_ACT = 0``, ``COM_OF_LOSS_T = 1``),
PX4's integers encoded bytewise as PX4 does.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mission.core.plan_types import PreflightPlan
from mission.flight.coordinator import Coordinator
from mission.flight.failsafe_params import assess
from mission.sim.embedded import DEFAULT_ORIGIN, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import MissionLog, read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import fly, run_fleet


@pytest.mark.parametrize("flavour, values, hovers, words", [
    ("ardupilot", {"FS_GCS_ENABLE": 0, "FS_GCS_TIMEOUT": 5.0}, True, "FS_GCS_ENABLE = 0"),
    ("ardupilot", {"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 5.0}, False, "RTL after 5 s"),
    ("ardupilot", {"FS_GCS_ENABLE": 5, "FS_GCS_TIMEOUT": 12.5}, False, "land after 12.5 s"),
    ("ardupilot", {"FS_GCS_TIMEOUT": 5.0}, None, "FS_GCS_ENABLE not reported"),
    ("px4", {"COM_OBL_RC_ACT": 0, "NAV_DLL_ACT": 0, "COM_OF_LOSS_T": 1.0, "COM_DL_LOSS_T": 10}, True,
     "on offboard loss (1 s): position mode"),
    ("px4", {"COM_OBL_RC_ACT": 5, "NAV_DLL_ACT": 1}, True, "on data-link loss: hold"),
    ("px4", {"COM_OBL_RC_ACT": 4, "NAV_DLL_ACT": 0, "COM_OF_LOSS_T": 1.0}, False, "offboard loss (1 s): land"),
    ("px4", {"COM_OBL_RC_ACT": 0, "NAV_DLL_ACT": 2, "COM_DL_LOSS_T": 10}, False, "data-link loss (10 s): return"),
    ("px4", {"COM_OBL_RC_ACT": 0}, None, "not reported"),
    ("generic", {}, None, "not checked"),
])
def test_assess(flavour, values, hovers, words):
    a = assess(flavour, values)
    assert a.hovers_forever is hovers
    assert words in a.action


def _fleet_and_plan(personality, params, require):
    n = 4
    ports = fleet_ports(n, personality)
    fleet = MockFleet(n=n, personality=personality, field=sigma2(np.array([4.0, 3.0, 12.0])),
                      origin=DEFAULT_ORIGIN, clock=VirtualClock(), seed=5,
                      udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=ports["tcp_base_port"], zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      params=params)
    plan = embedded_plan(n, ports, personality=personality, start_enu_m=(0.0, 0.0, 12.0), eps=50.0)
    return fleet, dataclasses.replace(plan, preflight=PreflightPlan(require_gcs_failsafe=require))


def _dry_run(tmp_path, personality, params, require):
    fleet, plan = _fleet_and_plan(personality, params, require)

    async def main(world):
        import zenoh

        session = zenoh.open(plan.zenoh.to_config())  # readings are a readiness check too
        log = MissionLog(tmp_path / "d.jsonl", fleet.clock)
        try:
            co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log)
            world.store = co.store
            return await co.dry_run()
        finally:
            log.close()
            session.close()
    try:
        result = run_fleet(fleet, main)
    finally:
        fleet.stop()
    events = [r for r in read_mission_log(tmp_path / "d.jsonl") if r["type"] == "event"
              and "if the ground station dies" in r["message"]]
    return result, events


@pytest.mark.timeout(300)
@pytest.mark.parametrize("personality, params, hovers", [
    ("ardupilot", {}, True),                       # ArduPilot's default: GCS failsafe disabled
    ("ardupilot", {"FS_GCS_ENABLE": 1}, False),
    ("px4", {}, True),                             # PX4's defaults: hold on both losses
    ("px4", {"COM_OBL_RC_ACT": 4}, False),         # bytewise INT32 decoded: land
])
def test_dry_run_reports_the_failsafe_and_warns(tmp_path, personality, params, hovers):
    result, events = _dry_run(tmp_path, personality, params, require=False)
    assert result.outcome == "ready", result.message       # a warning, not a refusal
    assert len(events) == 1 and events[0]["sysids"] == [1, 2, 3, 4]
    assert events[0]["hovers_forever"] is hovers
    assert events[0]["level"] == ("warning" if hovers else "info")
    for r in result.readiness:
        assert "gcs_failsafe" not in r["checks"]
        assert bool(r["warnings"]) is hovers
    if personality == "px4" and not hovers:
        assert "on offboard loss (1 s): land" in events[0]["message"]
        assert events[0]["failsafe"]["1"]["COM_OBL_RC_ACT"] == 4


@pytest.mark.timeout(300)
def test_required_failsafe_makes_hovering_vehicles_not_ready(tmp_path):
    result, events = _dry_run(tmp_path, "ardupilot", [{"FS_GCS_ENABLE": 5}] * 3 + [{}], require=True)
    assert result.outcome == "not_ready"
    by = {r["sysid"]: r for r in result.readiness}
    assert all(by[s]["ready"] and by[s]["checks"]["gcs_failsafe"] for s in (1, 2, 3))
    assert by[4]["checks"]["gcs_failsafe"] is False
    assert "failsafe required by the plan" in by[4]["problems"][0]
    assert {e["level"] for e in events} == {"info", "error"}


@pytest.mark.timeout(300)
def test_fly_refuses_without_the_required_failsafe(tmp_path):
    fleet, plan = _fleet_and_plan("px4", {}, require=True)
    try:
        result = run_fleet(fleet, lambda world: fly(plan, fleet, tmp_path / "m.jsonl", world=world))
        armed = [v.armed for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert result.outcome == "aborted" and "preflight failed" in result.message
    assert "ground-station-loss failsafe required" in result.message
    assert not any(armed)
