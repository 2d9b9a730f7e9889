"""What ``benchmarks/bench_sitl.py`` and ``fly_sitl_mission`` would start, without a SITL: the
sensors' command lines (the field and its flags) and the plan (a plume's start downwind)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mission.core.plan import load_plan
from mission.sim import sitl_mission
from mission.sim.sitl_mission import fly_sitl_mission, sensor_argv
from mission.sim.sitl_plan import write_plan
from sitl_mock.virtual_sensor import configure

_ORIGIN = (47.397742, 8.545594, 489.4)
_VEHICLES = [SimpleNamespace(sysid=i + 1, connection=f"udpin:127.0.0.1:{14540 + i}",
                             sensor_connection=f"udpin:127.0.0.1:{14030 + i}", pid=0) for i in range(4)]


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[3] / "benchmarks"))
    import bench_sitl
    return bench_sitl


def _sensor_args(argv: list[str]) -> argparse.Namespace:
    """``argv`` (after ``python -m mission sensor``) parsed by the sensor's own parser."""
    assert argv[:4] == [sys.executable, "-m", "mission", "sensor"]
    parser = argparse.ArgumentParser()
    configure(parser)
    return parser.parse_args(argv[4:])


class _Started(Exception):
    pass


def _first_sensor_argv(monkeypatch, tmp_path, **kwargs) -> list[str]:
    """The argv of the first process ``fly_sitl_mission`` starts (it is stopped right there)."""
    seen = []

    def popen(argv, **_):
        seen.append(argv)
        raise _Started

    monkeypatch.setattr(sitl_mission.subprocess, "Popen", popen)
    fleet = SimpleNamespace(vehicles=_VEHICLES, origin=_ORIGIN, config=SimpleNamespace(speedup=1.0))
    with pytest.raises(_Started):
        fly_sitl_mission(fleet, tmp_path / "plan.toml", tmp_path / "logs", (6.0, 12.0, 13.0), **kwargs)
    return seen[0]


def test_default_sensor_is_sigma2_as_before(monkeypatch, tmp_path):
    argv = _first_sensor_argv(monkeypatch, tmp_path)
    assert argv == [sys.executable, "-m", "mission", "sensor", "--connect", "udpin:127.0.0.1:14030",
                    "--sysid", "1", "--fleet", "sitl", "--field", "sigma2", "--source=6,12,13",
                    "--origin=47.3977420,8.5455940,489.4", "--noise", "0.005", "--seed", "1",
                    "--rate", "10", "--zenoh-connect", "tcp/127.0.0.1:7447", "--quiet"]
    parsed = _sensor_args(argv)
    assert parsed.field == "sigma2" and parsed.wind_from is None


def test_sensors_get_the_field_and_its_flags(monkeypatch, tmp_path):
    argv = _first_sensor_argv(monkeypatch, tmp_path, field="intermittent", noise=0.01,
                              field_args=("--wind-from", "270", "--wind-speed", "3"))
    i = argv.index("--field")
    assert argv[i:i + 6] == ["--field", "intermittent", "--wind-from", "270", "--wind-speed", "3"]
    parsed = _sensor_args(argv)
    assert (parsed.field, parsed.wind_from, parsed.wind_speed, parsed.noise) == ("intermittent", 270.0, 3.0, 0.01)


def test_field_args_must_be_strings():
    with pytest.raises(TypeError, match="sequence of strings"):
        sensor_argv(_VEHICLES[0], _ORIGIN, (0, 0, 0), fleet="f", zenoh="tcp/127.0.0.1:1", noise=0.0,
                    rate_hz=10.0, field="plume", field_args="--wind-from 270")
    with pytest.raises(TypeError, match="sequence of strings"):
        sensor_argv(_VEHICLES[0], _ORIGIN, (0, 0, 0), fleet="f", zenoh="tcp/127.0.0.1:1", noise=0.0,
                    rate_hz=10.0, field="plume", field_args=("--wind-from", 270))


def _plan(tmp_path, overrides):
    return load_plan(write_plan(tmp_path / "plan.toml", _VEHICLES, _ORIGIN, flavour="px4", overrides=overrides))


def test_intermittent_plume_mission_starts_downwind_with_ste(bench, tmp_path):
    args = bench.parse_args(["--seeker", "ste", "--sampling", "moving", "--field", "intermittent"])
    setting = bench.mission_settings(args)
    assert setting["field"] == "intermittent" and setting["field_args"] == ["--wind-from", "270"]
    assert setting["noise"] == 0.01
    plan = _plan(tmp_path, setting["overrides"])
    s = plan.seeking
    assert (s.seeker, s.sampling, s.plume_mode, s.gamma_m) == ("ste", "moving", "intermittent", 20.0)
    assert s.sensor_noise_std == setting["noise"] and s.sensor_detection_floor == 0.0
    assert s.wind_from_deg is None  # the wind is not given to the plan unless asked
    # wind from 270 (west) blows toward east: the start is 25 m east of the release, 3 m lower
    offset = np.subtract(s.start_enu_m, setting["source"])
    np.testing.assert_allclose(offset, [25.0, 0.0, -3.0], atol=1e-9)
    # the whole formation at the start is inside the plan's fence and altitude band
    poly = np.asarray(plan.geofence.polygon_en_m)
    r = plan.formation.radius_m
    assert poly[:, 0].min() < s.start_enu_m[0] - r and s.start_enu_m[0] + r < poly[:, 0].max()
    assert poly[:, 1].min() < s.start_enu_m[1] - r and s.start_enu_m[1] + r < poly[:, 1].max()
    assert plan.geofence.min_alt_m < s.start_enu_m[2] - r and s.start_enu_m[2] + r < plan.geofence.max_alt_m


def test_plume_defaults_and_the_seekers_wind(bench, tmp_path):
    args = bench.parse_args(["--field", "plume", "--wind-from", "0", "--seek-wind-from", "10"])
    setting = bench.mission_settings(args)
    plan = _plan(tmp_path, setting["overrides"])
    assert (plan.seeking.seeker, plan.seeking.sampling, plan.seeking.plume_mode) == ("ste", "moving", "steady")
    assert plan.seeking.wind_from_deg == 10.0
    # wind from the north: the start is south of the release
    np.testing.assert_allclose(np.subtract(plan.seeking.start_enu_m, setting["source"]), [0.0, -25.0, -3.0],
                               atol=1e-9)


def test_default_bench_mission_unchanged(bench, tmp_path):
    setting = bench.mission_settings(bench.parse_args([]))
    assert setting["field"] == "sigma2" and setting["field_args"] == [] and setting["noise"] == 0.005
    assert setting["overrides"] == {"seeking": dict(bench.SEEKING, seeker="gradient", sampling="stop_and_go",
                                                    gamma_m=1.0)}
    assert _plan(tmp_path, setting["overrides"]).seeking.start_enu_m == (0.0, 20.0, 15.0)


def test_fly_timeout_longer_on_a_plume(bench):
    assert bench.parse_args([]).fly_timeout == 900.0
    assert bench.parse_args(["--field", "intermittent"]).fly_timeout == 1800.0
    assert bench.parse_args(["--field", "plume", "--fly-timeout", "60"]).fly_timeout == 60.0


@pytest.mark.parametrize("argv, message", [
    (["--wind-from", "90"], "--wind-from/--wind-speed need --field plume or intermittent"),
    (["--field", "intermittent", "--seeker", "model", "--seek-wind-from", "270"],
     "--seek-wind-from needs --seeker plume or ste, not model"),
    (["--fly-timeout", "0"], "--fly-timeout must be > 0, got 0"),
])
def test_inconsistent_options_exit_2(bench, capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        bench.parse_args(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
