"""``swarmseek export LOG --kml OUT --geojson OUT``: the flown mission for Google Earth and QGIS.

The files are parsed back (lxml for KML, json for GeoJSON) and their coordinates compared with
the mission log's, converted with pymap3d: every vehicle's track, the fence, the start, the
estimate and its 95 % region.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from formation.geodesy import TangentFrame, enu_to_geodetic
from mission.cli import main as cli_main
from mission.core.plan import load_plan
from mission.telemetry.geo_export import REGION_VERTICES
from mission.telemetry.mission_log import read_mission_log, to_jsonable

ROOT = Path(__file__).resolve().parents[3]
KML_NS = {"k": "http://www.opengis.net/kml/2.2"}
#: written to 1e-8 deg and 1 mm: compared within a little more
DEG_TOL, ALT_TOL_M = 2e-8, 2e-3


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """A lock-step ``swarmseek run`` (seed 2): its mission log and its records."""
    log_dir = tmp_path_factory.mktemp("flown")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-m", "mission", "run", "--seed", "2", "--json", "--no-tlog",
                           "--log-dir", str(log_dir)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    log = log_dir / "mission.jsonl"
    return log, read_mission_log(log)


def _export(log: Path, tmp_path: Path) -> tuple[Path, Path]:
    kml, geojson = tmp_path / "mission.kml", tmp_path / "mission.geojson"
    assert cli_main(["export", str(log), "--kml", str(kml), "--geojson", str(geojson)]) == 0
    return kml, geojson


def _kml_placemarks(path: Path) -> dict[str, list[tuple[float, float, float]]]:
    """``{name: [(lon, lat, alt), ...]}`` of each Placemark of a KML file."""
    root = etree.parse(str(path)).getroot()
    out = {}
    for pm in root.iterfind(".//k:Placemark", KML_NS):
        text = pm.findtext(".//k:coordinates", namespaces=KML_NS)
        out[pm.findtext("k:name", namespaces=KML_NS)] = [tuple(float(v) for v in t.split(",")) for t in text.split()]
    return out


def _log_tracks(records) -> dict[str, np.ndarray]:
    """Each vehicle's positions (ENU) in the log's order of time, from status and iteration records."""
    rows: dict[str, list] = {}
    for r in records:
        if r["type"] == "status":
            for v in r["vehicles"]:
                if v.get("position_enu") is not None:
                    rows.setdefault(str(v["sysid"]), []).append((r["t_s"], v["position_enu"]))
        elif r["type"] == "iteration":
            for s, p in (r.get("positions_enu") or {}).items():
                rows.setdefault(str(s), []).append((r["t_s"], p))
    return {s: np.array([p for _, p in sorted(v, key=lambda x: x[0])]) for s, v in rows.items()}


def _lonlatalt(enu, origin) -> np.ndarray:
    lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), origin)
    return np.stack([lon, lat, alt], axis=-1)


def _close(got, expected) -> bool:
    got, expected = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
    return (got.shape == expected.shape and np.allclose(got[..., :2], expected[..., :2], atol=DEG_TOL, rtol=0)
            and (got.shape[-1] < 3 or np.allclose(got[..., 2], expected[..., 2], atol=ALT_TOL_M, rtol=0)))


def test_the_kml_round_trips_to_the_mission(flown, tmp_path):
    log, records = flown
    plan = next(r["plan"] for r in records if r["type"] == "plan")
    summary = next(r for r in records if r["type"] == "summary")
    origin = tuple(plan["origin"])
    marks = _kml_placemarks(_export(log, tmp_path)[0])
    tracks = _log_tracks(records)
    assert len(tracks) == 8
    for sysid, enu in tracks.items():
        name = next(n for n in marks if n.startswith(f"vehicle {sysid} "))
        assert _close(marks[name], _lonlatalt(enu, origin)), name
    geo = summary["estimate_geodetic"]  # the mission's own WGS-84 estimate
    assert _close(marks["estimate"], [(geo["lon_deg"], geo["lat_deg"], geo["alt_m"])])
    start = plan["seeking"]["start_enu_m"]
    assert _close(marks["start"], _lonlatalt([start], origin))
    fence = np.asarray(plan["geofence"]["polygon_en_m"])
    ring = np.array(marks["geofence"])
    assert np.allclose(ring[0], ring[-1])  # closed
    expected = _lonlatalt(np.column_stack([fence, np.zeros(len(fence))]), origin)[:, :2]
    assert all(any(np.allclose(v, e, atol=DEG_TOL, rtol=0) for v in ring[:-1, :2]) for e in expected)
    assert "true source (simulation)" in marks and "formation centre" in marks


def test_the_geojson_is_rfc7946_and_round_trips(flown, tmp_path):
    log, records = flown
    plan = next(r["plan"] for r in records if r["type"] == "plan")
    summary = next(r for r in records if r["type"] == "summary")
    origin = tuple(plan["origin"])
    doc = json.loads(_export(log, tmp_path)[1].read_text())
    assert doc["type"] == "FeatureCollection" and "crs" not in doc  # RFC 7946: WGS-84 lon/lat, no crs member
    feats = {f["properties"]["name"]: f for f in doc["features"]}
    for f in doc["features"]:
        geom = f["geometry"]
        rings = geom["coordinates"] if geom["type"] == "Polygon" else [
            geom["coordinates"] if geom["type"] == "LineString" else [geom["coordinates"]]]
        for ring in rings:
            pos = np.asarray(ring)
            assert pos.shape[1] == 2  # [lon, lat]: AMSL altitudes are no ellipsoidal heights
            assert np.all(np.abs(pos[:, 0]) <= 180) and np.all(np.abs(pos[:, 1]) <= 90)
            if geom["type"] == "Polygon":  # closed, counter-clockwise (right-hand rule)
                assert pos[0].tolist() == pos[-1].tolist()
                x, y = pos[:, 0], pos[:, 1]
                assert float(np.dot(x[:-1], y[1:]) - np.dot(y[:-1], x[1:])) > 0
    for sysid, enu in _log_tracks(records).items():
        f = next(f for n, f in feats.items() if n.startswith(f"vehicle {sysid} "))
        lla = _lonlatalt(enu, origin)
        assert _close(f["geometry"]["coordinates"], lla[:, :2]) and np.allclose(
            f["properties"]["alt_m_amsl"], lla[:, 2], atol=ALT_TOL_M)
    est = feats["estimate"]
    geo = summary["estimate_geodetic"]
    assert _close(est["geometry"]["coordinates"], [geo["lon_deg"], geo["lat_deg"]])  # lon first
    assert est["properties"]["region95_m"] == pytest.approx(summary["estimate_region95_m"])
    region = feats["estimate 95 % region"]
    frame = TangentFrame(origin)
    centre = np.asarray(summary["estimate_enu"])
    ring = region["geometry"]["coordinates"][0]
    assert len(ring) == REGION_VERTICES + 1
    alt = region["properties"]["alt_m_amsl"]
    dist = [np.hypot(*(np.array(frame.geodetic_to_enu_m(lat, lon, alt)[:2]) - centre[:2])) for lon, lat in ring]
    assert np.allclose(dist, summary["estimate_region95_m"], atol=2e-3)


def test_a_fence_from_a_kml_file_comes_back_as_drawn(tmp_path):
    """KML vertices -> mission frame (the plan) -> mission log -> GeoJSON: the file's own lat/lon."""
    plan = load_plan(ROOT / "mission" / "examples" / "fence_kml_plan.toml")
    log = tmp_path / "mission.jsonl"
    records = [{"t_s": 0.0, "type": "plan", "plan": to_jsonable(plan)},
               {"t_s": 1.0, "type": "status", "vehicles": [{"sysid": 1, "id": "a", "position_enu": [1.0, 2.0, 3.0]}]}]
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    doc = json.loads(_export(log, tmp_path)[1].read_text())
    fence = next(f for f in doc["features"] if f["properties"]["kind"] == "geofence")
    assert "fence.kml: KML Polygon 'Search area'" in fence["properties"]["source"]
    got = fence["geometry"]["coordinates"][0][:-1]
    drawn = [[lon, lat] for lat, lon in plan.geofence.source_latlon_deg]  # counter-clockwise already
    assert np.allclose(got, drawn, atol=DEG_TOL, rtol=0)
    assert doc["swarmseek"]["outcome"] == "no summary (interrupted?)"
    track = next(f for f in doc["features"] if f["properties"]["kind"] == "track")
    assert track["geometry"]["type"] == "Point"  # one sample: a point, not a one-vertex line


def _bad_log(tmp_path: Path, kind: str) -> Path:
    log = tmp_path / "mission.jsonl"
    if kind == "not a log":
        log.write_text("hello\n")
    elif kind == "no plan record":
        log.write_text(json.dumps({"t_s": 0.0, "type": "phase", "phase": "connect"}) + "\n")
    elif kind == "bad origin":
        log.write_text(json.dumps({"t_s": 0.0, "type": "plan", "plan": {"origin": [1, "x", 3]}}) + "\n")
    elif kind == "bad position":
        records = [{"t_s": 0.0, "type": "plan", "plan": {"origin": [45.0, 5.0, 200.0]}},
                   {"t_s": 1.0, "type": "status", "vehicles": [{"sysid": 1, "position_enu": [1.0, None, 3.0]}]}]
        log.write_text("".join(json.dumps(r) + "\n" for r in records))
    return log


@pytest.mark.parametrize("kind, args, why", [
    ("missing", ["--kml", "{tmp}/o.kml"], "no such mission log"),
    ("not a log", ["--kml", "{tmp}/o.kml"], "not a swarmseek mission log"),
    ("no plan record", ["--geojson", "{tmp}/o.geojson"], "no plan record"),
    ("bad origin", ["--geojson", "{tmp}/o.geojson"], "no usable origin"),
    ("bad position", ["--kml", "{tmp}/o.kml"], "vehicle 1 position is not east, north, up metres"),
    ("no plan record", [], "give --kml OUT and/or --geojson OUT"),
    ("no plan record", ["--kml", "{tmp}/nowhere/o.kml"], "no such directory"),
    ("no plan record", ["--geojson", "{tmp}"], "is a directory, not an output file"),
])
def test_bad_export_input_is_one_line_and_exit_2(tmp_path, capsys, kind, args, why):
    log = tmp_path / "absent.jsonl" if kind == "missing" else _bad_log(tmp_path, kind)
    argv = ["export", str(log)] + [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarmseek export: error: ") and why in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list(tmp_path.glob("o.*"))
