"""The estimated source in WGS-84 (lat, lon, alt AMSL) wherever its mission-frame ENU form appears."""
from __future__ import annotations

import json

import numpy as np
import pymap3d
import pytest

from mission.cli import main as cli_main
from mission.flight.result import MissionResult, geodetic_point
from mission.telemetry.display import format_geodetic, format_summary, format_table
from mission.telemetry.mission_log import to_jsonable


@pytest.mark.parametrize("origin", [(45.1885, 5.7245, 212.0), (-35.363261, 149.165230, 584.0),
                                    (64.8, -147.7, 130.0), (0.0, 179.9999, -20.0)])
@pytest.mark.parametrize("enu", [(0.0, 0.0, 0.0), (5.62, -9.40, 12.28), (-250.0, 400.0, 35.0)])
def test_geodetic_point_matches_pymap3d(origin, enu):
    lat, lon, alt = pymap3d.enu2geodetic(*enu, *origin)
    geo = geodetic_point(origin, enu)
    assert geo["lat_deg"] == pytest.approx(float(lat), abs=1e-8)
    assert geo["lon_deg"] == pytest.approx(float(lon), abs=1e-8)
    assert geo["alt_m"] == pytest.approx(float(alt), abs=1e-3)


def test_a_known_offset_gives_the_expected_latitude_and_longitude():
    """10 m north and 10 m east at the equator: 10 / 110574 deg of latitude, 10 / 111320 of longitude."""
    geo = geodetic_point((0.0, 0.0, 100.0), (10.0, 10.0, 5.0))
    assert geo["lat_deg"] == pytest.approx(10.0 / 110574.0, rel=1e-3)
    assert geo["lon_deg"] == pytest.approx(10.0 / 111319.5, rel=1e-3)
    assert geo["alt_m"] == pytest.approx(105.0, abs=1e-3)


def test_no_estimate_no_geodetic():
    assert geodetic_point((45.0, 5.0, 200.0), None) is None
    assert geodetic_point(None, (1.0, 2.0, 3.0)) is None


def test_log_serialiser_keeps_degrees_to_a_millimetre():
    """Other floats keep 6 decimals; angles (``*_deg``) keep 9 (1e-6 deg would be 0.11 m)."""
    out = to_jsonable({"lat_deg": 45.123456789123, "alt_m": 1.123456789})
    assert out == {"lat_deg": 45.123456789, "alt_m": 1.123457}


def test_summary_lines_and_table_show_latitude_longitude_altitude():
    geo = {"lat_deg": -35.36300641, "lon_deg": 149.16533944, "alt_m": 597.679}
    summary = MissionResult(outcome="converged", estimate_enu=[9.95, 28.25, 13.68], estimate_geodetic=geo,
                            true_source_enu=[10.0, 30.0, 14.0],
                            true_source_geodetic={"lat_deg": -35.3629926, "lon_deg": 149.1653400, "alt_m": 598.0},
                            error_m=1.78).to_json()
    text = "\n".join(format_summary(summary))
    assert "lat -35.3630064, lon 149.1653394, alt 597.7 m AMSL" in text
    assert "lat -35.3629926, lon 149.1653400, alt 598.0 m AMSL" in text
    table = "\n".join(format_table({"estimate_enu": [9.95, 28.25, 13.68], "estimate_geodetic": geo}))
    assert format_geodetic(geo) in table
    assert "AMSL" not in "\n".join(format_table({"estimate_enu": None, "estimate_geodetic": None}))


@pytest.fixture(scope="module")
def embedded_run(tmp_path_factory):
    """One lock-step ``swarmseek run --json`` (N = 6), its JSON summary and its mission log."""
    import contextlib
    import io

    log_dir = tmp_path_factory.mktemp("geo_run")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cli_main(["run", "--n", "6", "--seed", "2", "--json", "--no-tlog", "--log-dir", str(log_dir)])
    records = [json.loads(line) for line in (log_dir / "mission.jsonl").read_text().splitlines()]
    return rc, json.loads(buf.getvalue()), records


def test_json_summary_carries_the_geodetic_estimate_and_truth(embedded_run):
    rc, summary, records = embedded_run
    assert rc == 0 and summary["outcome"] == "converged"
    origin = next(r for r in records if r["type"] == "plan")["plan"]["origin"]
    for enu_key, geo_key in (("estimate_enu", "estimate_geodetic"), ("true_source_enu", "true_source_geodetic")):
        lat, lon, alt = pymap3d.enu2geodetic(*summary[enu_key], *origin)
        geo = summary[geo_key]
        assert (geo["lat_deg"], geo["lon_deg"]) == pytest.approx((float(lat), float(lon)), abs=1e-7)
        assert geo["alt_m"] == pytest.approx(float(alt), abs=1e-3)


def test_mission_log_records_carry_the_geodetic_estimate(embedded_run):
    _, summary, records = embedded_run
    origin = next(r for r in records if r["type"] == "plan")["plan"]["origin"]
    iterations = [r for r in records if r["type"] == "iteration"]
    with_estimate = [r for r in iterations if r["estimate_enu"] is not None]
    assert with_estimate and all(r["estimate_geodetic"] is not None for r in with_estimate)
    assert all(r["estimate_geodetic"] is None for r in iterations if r["estimate_enu"] is None)
    last = with_estimate[-1]
    lat, lon, _ = pymap3d.enu2geodetic(*last["estimate_enu"], *origin)
    assert (last["estimate_geodetic"]["lat_deg"], last["estimate_geodetic"]["lon_deg"]) == pytest.approx(
        (float(lat), float(lon)), abs=1e-7)
    logged = next(r for r in reversed(records) if r["type"] == "summary")
    assert logged["estimate_geodetic"] == summary["estimate_geodetic"]
    truth = next(r for r in records if r["type"] == "truth")
    assert truth["source_geodetic"] == summary["true_source_geodetic"]
    assert np.allclose(truth["source_enu"], summary["true_source_enu"])
