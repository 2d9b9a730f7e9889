"""One bad plan value is reported once, at its key: the checks that span sections skip what an
earlier problem already explains (a bad vehicle entry once also said "a formation needs at
least 4 vehicles, got 3")."""
from __future__ import annotations

from pathlib import Path

import pytest

from mission.cli import main as cli_main
from mission.core.plan import parse_plan
from mission.core.plan_types import PlanError

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


def _problems(doc: dict) -> list[tuple[str, str]]:
    with pytest.raises(PlanError, match="invalid plan") as info:
        parse_plan(doc)
    return info.value.problems


@pytest.mark.parametrize("key, value, why", [("sysid", "two", "expected an integer"),
                                             ("connection", "carrier-pigeon:42", "carrier-pigeon"),
                                             ("sysid", 999, "must be <= 254")])
def test_one_bad_vehicle_entry_is_the_only_problem(doc, key, value, why):
    assert len(doc["vehicles"]) == 4
    doc["vehicles"][1][key] = value
    problems = _problems(doc)
    assert [k for k, _ in problems] == [f"vehicles[1].{key}"]
    assert why in problems[0][1]


def test_a_bad_vehicle_entry_in_a_too_small_fleet_reports_both_real_problems(doc):
    doc["vehicles"] = doc["vehicles"][:3]
    doc["vehicles"][0]["sysid"] = "one"
    problems = dict(_problems(doc))
    assert set(problems) == {"vehicles[0].sysid", "vehicles"}
    assert problems["vehicles"] == "a formation needs at least 4 vehicles, got 3"  # 3 entries written


def test_an_invalid_separation_is_not_compared_with_the_radius_as_its_default(doc):
    doc["formation"]["radius_m"] = 1.0  # smaller than the default min_separation_m 1.5
    doc["min_separation_m"] = "wide"
    assert [k for k, _ in _problems(doc)] == ["min_separation_m"]


def test_an_invalid_takeoff_altitude_is_not_checked_against_the_fence_as_its_default(doc):
    doc["geofence"]["min_alt_m"] = 12.0  # the default take-off altitude 10 m is below the band
    doc["takeoff_alt_m"] = 0.5
    problems = _problems(doc)
    assert [k for k, _ in problems] == ["takeoff_alt_m"] and "must be >= 1.0" in problems[0][1]


def test_dry_run_prints_the_root_cause_once(doc, tmp_path, capsys):
    text = SAMPLE.read_text().replace("sysid = 2", 'sysid = "two"', 1)
    assert 'sysid = "two"' in text
    plan = tmp_path / "bad.toml"
    plan.write_text(text)
    assert cli_main(["dry-run", "--plan", str(plan)]) == 2
    err = capsys.readouterr().err
    assert "vehicles[1].sysid: expected an integer" in err
    assert len(err.strip().splitlines()) == 1, err  # one problem, one line
    assert "a formation needs at least" not in err
