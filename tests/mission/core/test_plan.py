"""Mission plan: the sample plan loads, every invalid key is reported with its path, all at once."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from mission.core.plan_types import PLAN_VERSION, Plan, PlanError
from mission.core.plan import load_plan, parse_plan

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


def _keys(exc: PlanError) -> list[str]:
    return [k for k, _ in exc.problems]


def test_sample_plan_loads():
    plan = load_plan(SAMPLE)
    assert isinstance(plan, Plan)
    assert plan.version == PLAN_VERSION
    assert len(plan.vehicles) == 4
    assert [v.sysid for v in plan.vehicles] == [1, 2, 3, 4]
    assert plan.formation.type == "cvt"
    assert plan.geofence.min_alt_m < plan.geofence.max_alt_m
    assert np.allclose(plan.seeking.start_point(), [0.0, 20.0, 15.0])


@pytest.mark.parametrize("path, value, key, why", [
    (("version",), 2, "version", "unsupported version"),
    (("fleet",), "a/b", "fleet", "must not contain"),
    (("origin", "lat_deg"), 95.0, "origin.lat_deg", "must be <= 90"),
    (("origin", "lon_deg"), "east", "origin.lon_deg", "expected a number"),
    (("formation", "type"), "ring", "formation.type", "must be one of cvt, symmetric"),
    (("formation", "radius_m"), -1.0, "formation.radius_m", "must be > 0"),
    (("seeking", "eps"), 0.0, "seeking.eps", "must be > 0"),
    (("seeking", "estimator"), "magic", "seeking.estimator", "must be one of"),
    (("seeking", "max_iterations"), 2.5, "seeking.max_iterations", "expected an integer"),
    (("seeking", "convergence_window"), 3, "seeking.convergence_window", "must be >= 8"),
    (("seeking", "region_hold"), 1, "seeking.region_hold", "must be 0 (the region rule off) or at least 2"),
    (("seeking", "region_hold"), -2, "seeking.region_hold", "must be >= 0"),
    (("seeking", "region_hold"), 2.5, "seeking.region_hold", "expected an integer"),
    (("seeking", "start_enu_m"), [1.0, 2.0], "seeking.start_enu_m", "expected 3 finite numbers"),
    (("geofence", "max_alt_m"), 1.0, "geofence.max_alt_m", "must be greater than min_alt_m"),
    (("geofence", "polygon_enu_m"), [[0, 0], [1, 1]], "geofence.polygon_enu_m", "at least 3"),
    (("geofence", "polygon_enu_m"), [[0, 0], [1, 1], [2, 2]], "geofence.polygon_enu_m", "zero area"),
    (("zenoh", "mode"), "mesh", "zenoh.mode", "must be one of"),
    (("zenoh", "listen"), ["127.0.0.1:7447"], "zenoh.listen", "tcp/HOST:PORT"),
    (("max_speed_m_s",), float("nan"), "max_speed_m_s", "must be finite"),
    (("return",), "crash", "return", "must be one of land, rtl"),
    (("stagger_s",), True, "stagger_s", "expected a number"),
])
def test_each_invalid_value_is_reported_with_its_key(doc, path, value, key, why):
    target = doc
    for p in path[:-1]:
        target = target[p]
    target[path[-1]] = value
    with pytest.raises(PlanError, match="invalid plan") as info:
        parse_plan(doc)
    assert key in _keys(info.value)
    assert any(why in w for k, w in info.value.problems if k == key), info.value.problems


def test_all_problems_reported_at_once(doc):
    doc["version"] = 7
    doc["origin"]["lat_deg"] = 123.0
    doc["vehicles"][1]["sysid"] = 1
    doc["vehicles"][2]["connection"] = "carrier-pigeon:42"
    doc["formation"]["radius_m"] = 0
    doc["seeking"]["gamma_m"] = -1
    doc["bogus"] = 1
    doc["seeking"]["epsilon"] = 1.0
    with pytest.raises(PlanError) as info:
        parse_plan(doc, source="test.toml")
    keys = _keys(info.value)
    for expected in ("version", "origin.lat_deg", "vehicles[1].sysid", "vehicles[2].connection",
                     "formation.radius_m", "seeking.gamma_m", "bogus", "seeking.epsilon"):
        assert expected in keys, (expected, keys)
    text = str(info.value)
    assert "test.toml" in text and f"({len(keys)} problems)" in text


@pytest.mark.parametrize("n, kind, ok", [(3, "cvt", False), (4, "cvt", True), (5, "symmetric", False),
                                         (6, "symmetric", True)])
def test_vehicle_count_and_formation(doc, n, kind, ok):
    template = doc["vehicles"][0]
    doc["vehicles"] = [dict(template, id=f"v{i}", sysid=i + 1, connection=f"tcp:127.0.0.1:{5760 + 10 * i}")
                       for i in range(n)]
    doc["formation"]["type"] = kind
    if ok:
        assert len(parse_plan(doc).vehicles) == n
    else:
        with pytest.raises(PlanError, match="vehicles|formation.type"):
            parse_plan(doc)


def test_duplicate_ids_and_sysids(doc):
    doc["vehicles"][3]["id"] = doc["vehicles"][0]["id"]
    doc["vehicles"][2]["sysid"] = doc["vehicles"][0]["sysid"]
    with pytest.raises(PlanError) as info:
        parse_plan(doc)
    assert {"vehicles[3].id", "vehicles[2].sysid"} <= set(_keys(info.value))
    assert "also vehicles[0]" in str(info.value)


def test_missing_required_sections(doc):
    for key in ("origin", "vehicles", "fleet", "version"):
        doc.pop(key)
    with pytest.raises(PlanError) as info:
        parse_plan(doc)
    assert {"origin", "vehicles", "fleet", "version"} <= set(_keys(info.value))


def test_latlon_polygon_is_converted_to_the_mission_frame(doc):
    lat0, lon0 = doc["origin"]["lat_deg"], doc["origin"]["lon_deg"]
    d = 0.0005
    del doc["geofence"]["polygon_enu_m"]
    doc["geofence"]["polygon_latlon_deg"] = [[lat0 - d, lon0 - d], [lat0 - d, lon0 + d],
                                             [lat0 + d, lon0 + d], [lat0 + d, lon0 - d]]
    plan = parse_plan(doc)
    poly = np.asarray(plan.geofence.polygon_en_m)
    assert poly.shape == (4, 2)
    # 0.0005 deg of latitude is ~55.5 m; of longitude at -35 deg ~45.6 m
    assert np.allclose(np.abs(poly[:, 1]), 55.5, atol=0.5)
    assert np.allclose(np.abs(poly[:, 0]), 45.6, atol=0.5)


def test_start_altitude_must_leave_room_for_the_formation(doc):
    doc["seeking"]["start_enu_m"] = [0.0, 0.0, 4.0]
    with pytest.raises(PlanError, match="seeking.start_enu_m"):
        parse_plan(doc)


def test_tls_files_must_exist(doc, tmp_path):
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    doc["zenoh"]["tls"] = {"root_ca_certificate": "ca.pem", "connect_certificate": "missing.pem"}
    with pytest.raises(PlanError) as info:
        parse_plan(doc, base_dir=tmp_path)
    assert _keys(info.value) == ["zenoh.tls.connect_certificate"]
    doc["zenoh"]["tls"].pop("connect_certificate")
    plan = parse_plan(copy.deepcopy(doc), base_dir=tmp_path)
    assert plan.zenoh.tls["root_ca_certificate"] == str(ca)


@pytest.mark.parametrize("content, why", [("version = 1\n[origin\n", "not valid TOML"),
                                          (b"\xff\xfe", "not UTF-8")])
def test_unreadable_files(tmp_path, content, why):
    p = tmp_path / "plan.toml"
    (p.write_bytes if isinstance(content, bytes) else p.write_text)(content)
    with pytest.raises(PlanError, match=why):
        load_plan(p)
    with pytest.raises(PlanError, match="cannot read"):
        load_plan(tmp_path / "nope.toml")


def test_zenoh_config_has_explicit_endpoints_and_no_multicast(doc):
    plan = parse_plan(doc)
    conf = plan.zenoh.to_config()
    assert '"tcp/127.0.0.1:7447"' in conf.get_json("listen/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"


@pytest.mark.parametrize("faults, expected", [
    ({}, ("retire", 20)),
    ({"faulty_sensor": "keep"}, ("keep", 20)),
    ({"faulty_sensor": "retire", "retire_after": 5}, ("retire", 5)),
    ({"retire_after": 1, "retire_min_noise_ratio": 2}, ("retire", 1, 2.0)),
])
def test_faulty_sensor_keys_and_defaults(doc, faults, expected):
    doc["faults"] = faults
    f = parse_plan(doc).faults
    assert (f.faulty_sensor, f.retire_after, f.retire_min_noise_ratio) == expected + (3.0,) * (3 - len(expected))


@pytest.mark.parametrize("key, value, why", [
    ("faulty_sensor", "land", "must be one of retire, keep"),
    ("faulty_sensor", "", "expected a non-empty string"),
    ("faulty_sensor", True, "expected a non-empty string"),
    ("retire_after", 0, "must be >= 1"),
    ("retire_after", -3, "must be >= 1"),
    ("retire_after", 2.5, "expected an integer"),
    ("retire_after", "20", "expected an integer"),
    ("retire_after", True, "expected an integer"),
    ("retire_after", 10**6, "must be <= 10000"),
    ("retire_min_noise_ratio", 0.5, "must be >= 1.0"),
    ("retire_min_noise_ratio", "3x", "expected a number"),
    ("retire_min_noise_ratio", float("inf"), "must be finite"),
])
def test_bad_faulty_sensor_keys_are_reported_with_their_key(doc, key, value, why):
    doc["faults"] = {key: value}
    with pytest.raises(PlanError, match=f"faults.{key}") as info:
        parse_plan(doc)
    assert _keys(info.value) == [f"faults.{key}"]
    assert why in info.value.problems[0][1], info.value.problems


@pytest.mark.parametrize("given, expected", [(None, 3), (0, 0), (5, 5)])
def test_region_hold_defaults_to_three_and_zero_turns_the_rule_off(doc, given, expected):
    if given is not None:
        doc["seeking"]["region_hold"] = given
    assert parse_plan(doc).seeking.region_hold == expected
