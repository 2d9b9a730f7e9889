"""Field selection: the plan's [field] section, the field flags of mock / sensor / run
(including --field-config), and the offline simulation on every field."""
from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import numpy as np
import pytest

import formation
from experiments.offline import simulate
from mission.cli import main as cli_main
from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from sitl_mock import cli as mock_cli
from sitl_mock.cli_args import field_from_args
from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_gaussian import SumField
from sitl_mock.fields_config import field_from_table, make_field

SAMPLE = Path(__file__).resolve().parents[2] / "mission" / "examples" / "sitl_plan.toml"
FIELD = {"type": "plume", "source_enu_m": [5.0, 20.0, 15.0], "wind_from_deg": 200.0, "stability": "B",
         "ground_reflection": False, "sensor_time_constant_s": 0.5, "sensor_detection_floor": 0.002}


def _doc(field: dict) -> dict:
    doc = tomllib.loads(SAMPLE.read_text())
    doc["field"] = field
    return doc


def test_plan_field_section_builds_the_same_field_as_sitl_mock():
    plan = parse_plan(_doc(dict(FIELD, extra_sources_enu_m=[[40.0, 0.0, 12.0]], strengths=[1.0, 0.5])))
    assert plan.field.type == "plume" and plan.field.source_enu_m == (5.0, 20.0, 15.0)
    field, sensor = field_from_table(plan.field.to_table())
    assert isinstance(field, SumField) and np.allclose(field.sources_enu(), [[5, 20, 15], [40, 0, 12]])
    assert field.parts[0].wind_from_deg == 200.0 and field.parts[0].stability == "B"
    assert not field.parts[0].ground_reflection
    assert sensor == {"time_constant_s": 0.5, "detection_floor": 0.002}
    assert parse_plan(tomllib.loads(SAMPLE.read_text())).field is None  # optional


@pytest.mark.parametrize("change, key, why", [
    ({"type": "smoke"}, "field.type", "must be one of"),
    ({"wind_speed_m_s": 0.0}, "field.wind_speed_m_s", "must be > 0"),
    ({"seed": 3}, "field.seed", "does not apply to the plume field"),
    ({"stability": "Z"}, "field.stability", "must be one of A, B"),
    ({"ground_reflection": "yes"}, "field.ground_reflection", "true or false"),
    ({"colour": "red"}, "field.colour", "unknown key"),
    ({"strengths": [1.0, 2.0]}, "field.strengths", "expected 1 positive numbers"),
    ({"extra_sources_enu_m": [[1.0, 2.0]]}, "field.extra_sources_enu_m[0]", "expected 3 finite numbers"),
    ({"sensor_time_constant_s": -1.0}, "field.sensor_time_constant_s", "must be >= 0"),
])
def test_plan_field_section_reports_each_bad_key(change, key, why):
    with pytest.raises(PlanError) as info:
        parse_plan(_doc(dict(FIELD, **change)))
    assert any(k == key and why in w for k, w in info.value.problems), info.value.problems


def _mock_args(argv):
    parser = argparse.ArgumentParser()
    mock_cli.configure(parser)
    return parser.parse_args(argv)


def test_field_config_file_with_flags_overriding(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(SAMPLE.read_text() + '\n[field]\ntype = "intermittent"\nsource_enu_m = [1.0, 2.0, 12.0]\n'
                    "wind_speed_m_s = 3.0\nseed = 9\nsensor_time_constant_s = 0.4\n")
    name, field, response = field_from_args(_mock_args(["--field-config", str(plan), "--wind-speed", "5"]), None)
    assert name == "intermittent" and isinstance(field, FilamentPlume) and field.seed == 9
    assert field.steady.wind_speed_m_s == 5.0 and np.allclose(field.source_enu(), [1.0, 2.0, 12.0])
    assert response == {"time_constant_s": 0.4}
    _, field, _ = field_from_args(_mock_args(["--field-config", str(plan), "--wind-from", "10"]), (0.0, 0.0, 8.0))
    assert field.steady.wind_from_deg == 10.0 and np.allclose(field.source_enu(), [0.0, 0.0, 8.0])
    with pytest.raises(ValueError, match="field 'plume' has no parameter seed"):  # the file's keys still count
        field_from_args(_mock_args(["--field-config", str(plan), "--field", "plume"]), None)
    _, field, response = field_from_args(_mock_args(["--extra-source", "10,0,0", "--sensor-tau", "1"]), None)
    assert isinstance(field, SumField) and response == {"time_constant_s": 1.0}  # default sigma1, two sources


@pytest.mark.parametrize("argv, why", [
    (["mock", "--field", "sigma2", "--wind-from", "90"], "--wind-from does not apply to the sigma2 field"),
    (["mock", "--field", "plume", "--field-seed", "3"], "--field-seed does not apply to the plume field"),
    (["mock", "--field-config", "/nonexistent/plan.toml"], "cannot read"),
    (["run", "--field", "sigma1", "--stability", "D"], "--stability does not apply"),
    (["run", "--field", "plume", "--source=0,0,-3"], "below the ground"),
    (["sensor", "--connect", "tcp:127.0.0.1:5762", "--origin", "45,5,200", "--zenoh-connect",
      "tcp/127.0.0.1:7447"], "give --field or --field-config"),
])
def test_bad_field_options_exit_2_with_a_message(argv, why, capsys, tmp_path):
    assert cli_main(argv + (["--log-dir", str(tmp_path)] if argv[0] == "run" else [])) == 2
    assert why in capsys.readouterr().err


def test_field_config_without_field_table_is_an_error(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(SAMPLE.read_text())
    assert cli_main(["mock", "--field-config", str(plan)]) == 2
    assert "has no [field] table" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["sigma1", "sigma2", "plume", "intermittent", "multi-plume"])
def test_offline_simulation_runs_on_every_field(name):
    off = formation.cvt_sphere(8, 2.0, seed=0)
    if name == "multi-plume":
        field = make_field("plume", (0.0, 0.0, 15.0), extra_sources=[(0.0, 40.0, 15.0)])
    elif name.startswith("sigma"):
        field = name  # by name
    else:
        field = make_field(name, (0.0, 0.0, 15.0), seed=1) if name == "intermittent" else make_field(name, (0, 0, 15))
    start = (8.0, 0.5, 15.0) if not name.startswith("sigma") else (3.0, 2.0, 1.0)
    eps = 1.0 if name.startswith("sigma") else 3.0
    kw = dict(eps=eps, gamma=0.5, iterations=60, trials=4, rotate=True, seed=2, noise_std=1e-3)
    res = simulate(off, field, start, **kw)
    d = res.distance_to_source_m()
    assert np.all(np.isfinite(res.readings)) and np.all(np.isfinite(res.centres))
    if name == "intermittent":  # patchy readings: many at the background (the ascent is lost in them)
        assert np.mean(res.readings < 0.01) > 0.2
    else:
        assert np.median(d[-1]) < np.median(d[0])  # it climbs toward the source
    again = simulate(off, field, start, **kw)
    assert np.array_equal(res.centres, again.centres)  # deterministic for a seed
