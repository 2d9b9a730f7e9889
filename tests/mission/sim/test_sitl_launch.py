"""The SITL launcher without running a SITL: settings, per-instance commands and ports, homes,
free layouts, and the plan written for a fleet (scaled for a speed-up)."""
from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from formation.geodesy import geodetic_to_enu
from mission.core.plan import load_plan
from mission.sim.sitl_fleet import SitlFleetConfig
from mission.sim.sitl_launch import instance_specs, pick_layout, spread_homes
from mission.sim.sitl_plan import write_plan
from mission.sim.sitl_settings import SitlSetupError, resolve_sitl_dir


def _fake_sitl(tmp_path: Path, flavour: str) -> Path:
    root = tmp_path / flavour
    if flavour == "px4":
        (root / "etc" / "init.d-posix").mkdir(parents=True)
        (root / "etc" / "init.d-posix" / "rcS").write_text("")
        (root / "bin").mkdir()
        binary = root / "bin" / "px4"
        (root / "bin" / "px4-param").write_text("px4")  # a module link copied as a plain file
    else:
        (root / "bin").mkdir(parents=True)
        (root / "copter.parm").write_text("")
        binary = root / "bin" / "arducopter"
    binary.write_text("#!/bin/sh\n")
    binary.chmod(0o755)
    return root


def test_resolve_prefers_the_flag_and_names_what_is_wrong(tmp_path):
    px4 = _fake_sitl(tmp_path, "px4")
    assert resolve_sitl_dir("px4", environ={"SWARMSEEK_PX4_SITL": str(px4)}) == px4.resolve()
    assert resolve_sitl_dir("px4", px4, environ={"SWARMSEEK_PX4_SITL": "/nowhere"}) == px4.resolve()
    with pytest.raises(SitlSetupError, match="SWARMSEEK_ARDUPILOT_SITL is not set"):
        resolve_sitl_dir("ardupilot", environ={})
    with pytest.raises(SitlSetupError, match=r"SWARMSEEK_ARDUPILOT_SITL=.*missing bin/arducopter, copter.parm"):
        resolve_sitl_dir("ardupilot", environ={"SWARMSEEK_ARDUPILOT_SITL": str(px4)})
    (px4 / "bin" / "px4").chmod(0o644)
    with pytest.raises(SitlSetupError, match="is not executable"):
        resolve_sitl_dir("px4", environ={"SWARMSEEK_PX4_SITL": str(px4)})


def test_homes_are_spread_east_by_the_spacing():
    homes = spread_homes((47.397742, 8.545594, 489.4), 4, 4.0)
    enu = np.array([geodetic_to_enu(*h, homes[0]) for h in homes])
    np.testing.assert_allclose(enu[:, 0], [0.0, 4.0, 8.0, 12.0], atol=0.01)  # the 1e-7 degree rounding
    np.testing.assert_allclose(enu[:, 1:], 0.0, atol=0.02)


def test_px4_specs_ports_sysids_params_and_links(tmp_path):
    sitl = _fake_sitl(tmp_path, "px4")
    cfg = SitlFleetConfig(flavour="px4", n=3, sitl_dir=sitl, first_instance=2, port_offset=1000, speedup=3.0,
                          params={"COM_OF_LOSS_T": 2})
    specs = instance_specs(cfg, sitl, tmp_path / "run")
    assert [s.sysid for s in specs] == [3, 4, 5]
    assert [s.connection for s in specs] == [f"udpin:127.0.0.1:{15540 + i}" for i in (2, 3, 4)]
    assert [s.sensor_connection for s in specs] == [f"udpin:127.0.0.1:{15030 + i}" for i in (2, 3, 4)]
    assert {s.ready_connection for s in specs} == {"udpin:127.0.0.1:15550"}
    env = specs[1].env
    assert env["PX4_PORT_OFFSET"] == "1000" and env["PX4_SIM_SPEED_FACTOR"] == "3"
    assert env["PX4_PARAM_NAV_DLL_ACT"] == "3" and env["PX4_PARAM_SDLOG_MODE"] == "-1"
    assert env["PX4_PARAM_COM_OF_LOSS_T"] == "2"
    assert specs[1].argv[1:4] == ["-i", "3", "-d"]
    link = tmp_path / "run" / "px4-bin" / "px4-param"
    assert link.is_symlink() and os.readlink(link) == "px4"
    assert any("-s" in c and "ATTITUDE" in c for c in specs[0].setup_commands)


def test_ardupilot_specs_ports_and_parameter_file(tmp_path):
    sitl = _fake_sitl(tmp_path, "ardupilot")
    cfg = SitlFleetConfig(flavour="ardupilot", n=2, sitl_dir=sitl, first_instance=5, port_offset=100)
    specs = instance_specs(cfg, sitl, tmp_path / "run")
    assert [s.sysid for s in specs] == [6, 7]
    assert [s.connection for s in specs] == ["tcp:127.0.0.1:5910", "tcp:127.0.0.1:5920"]
    assert [s.sensor_connection for s in specs] == ["tcp:127.0.0.1:5912", "tcp:127.0.0.1:5922"]
    assert specs[0].ready_connection == "tcp:127.0.0.1:5913"
    assert "--sysid" in specs[0].argv and specs[0].argv[specs[0].argv.index("--sysid") + 1] == "6"
    parm = (tmp_path / "run" / "swarmseek.parm").read_text()
    assert "FS_GCS_ENABLE 5" in parm and "LOG_BACKEND_TYPE 0" in parm


@pytest.mark.parametrize("speedup, params, timeout_s", [(1.0, {}, 10.0), (3.0, {}, 30.0), (40.0, {}, 120.0),
                                                     (3.0, {"FS_GCS_TIMEOUT": 120.0}, 120.0)])
def test_ardupilot_gcs_failsafe_timeout_scaled_by_the_speedup(speedup, params, timeout_s):
    """FS_GCS_TIMEOUT is simulated time, the ground station's heartbeat wall time: 10 s (PX4's
    COM_DL_LOSS_T) times the speed-up (capped at ArduCopter's maximum 120 s), unless given."""
    cfg = SitlFleetConfig(flavour="ardupilot", n=1, speedup=speedup, params=params)
    assert cfg.all_params().get("FS_GCS_TIMEOUT") == timeout_s
    assert cfg.all_params()["FS_GCS_ENABLE"] == 5
    assert "FS_GCS_TIMEOUT" not in SitlFleetConfig(flavour="px4", n=1, speedup=speedup).all_params()


@pytest.mark.parametrize("kwargs, message", [
    ({"flavour": "betaflight", "n": 4}, "unknown SITL flavour"),
    ({"flavour": "px4", "n": 0}, "at least 1 vehicle"),
    ({"flavour": "px4", "n": 4, "first_instance": 7}, "must stay below 10"),
    ({"flavour": "ardupilot", "n": 4, "speedup": 0.0}, "must be > 0"),
])
def test_bad_configuration_is_a_clear_error(kwargs, message):
    with pytest.raises(SitlSetupError, match=message):
        SitlFleetConfig(**kwargs)


def test_free_layouts_keep_px4_below_ten_instances(monkeypatch, tmp_path):
    import mission.sim.sitl_launch as launch

    busy = {0, 1, 2, 5}  # held by other fleets: only 6..9 leave room for 4 in a row
    monkeypatch.setattr(launch, "px4_instance_free", lambda i: i not in busy)
    for _ in range(5):  # no lease: the same block each time
        first, offset = pick_layout("px4", 4, lease_dir=tmp_path, lease_s=0.0)
        assert first == 6 and 1000 <= offset < 45000
    busy.add(8)
    with pytest.raises(SitlSetupError, match="no free instance numbers"):
        pick_layout("px4", 4, tries=50, lease_dir=tmp_path)


def test_px4_picks_before_any_start_get_disjoint_instances(monkeypatch, tmp_path):
    """Two fleets picked at once (nothing started, so no PX4 lock file yet) must not share an
    instance number: the first pick's numbers are leased."""
    import mission.sim.sitl_launch as launch

    monkeypatch.setattr(launch, "px4_instance_free", lambda i: True)
    first_a, _ = pick_layout("px4", 4, lease_dir=tmp_path)
    first_b, _ = pick_layout("px4", 4, lease_dir=tmp_path)
    assert (first_a, first_b) == (0, 4)
    with pytest.raises(SitlSetupError, match="no free instance numbers"):
        pick_layout("px4", 3, tries=20, lease_dir=tmp_path)  # 8 and 9 left: not 3 in a row
    (tmp_path / "instances.json").write_text("{cut sh")  # a file cut short by a killed writer
    assert pick_layout("px4", 4, lease_dir=tmp_path)[0] == 0
    with pytest.raises(SitlSetupError, match="at most 10"):
        pick_layout("px4", 11)


def test_plan_for_a_sped_up_fleet_loads_and_is_scaled(tmp_path):
    vehicles = [SimpleNamespace(sysid=i + 1, connection=f"udpin:127.0.0.1:{20000 + i}") for i in range(4)]
    origin = (47.397742, 8.545594, 489.4)
    plan = load_plan(write_plan(tmp_path / "p1.toml", vehicles, origin, flavour="px4"))
    fast = load_plan(write_plan(tmp_path / "p3.toml", vehicles, origin, flavour="px4", speedup=3.0,
                                overrides={"seeking": {"start_enu_m": [1.0, 2.0, 12.0]}}))
    assert [v.sysid for v in fast.vehicles] == [1, 2, 3, 4] and fast.origin == origin
    assert fast.max_speed_m_s == pytest.approx(3 * plan.max_speed_m_s)
    assert fast.seeking.rate_hz == pytest.approx(3 * plan.seeking.rate_hz)
    assert fast.stagger_s == pytest.approx(plan.stagger_s / 3)
    assert fast.seeking.reading_window_s == pytest.approx(plan.seeking.reading_window_s / 3)
    assert tuple(fast.seeking.start_enu_m) == (1.0, 2.0, 12.0)
    with pytest.raises(ValueError, match="radius_m"):
        write_plan(tmp_path / "bad.toml", vehicles, origin, flavour="px4", overrides={"formation": {"radius_m": -1.0}})
    assert not (tmp_path / "bad.toml").exists()


@pytest.mark.parametrize("seeker, gamma_m, sampling", [("model", 20.0, "moving"), ("newton", 20.0, "moving"),
                                                       ("plume", 20.0, "stop_and_go"), ("gradient", 1.0, "stop_and_go")])
def test_swarmseek_sitl_writes_its_seeker_into_the_plan(tmp_path, seeker, gamma_m, sampling):
    import argparse

    from mission.cli import cmd_sitl
    from mission.sim.sitl_plan import seeker_settings

    parser = argparse.ArgumentParser()
    cmd_sitl.configure(parser)
    assert parser.parse_args(["--flavour", "px4"]).seeker == "model"  # the default, measured on real firmware
    args = parser.parse_args(["--flavour", "px4", "--seeker", seeker])
    vehicles = [SimpleNamespace(sysid=i + 1, connection=f"udpin:127.0.0.1:{20000 + i}") for i in range(4)]
    plan = load_plan(write_plan(tmp_path / "p.toml", vehicles, (47.397742, 8.545594, 489.4), flavour="px4",
                                overrides={"seeking": seeker_settings(args.seeker)}))
    assert (plan.seeking.seeker, plan.seeking.gamma_m, plan.seeking.sampling) == (seeker, gamma_m, sampling)
    with pytest.raises(SystemExit):
        parser.parse_args(["--flavour", "px4", "--seeker", "bogus"])
