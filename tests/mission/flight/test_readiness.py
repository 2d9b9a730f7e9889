"""Readiness means ready to seek: a reading from every sensor, the zenoh session up,
the start point and every vehicle's path to its slot inside the geofence. ``dry-run`` reports each
check; ``fly`` arms nothing when one fails; ``[preflight] require_readings = false`` relaxes the
sensor check; an unreachable zenoh endpoint is said in plain words; a start outside the fence is
a plan error."""
from __future__ import annotations

import copy
import dataclasses
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mission.cli.cmd_dryrun import dry_run, format_readiness
from mission.core.plan_types import GeofencePlan, PlanError
from mission.core.plan import parse_plan
from mission.core.zenoh_config import ZenohPlan
from mission.sim.embedded import DEFAULT_ORIGIN, embedded_plan, fleet_ports, free_port_block
from mission.sim.lockstep import VirtualClock
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import fly, run_fleet

pytestmark = pytest.mark.timeout(300)

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"


# ----------------------------------------------------------------------------- the plan check
@pytest.mark.parametrize("start, why", [([80.0, 0.0, 15.0], "outside the geofence polygon"),
                                        ([59.0, 0.0, 15.0], "would cross it")])
def test_a_start_outside_the_fence_is_a_plan_error(start, why):
    doc = tomllib.loads(SAMPLE.read_text())
    doc["seeking"]["start_enu_m"] = start
    with pytest.raises(PlanError) as err:
        parse_plan(copy.deepcopy(doc))
    assert ("seeking.start_enu_m", ) == tuple(k for k, _ in err.value.problems)
    assert why in str(err.value)


def test_a_start_inside_the_fence_passes_the_plan_check():
    doc = tomllib.loads(SAMPLE.read_text())
    doc["seeking"]["start_enu_m"] = [50.0, -50.0, 15.0]  # 10 m from two edges, radius 2 m
    assert np.allclose(parse_plan(doc).seeking.start_point(), [50.0, -50.0, 15.0])


@pytest.mark.parametrize("key, value", [("require_readings", "no"), ("readings_timeout_s", 0.0)])
def test_preflight_reading_keys_are_checked(key, value):
    doc = tomllib.loads(SAMPLE.read_text())
    doc["preflight"] = {key: value}
    with pytest.raises(PlanError) as err:
        parse_plan(doc)
    assert [k for k, _ in err.value.problems] == [f"preflight.{key}"]


# ----------------------------------------------------------------------------- against the mock
def _fleet_and_plan(**plan_kw):
    n = 4
    ports = fleet_ports(n, "px4")
    source = np.array([5.0, 5.0, 12.0])
    fleet = MockFleet(n=n, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=7, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="swarmseek", zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    plan = embedded_plan(n, ports, start_enu_m=(0.0, 0.0, 12.0), eps=50.0, max_iterations=3)
    return fleet, dataclasses.replace(plan, **plan_kw)


def _no_sensor_zenoh():
    """A zenoh plan that is up (it listens) but that no sensor reaches."""
    return ZenohPlan(mode="peer", listen=(f"tcp/127.0.0.1:{free_port_block(1, kinds=('tcp',))}",))


def _dry_run(fleet, plan):
    try:
        return run_fleet(fleet, lambda world: _dry_run_in(plan, fleet, world))
    finally:
        fleet.stop()


async def _dry_run_in(plan, fleet, world):
    import zenoh

    session = None
    problem = None
    try:
        session = zenoh.open(plan.zenoh.to_config())
    except zenoh.ZError as exc:
        problem = exc
    try:
        if problem is not None:  # dry_run opens it itself and reports why it cannot
            return await dry_run(plan, clock=fleet.clock)
        _hook_store(world)
        return await dry_run(plan, clock=fleet.clock, zenoh_session=session)
    finally:
        if session is not None:
            session.close()


def _hook_store(world):
    """In lock-step the world must know where readings arrive: patch Coordinator to tell it."""
    from mission.flight import coordinator as coordinator_module

    original = coordinator_module.Coordinator.__init__

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        world.store = self.store
        coordinator_module.Coordinator.__init__ = original
    coordinator_module.Coordinator.__init__ = init


def _checks(result):
    return {c["name"]: c for c in result.mission_checks}


def test_dry_run_reports_every_check_ready():
    fleet, plan = _fleet_and_plan()
    result = _dry_run(fleet, plan)
    checks = _checks(result)
    assert set(checks) == {"zenoh", "readings", "start_in_fence", "path_in_fence"}
    assert all(c["ok"] for c in checks.values()), checks
    assert result.outcome == "ready"
    lines = format_readiness(result)
    for name in checks:
        assert any(line.startswith(f"check {name}") and " ok " in line for line in lines), lines


def test_no_reading_is_not_ready_unless_the_plan_relaxes_it():
    fleet, plan = _fleet_and_plan(zenoh=_no_sensor_zenoh())
    result = _dry_run(fleet, plan)
    checks = _checks(result)
    assert result.outcome == "not_ready" and "readings failed" in result.message
    assert not checks["readings"]["ok"] and "require_readings = false" in checks["readings"]["detail"]
    assert checks["zenoh"]["ok"]
    assert all(r["checks"]["reading"] is False and not r["ready"] for r in result.readiness)
    # relaxed: a warning, ready
    fleet, plan = _fleet_and_plan(zenoh=_no_sensor_zenoh())
    plan = dataclasses.replace(plan, preflight=dataclasses.replace(plan.preflight, require_readings=False,
                                                                   readings_timeout_s=2.0))
    result = _dry_run(fleet, plan)
    assert result.outcome == "ready", result.message
    assert "WARNING" in _checks(result)["readings"]["detail"]


def test_fly_arms_nothing_without_readings(tmp_path):
    fleet, plan = _fleet_and_plan(zenoh=_no_sensor_zenoh())
    try:
        result = run_fleet(fleet, lambda world: fly(plan, fleet, tmp_path / "m.jsonl", world=world))
        armed = [v.armed for v in fleet.vehicles]
    finally:
        fleet.stop()
    assert result.outcome == "aborted" and "not ready to seek, nothing armed" in result.message
    assert "no sensor reading" in result.message
    assert not any(armed)


def test_start_outside_the_fence_fails_the_dry_run():
    """A plan built in code (not parsed) with its start outside the fence: the dry run says so."""
    fleet, plan = _fleet_and_plan()
    plan = dataclasses.replace(plan, seeking=dataclasses.replace(plan.seeking, start_enu_m=(200.0, 0.0, 12.0)))
    result = _dry_run(fleet, plan)
    checks = _checks(result)
    assert result.outcome == "not_ready"
    assert not checks["start_in_fence"]["ok"] and "outside the geofence" in checks["start_in_fence"]["detail"]
    assert not checks["path_in_fence"]["ok"]


def test_a_path_across_a_notch_of_the_fence_fails_the_dry_run():
    """An L-shaped fence: start and homes inside, but the straight way from the homes to the
    start crosses the notch."""
    fleet, plan = _fleet_and_plan()
    fence = GeofencePlan(polygon_en_m=((-20.0, -20.0), (60.0, -20.0), (60.0, 60.0), (30.0, 60.0), (30.0, 10.0),
                                       (-20.0, 10.0)), min_alt_m=plan.geofence.min_alt_m, max_alt_m=80.0)
    plan = dataclasses.replace(plan, geofence=fence,
                               seeking=dataclasses.replace(plan.seeking, start_enu_m=(45.0, 45.0, 12.0)))
    result = _dry_run(fleet, plan)
    checks = _checks(result)
    assert checks["start_in_fence"]["ok"], checks["start_in_fence"]
    assert not checks["path_in_fence"]["ok"] and "leaves the geofence" in checks["path_in_fence"]["detail"]
    assert result.outcome == "not_ready"


def test_unreachable_zenoh_endpoint_is_said_in_plain_words():
    fleet, plan = _fleet_and_plan()
    nowhere = free_port_block(1, kinds=("tcp",))
    plan = dataclasses.replace(plan, zenoh=ZenohPlan(mode="client", connect=(f"tcp/127.0.0.1:{nowhere}",)))
    result = _dry_run(fleet, plan)
    zenoh_check = _checks(result)["zenoh"]
    assert result.outcome == "not_ready" and not zenoh_check["ok"]
    assert f"cannot reach the zenoh endpoint(s) tcp/127.0.0.1:{nowhere}" in zenoh_check["detail"]
    assert ".rs:" not in zenoh_check["detail"]


def test_fly_with_an_unreachable_zenoh_endpoint_exits_1_in_plain_words(tmp_path):
    nowhere = free_port_block(1, kinds=("tcp",))
    text = SAMPLE.read_text().replace('mode = "peer"\nlisten = ["tcp/127.0.0.1:7447"]',
                                      f'mode = "client"\nconnect = ["tcp/127.0.0.1:{nowhere}"]')
    assert f"tcp/127.0.0.1:{nowhere}" in text
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "mission", "fly", "--plan", str(plan_path), "--log-dir",
                           str(tmp_path / "logs"), "--no-tlog"], capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 1, proc.stderr
    assert f"cannot reach the zenoh endpoint(s) tcp/127.0.0.1:{nowhere}" in proc.stderr
    assert "nothing armed" in proc.stderr and ".rs:" not in proc.stderr and "Traceback" not in proc.stderr
