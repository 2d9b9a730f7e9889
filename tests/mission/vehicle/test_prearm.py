"""The autopilot's own pre-arm state: read from telemetry, served by the mock like ArduCopter SITL,
waited for by preflight / dry-run, and arming retried while it is refused.

The mock's ArduPilot EKF start-up (``SIM_EKF_GPS_S``, :mod:`sitl_mock.ap_prearm`) follows what
ArduCopter 4.7 SITL was measured to do: EKF flags 0xa7 then 0x33f, ``Arm: Need Position
Estimate`` (FAILED) in GUIDED, the SYS_STATUS pre-arm bit judged for the current mode.
"""
from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mission.core.plan_types import PlanError, PreflightPlan
from mission.core.plan import parse_plan
from mission.flight.coordinator import Coordinator
from mission.flight.readiness_autopilot import arm_and_takeoff
from mission.flight.state import MissionError
from mission.sim.embedded import DEFAULT_ORIGIN, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.vehicle.prearm import EKF_NEEDED, PrearmStatus
from mission.vehicle.state import CommandError
from sitl_mock.ap_prearm import EKF_FLAGS_NO_GPS, EKF_FLAGS_OK, PREARM_REPORT_INTERVAL_S
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import fly, run_fleet
from tests.sitl_mock.test_mock_autopilot import Harness

_PREARM = mav.MAV_SYS_STATUS_PREARM_CHECK
_GPS = mav.MAV_SYS_STATUS_SENSOR_GPS


# --------------------------------------------------------------------------- PrearmStatus
def _sys_status(enabled: int, health: int):
    return mav.MAVLink_sys_status_message(enabled, enabled, health, 0, 12000, -1, 80, 0, 0, 0, 0, 0, 0)


def _text(s: str):
    return mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, s.encode())


def test_status_reads_sys_status_bits_ekf_flags_and_refusal_texts():
    st = PrearmStatus("ardupilot")
    assert st.problems(0.0) == ["no SYS_STATUS received yet", "no EKF_STATUS_REPORT received yet"]
    enabled = _PREARM | _GPS | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
    st.on_sys_status(_sys_status(enabled, enabled & ~_PREARM & ~mav.MAV_SYS_STATUS_SENSOR_3D_MAG))
    st.on_ekf_status(mav.MAVLink_ekf_status_report_message(0xA7, 0, 0, 0, 0, 0))
    st.on_statustext(_text("EKF3 IMU0 initialised"), 1.0)   # not a refusal: ignored
    st.on_statustext(_text("Arm: Need Position Estimate"), 2.0)
    problems = st.problems(3.0)
    assert len(problems) == 3
    assert "PREARM_CHECK unhealthy" in problems[0] and "'Arm: Need Position Estimate'" in problems[0]
    assert problems[1] == "unhealthy sensors: 3D_MAG"
    assert "0xa7" in problems[2] and "CONST_POS_MODE" in problems[2] and "Need Position Estimate" in problems[2]
    assert st.autopilot_says(2.0 + 100.0) is None  # an old text is not today's reason
    st.on_sys_status(_sys_status(enabled, enabled))
    st.on_ekf_status(mav.MAVLink_ekf_status_report_message(0x33F, 0, 0, 0, 0, 0))
    assert st.problems(3.0) == []
    st.on_ekf_status(mav.MAVLink_ekf_status_report_message(0x33F | mav.EKF_GPS_GLITCHING, 0, 0, 0, 0, 0))
    assert "GPS_GLITCHING" in st.problems(3.0)[0]


def test_status_px4_estimator_flags_only_when_sent():
    st = PrearmStatus("px4")
    st.on_sys_status(_sys_status(_PREARM, _PREARM))
    assert st.problems(0.0) == []  # PX4 needs no EKF_STATUS_REPORT
    st.on_estimator_status(mav.MAVLink_estimator_status_message(0, mav.ESTIMATOR_ATTITUDE, 0, 0, 0, 0, 0, 0, 0, 0))
    assert "ESTIMATOR_STATUS" in st.problems(0.0)[0]
    assert EKF_NEEDED & 0x33F == EKF_NEEDED and EKF_NEEDED & 0xA7 != EKF_NEEDED  # measured on the SITL


def test_px4_sih_state_as_measured_is_ready_with_a_warning_for_its_missing_rc():
    """PX4 v1.16 SIH: ESTIMATOR_STATUS flags 0x3ff (CONST_POS_MODE among them) and an RC receiver
    present, enabled and unhealthy; it arms and flies offboard, so neither blocks."""
    rc = mav.MAV_SYS_STATUS_SENSOR_RC_RECEIVER
    st = PrearmStatus("px4")
    st.on_sys_status(_sys_status(_PREARM | _GPS | rc, _PREARM | _GPS))
    st.on_estimator_status(mav.MAVLink_estimator_status_message(0, 0x3FF, 0, 0, 0, 0, 0, 0, 0, 0))
    assert st.problems(0.0) == []
    assert len(st.notes()) == 1 and "RC_RECEIVER unhealthy" in st.notes()[0]
    st.on_estimator_status(mav.MAVLink_estimator_status_message(0, 0x3FF & ~mav.ESTIMATOR_POS_HORIZ_ABS,
                                                                0, 0, 0, 0, 0, 0, 0, 0))
    assert len(st.problems(0.0)) == 1 and "estimator has no usable position" in st.problems(0.0)[0]
    st.on_sys_status(_sys_status(_PREARM | _GPS | rc, _PREARM | rc))  # GPS unhealthy: blocks
    assert any("unhealthy sensors: GPS" in p for p in st.problems(0.0))


# --------------------------------------------------------------------------- the mock
def _texts(h) -> list[str]:
    return [m.text for m in h.received if m.get_type() == "STATUSTEXT"]


def _last(h, kind):
    return [m for m in h.received if m.get_type() == kind][-1]


def test_mock_ardupilot_refuses_guided_arming_until_the_ekf_uses_the_gps():
    h = Harness("ardupilot", SIM_EKF_GPS_S=40.0)
    h.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 1e6)
    h.run(5.0)   # GPS fix (2 s), home set, EKF still without GPS
    assert h.ap.home is not None
    assert _last(h, "EKF_STATUS_REPORT").flags == EKF_FLAGS_NO_GPS
    # STABILIZE (boot mode) needs no position: the pre-arm bit reads healthy, as on the SITL
    assert _last(h, "SYS_STATUS").onboard_control_sensors_health & _PREARM
    assert h.set_mode("GUIDED") == mav.MAV_RESULT_ACCEPTED
    assert h.arm() == mav.MAV_RESULT_FAILED
    assert "Arm: Need Position Estimate" in _texts(h)
    h.run(1.5)
    assert not _last(h, "SYS_STATUS").onboard_control_sensors_health & _PREARM
    assert h.command(mav.MAV_CMD_RUN_PREARM_CHECKS) == mav.MAV_RESULT_ACCEPTED
    assert _texts(h)[-1] == "PreArm: Need Position Estimate"
    before = len(_texts(h))
    h.run(PREARM_REPORT_INTERVAL_S + 1.0)   # repeated every 30 s while disarmed
    assert "PreArm: Need Position Estimate" in _texts(h)[before:]
    h.run(42.5 - h.t)
    assert _last(h, "EKF_STATUS_REPORT").flags == EKF_FLAGS_OK
    assert _last(h, "SYS_STATUS").onboard_control_sensors_health & _PREARM
    assert h.arm() == mav.MAV_RESULT_ACCEPTED


def test_mock_without_delay_is_ready_after_the_gps_warmup():
    h = Harness("ardupilot")
    h.run(2.5)
    assert h.set_mode("GUIDED") == mav.MAV_RESULT_ACCEPTED
    assert h.arm() == mav.MAV_RESULT_ACCEPTED
    assert Harness("px4").command(mav.MAV_CMD_RUN_PREARM_CHECKS) == mav.MAV_RESULT_UNSUPPORTED


# --------------------------------------------------------------------------- plan keys
def _doc(**preflight):
    return {"version": 1, "fleet": "f", "origin": {"lat_deg": 45.0, "lon_deg": 5.0},
            "vehicles": [{"sysid": i, "connection": f"udpin:127.0.0.1:{14540 + i}"} for i in range(1, 5)],
            "geofence": {"polygon_enu_m": [[-50, -50], [50, -50], [50, 50], [-50, 50]]},
            **({"preflight": preflight} if preflight else {})}


def test_plan_preflight_section():
    assert parse_plan(_doc()).preflight == PreflightPlan()
    plan = parse_plan(_doc(autopilot_ready_timeout_s=30, require_gcs_failsafe=True))
    assert plan.preflight == PreflightPlan(autopilot_ready_timeout_s=30.0, require_gcs_failsafe=True)
    with pytest.raises(PlanError) as err:
        parse_plan(_doc(autopilot_ready_timeout_s=0, require_gcs_failsafe="yes", wait=1))
    keys = [k for k, _ in err.value.problems]
    assert keys == ["preflight.wait", "preflight.autopilot_ready_timeout_s", "preflight.require_gcs_failsafe"]


# --------------------------------------------------------------------------- lock-step missions
def _ardupilot_fleet(tmp_path, ekf_s: float, ready_timeout_s: float):
    n = 4
    ports = fleet_ports(n, "ardupilot")
    source = np.array([4.0, 3.0, 12.0])
    fleet = MockFleet(n=n, personality="ardupilot", field=sigma2(source), origin=DEFAULT_ORIGIN,
                      clock=VirtualClock(), seed=3, udp_base_port=0, tcp_base_port=ports["tcp_base_port"],
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      params={"SIM_EKF_GPS_S": ekf_s})
    plan = embedded_plan(n, ports, personality="ardupilot", start_enu_m=(0.0, 0.0, 12.0), eps=50.0)
    plan = dataclasses.replace(plan, preflight=PreflightPlan(autopilot_ready_timeout_s=ready_timeout_s))
    return fleet, plan


@pytest.mark.timeout(300)
def test_dry_run_is_not_ready_while_the_ekf_has_no_position(tmp_path):
    fleet, plan = _ardupilot_fleet(tmp_path, ekf_s=40.0, ready_timeout_s=10.0)

    async def main(world):
        import zenoh

        session = zenoh.open(plan.zenoh.to_config())
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
        armed = [v.armed for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert result.outcome == "not_ready" and not any(armed)
    for r in result.readiness:
        assert r["checks"]["position"] and r["checks"]["home"] and r["checks"]["armable"]
        assert r["checks"]["autopilot"] is False
        assert any("Need Position Estimate" in p and "after 10 s" in p for p in r["problems"]), r["problems"]
    events = [r["message"] for r in read_mission_log(tmp_path / "d.jsonl") if r["type"] == "event"]
    assert any(m.startswith("preflight: waiting for the autopilots' own readiness") for m in events)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_fly_waits_for_the_autopilots_then_flies(tmp_path):
    """The case seen on ArduCopter SITL: fly started right after boot; ArduCopter needs 40 s for its EKF."""
    fleet, plan = _ardupilot_fleet(tmp_path, ekf_s=40.0, ready_timeout_s=120.0)
    try:
        result = run_fleet(fleet, lambda world: fly(plan, fleet, tmp_path / "m.jsonl", world=world))
    finally:
        fleet.stop()
    assert result.outcome == "converged", result.message
    records = read_mission_log(tmp_path / "m.jsonl")
    waited = [r for r in records if r["type"] == "event" and r["message"].startswith("preflight: every autopilot")]
    assert len(waited) == 1 and 35.0 <= waited[0]["waited_s"] <= 45.0
    progress = [r for r in records if r["type"] == "event" and "waiting for the autopilots" in r["message"]]
    assert len(progress) >= 5 and "Need Position Estimate" in progress[0]["message"]
    assert not [r for r in records if r["type"] == "event" and "arming refused" in r["message"]]


# --------------------------------------------------------------------------- arming retries
class _Clock:
    def __init__(self):
        self.t = 0.0

    def time(self):
        return self.t

    async def sleep(self, dt):
        self.t += dt
        await asyncio.sleep(0)


class _Co:
    def __init__(self, timeout_s):
        self.clock = _Clock()
        self.plan = dataclasses.replace(embedded_plan(4, {"udp_base_port": 14540, "zenoh_port": 7447}),
                                        preflight=PreflightPlan(autopilot_ready_timeout_s=timeout_s))
        self.events = []

    def event(self, message, level="info", **fields):
        self.events.append((level, message))


class _Vehicle:
    """An ArduPilot link whose arming is refused ``refusals`` times and whose RC forces STABILIZE
    right after the first successful arming."""

    flavour = "ardupilot"
    sysid = 3

    def __init__(self, co, refusals):
        self.co, self.refusals = co, refusals
        self.state = type("S", (), {"mode": "STABILIZE"})()
        self.prearm = PrearmStatus("ardupilot")
        self.calls = []

    async def set_mode(self, name):
        self.calls.append(("mode", name))
        self.state.mode = name

    def request_heartbeat(self, min_interval_s=0.5):
        return True

    async def wait_for(self, predicate, timeout_s, what):
        assert predicate(self.state)

    async def arm(self):
        self.calls.append(("arm",))
        if self.refusals:
            self.refusals -= 1
            self.prearm.on_statustext(_text("Arm: Need Position Estimate"), self.co.clock.time())
            raise CommandError("arm failed: FAILED", sysid=3, command=mav.MAV_CMD_COMPONENT_ARM_DISARM,
                               result=mav.MAV_RESULT_FAILED)
        self.state.mode = "STABILIZE"  # the RC input switched the mode

    async def command_long(self, command, *params, timeout_s=1.0, **kw):
        self.calls.append(("takeoff", self.state.mode, params[-1]))


def test_arming_retried_with_the_autopilot_words_and_mode_set_again():
    co = _Co(timeout_s=30.0)
    v = _Vehicle(co, refusals=4)
    asyncio.run(arm_and_takeoff(3, v, 10.0, co.clock, co, co.plan.preflight.autopilot_ready_timeout_s))
    assert [c[0] for c in v.calls].count("arm") == 5
    assert v.calls[-2:] == [("mode", "GUIDED"), ("takeoff", "GUIDED", 10.0)]  # re-set after arming
    warnings = [m for lvl, m in co.events if lvl == "warning"]
    assert warnings[0].startswith("vehicle 3: arming refused: Arm: Need Position Estimate; retrying")
    assert len([m for m in warnings if "arming refused" in m]) == 1  # the same reason is shown once
    assert any("mode STABILIZE after arming" in m for m in warnings)


def test_arming_gives_up_at_the_timeout():
    co = _Co(timeout_s=5.0)
    v = _Vehicle(co, refusals=1000)
    with pytest.raises(MissionError, match=r"takeoff of vehicle 3 failed \(arming refused for 5 s\)"):
        asyncio.run(arm_and_takeoff(3, v, 10.0, co.clock, co, co.plan.preflight.autopilot_ready_timeout_s))
    assert 5.0 <= co.clock.t <= 7.0


def test_dry_run_ready_timeout_option_is_checked(capsys):
    from mission.cli import main as cli_main

    with pytest.raises(SystemExit) as exit_info:  # refused by argparse (the option's type)
        cli_main(["dry-run", "--plan", "mission/examples/sitl_plan.toml", "--ready-timeout", "-1"])
    assert exit_info.value.code == 2
    assert "--ready-timeout: expected a number >= 0, got '-1'" in capsys.readouterr().err
