"""The geofence drawn in Google Earth / QGIS (KML) or QGroundControl (.plan): ``[geofence] file``.

The polygon is converted into the mission frame about the origin (the plan's, or the file's home)
and shown by ``dry-run``; a fence the safety envelope cannot hold exactly (circles, exclusion
zones, holes, several polygons, a self-intersection) and a malformed file are refused with one
reason and exit 2, before anything is contacted.
"""
from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from formation.geodesy import TangentFrame
from mission.cli import main as cli_main
from mission.cli.common import fence_problem
from mission.core.fence_file import (MAX_FENCE_FILE_BYTES, MAX_FENCE_VERTICES, FenceFileError, fence_in_mission_frame,
                                     read_fence_file)
from mission.core.plan import load_plan
from mission.core.plan_types import PlanError

EXAMPLES = Path(__file__).resolve().parents[3] / "mission" / "examples"
KML_PLAN, QGC_PLAN = EXAMPLES / "fence_kml_plan.toml", EXAMPLES / "fence_qgc_plan.toml"
CMAC = (-35.363261, 149.165230, 584.0)
#: the example fences as drawn (east, north) m about CMAC, before their vertices were rounded to 1e-7 deg
KML_EN_M = [(-60, -60), (60, -60), (75, 0), (60, 60), (-60, 60), (-70, 0)]
QGC_EN_M = [(-55, -65), (65, -55), (60, 65), (-65, 60)]


def _latlon(en_m, origin=CMAC):
    frame = TangentFrame(origin)
    return [frame.enu_to_geodetic(e, n, 0.0)[:2] for e, n in en_m]


def _kml(rings=None, *, extra="", point=None, root="kml"):
    """A KML document with one Placemark per ring of ``(lat, lon)`` vertices (``rings`` None: the
    square of side 100 m about CMAC)."""
    rings = [_latlon([(-50, -50), (50, -50), (50, 50), (-50, 50)])] if rings is None else rings
    marks = "".join(
        "<Placemark><name>area</name><Polygon><outerBoundaryIs><LinearRing><coordinates>"
        + " ".join(f"{lon!r},{lat!r},0" for lat, lon in ring)
        + f"</coordinates></LinearRing></outerBoundaryIs>{extra}</Polygon></Placemark>" for ring in rings)
    if point is not None:
        marks += f"<Placemark><name>home</name><Point>{point}</Point></Placemark>"
    return f'<?xml version="1.0"?><{root} xmlns="http://www.opengis.net/kml/2.2"><Document>{marks}</Document></{root}>'


def _qgc(polygons=None, circles=(), home=(CMAC[0], CMAC[1], CMAC[2])):
    polygons = ([{"inclusion": True, "polygon": [list(v) for v in _latlon(QGC_EN_M)], "version": 1}]
                if polygons is None else polygons)
    doc = {"fileType": "Plan", "geoFence": {"circles": list(circles), "polygons": polygons, "version": 2},
           "groundStation": "QGroundControl", "mission": {"items": [], "version": 2}, "version": 1}
    if home is not None:
        doc["mission"]["plannedHomePosition"] = list(home)
    return json.dumps(doc)


def _plan_with_fence(tmp_path: Path, name: str, content: str | bytes, *, origin: bool = True) -> Path:
    """The example KML plan with ``[geofence] file`` = ``name`` (written with ``content``), and
    without ``[origin]`` when ``origin`` is False."""
    fence = tmp_path / name
    fence.write_bytes(content if isinstance(content, bytes) else content.encode())
    text = KML_PLAN.read_text().replace('file = "fence.kml"', f'file = "{name}"')
    if not origin:
        doc_start = text.index("\n[origin]\n") + 1
        text = text[:doc_start] + text[text.index("\n[[vehicles]]\n", doc_start) + 1:]
    plan = tmp_path / "plan.toml"
    plan.write_text(text)
    return plan


# ------------------------------------------------------------------------------ the examples
def test_the_example_kml_converts_into_the_mission_frame():
    plan = load_plan(KML_PLAN)
    assert plan.origin == CMAC and not plan.geofence.origin_from_file
    assert "fence.kml: KML Polygon 'Search area'" in plan.geofence.source
    assert np.allclose(plan.geofence.polygon_en_m, KML_EN_M, atol=0.02)  # 1e-7 deg is at most 1.1 cm
    assert (plan.geofence.min_alt_m, plan.geofence.max_alt_m) == (3.0, 40.0)
    # and back: the mission frame's vertices are the file's, to 1e-9 deg
    frame = TangentFrame(plan.origin)
    back = [frame.enu_to_geodetic(e, n, 0.0)[:2] for e, n in plan.geofence.polygon_en_m]
    assert np.allclose(back, plan.geofence.source_latlon_deg, atol=1e-9, rtol=0)


def test_the_example_qgc_plan_gives_the_fence_and_the_origin():
    plan = load_plan(QGC_PLAN)
    assert plan.origin == CMAC and plan.geofence.origin_from_file
    assert "QGroundControl geoFence inclusion polygon" in plan.geofence.source
    assert np.allclose(plan.geofence.polygon_en_m, QGC_EN_M, atol=0.02)
    assert fence_problem(plan.geofence) is None


def test_the_plan_origin_wins_over_the_file_home(tmp_path):
    far_home = "<altitudeMode>absolute</altitudeMode><coordinates>149.1653,-35.3632,600</coordinates>"
    plan = load_plan(_plan_with_fence(tmp_path, "f.kml", _kml(point=far_home)))
    assert plan.origin == CMAC and not plan.geofence.origin_from_file
    plan = load_plan(_plan_with_fence(tmp_path, "f.kml", _kml(point=far_home), origin=False))
    assert plan.origin == (-35.3632, 149.1653, 600.0) and plan.geofence.origin_from_file
    # the same fence about the other origin: shifted by the origins' offset
    shift = TangentFrame(CMAC).geodetic_to_enu_m(-35.3632, 149.1653, CMAC[2])[:2]
    assert np.allclose(np.asarray(plan.geofence.polygon_en_m) + shift,
                       [(-50, -50), (50, -50), (50, 50), (-50, 50)], atol=0.05)


@pytest.mark.parametrize("point, why", [
    ("<coordinates>149.1652,-35.3632,600</coordinates>", "no absolute altitude"),  # clampToGround
    ("<altitudeMode>absolute</altitudeMode><coordinates>149.1652,-35.3632</coordinates>", "no absolute altitude"),
    (None, "gives no home position"),
])
def test_without_origin_the_file_must_give_a_home_with_its_altitude(tmp_path, point, why):
    with pytest.raises(PlanError, match=why) as err:
        load_plan(_plan_with_fence(tmp_path, "f.kml", _kml(point=point), origin=False))
    assert [k for k, _ in err.value.problems] == ["origin"]


# ---------------------------------------------------------------------------- bad fence files
_SQUARE = _latlon([(-50, -50), (50, -50), (50, 50), (-50, 50)])
_BAD_FILES = {
    "not XML": ("f.kml", "<kml><Document>", r"not XML"),
    "JSON in a .kml": ("f.kml", _qgc(), r"not XML"),
    "not KML": ("f.kml", _kml(root="svg"), r"not a KML document \(root element <svg>"),
    "no polygon": ("f.kml", '<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><LineString><coordinates>'
                   "149.1,-35.3 149.2,-35.3 149.2,-35.4</coordinates></LineString></Placemark></kml>", r"no Polygon"),
    "two polygons": ("f.kml", _kml([_SQUARE, _SQUARE]), r"2 Polygons: the safety envelope holds one"),
    "a hole": ("f.kml", _kml(extra="<innerBoundaryIs><LinearRing><coordinates>149.1652,-35.3632 "
                         "149.1653,-35.3632 149.1653,-35.3633</coordinates></LinearRing></innerBoundaryIs>"),
               r"has a hole \(innerBoundaryIs\)"),
    "latitude > 90": ("f.kml", _kml([[(95.0, 149.16), (95.0, 149.17), (95.1, 149.17)]]),
                      r"vertex 0: latitude 95.0 is outside -90..90"),
    "longitude > 180": ("f.kml", _kml([[(-35.36, 190.0), (-35.37, 190.0), (-35.37, 190.1)]]),
                        r"vertex 0: longitude 190.0 is outside -180..180"),
    "not numbers": ("f.kml", _kml().replace("<coordinates>", "<coordinates>east,north "), r"coordinate 0 'east,north'"),
    "two vertices": ("f.kml", _kml([_SQUARE[:2]]), r"2 vertices, at least 3"),
    "too many vertices": ("f.kml", _kml([_latlon([(50 * np.cos(a), 50 * np.sin(a)) for a in
                                                  np.linspace(0, 6.28, MAX_FENCE_VERTICES + 1)])]),
                          rf"{MAX_FENCE_VERTICES + 1} vertices, more than {MAX_FENCE_VERTICES}"),
    "external entity": ("f.kml", '<?xml version="1.0"?><!DOCTYPE kml [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                        '<kml><Placemark><Polygon><outerBoundaryIs><LinearRing><coordinates>&x;</coordinates>'
                        "</LinearRing></outerBoundaryIs></Polygon></Placemark></kml>", r"0 vertices, at least 3"),
    "plan not JSON": ("f.plan", "{fileType: Plan", r"not JSON"),
    "plan not UTF-8": ("f.plan", b"\xff\xfe{}", r"not UTF-8"),
    "plan of another kind": ("f.plan", json.dumps({"fileType": "Mission"}), r"not a QGroundControl plan"),
    "plan without geoFence": ("f.plan", json.dumps({"fileType": "Plan"}), r"no geoFence in the plan"),
    "empty geoFence": ("f.plan", _qgc(polygons=[]), r"no geoFence polygon"),
    "inclusion circle": ("f.plan", _qgc(circles=[{"circle": {"center": [-35.36, 149.16], "radius": 80},
                                                  "inclusion": True, "version": 1}]),
                         r"inclusion circle \(radius 80 m\): the safety envelope holds one polygon, not circles"),
    "exclusion circle": ("f.plan", _qgc(circles=[{"circle": {"center": [-35.36, 149.16], "radius": 5},
                                                  "inclusion": False, "version": 1}]), r"exclusion circle"),
    "exclusion polygon": ("f.plan", _qgc(polygons=[
        {"inclusion": True, "polygon": [list(v) for v in _SQUARE]},
        {"inclusion": False, "polygon": [list(v) for v in _SQUARE]}]), r"1 geoFence exclusion polygon"),
    "two inclusion polygons": ("f.plan", _qgc(polygons=[{"inclusion": True, "polygon": [list(v) for v in _SQUARE]}] * 2),
                               r"2 geoFence inclusion polygons"),
    "plan vertex not numbers": ("f.plan", _qgc(polygons=[{"inclusion": True, "polygon": [[1, 2], ["a", 3], [4, 5]]}]),
                                r"geoFence vertex 1 \['a', 3\] is not \[lat, lon\]"),
    "no inclusion flag": ("f.plan", _qgc(polygons=[{"polygon": [list(v) for v in _SQUARE]}]),
                          r"each geoFence polygon must be an object with \"inclusion\": true or false"),
    "plan latitude > 90": ("f.plan", _qgc(polygons=[{"inclusion": True, "polygon": [[91, 2], [1, 3], [4, 5]]}]),
                           r"vertex 0: latitude 91.0 is outside"),
    "bad home": ("f.plan", _qgc(home=[200, 149.1, 10]), r"plannedHomePosition: latitude 200 is outside"),
    "unknown type": ("f.txt", "anything", r"unknown fence file type '.txt'"),
}


@pytest.mark.parametrize("name, content, why", list(_BAD_FILES.values()), ids=list(_BAD_FILES))
def test_a_bad_fence_file_is_refused_with_the_reason(tmp_path, name, content, why):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(FenceFileError, match=why):
        read_fence_file(path)


def test_a_huge_fence_file_is_refused_unread(tmp_path):
    path = tmp_path / "huge.kml"
    path.write_bytes(b"<kml>" + b" " * MAX_FENCE_FILE_BYTES + b"</kml>")
    with pytest.raises(FenceFileError, match=rf"{MAX_FENCE_FILE_BYTES + 11} bytes, more than the {MAX_FENCE_FILE_BYTES}"):
        read_fence_file(path)


def test_a_missing_fence_file_is_refused(tmp_path):
    with pytest.raises(FenceFileError, match=r"nowhere.kml: cannot read: No such file"):
        read_fence_file(tmp_path / "nowhere.kml")


def test_swapped_latitude_and_longitude_are_refused_far_from_the_origin():
    fence = read_fence_file(EXAMPLES / "fence.plan")
    swapped = dataclasses.replace(fence, polygon_latlon_deg=tuple((lon - 180.0, lat) for lat, lon in
                                                                  fence.polygon_latlon_deg))
    with pytest.raises(FenceFileError, match=r"vertex 0 .* km from the origin .* latitude and longitude swapped"):
        fence_in_mission_frame(swapped, CMAC)
    # a KML written lat,lon (the usual slip): latitudes of 149 are refused, wherever the origin
    kml = _kml([[(lon, lat) for lat, lon in _SQUARE]])
    with pytest.raises(FenceFileError, match=r"latitude 149.16.* is outside -90..90"):
        from mission.core.fence_file import parse_kml
        parse_kml(kml.encode(), "swapped.kml")


def test_a_fence_far_from_the_plan_origin_is_a_plan_error(tmp_path):
    far = _kml([_latlon([(-50, -50), (50, -50), (50, 50), (-50, 50)], origin=(-35.0, 149.0, 0.0))])
    with pytest.raises(PlanError, match=r"geofence.file: .*f.kml: vertex 0 .* km from the origin"):
        load_plan(_plan_with_fence(tmp_path, "f.kml", far))


def test_a_self_intersecting_fence_file_is_refused_by_the_envelope_check(tmp_path):
    bowtie = _latlon([(-60, -60), (60, -60), (60, 60), (-60, 60), (0, -80), (-70, 0)])
    plan = load_plan(_plan_with_fence(tmp_path, "bow.kml", _kml([bowtie])))
    problem = fence_problem(plan.geofence)
    assert problem is not None and problem.startswith("geofence.file (")
    assert "bow.kml: KML Polygon 'area'" in problem and "self-intersecting: edge" in problem


# ------------------------------------------------------------------------- on the command line
def _one_line_error(err: str, prefix: str, *needles: str) -> None:
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith(prefix), err
    for needle in needles:
        assert needle in err, (needle, err)


@pytest.mark.parametrize("command", ["dry-run", "fly"])
@pytest.mark.parametrize("name, content, why", [
    ("f.plan", _qgc(circles=[{"circle": {"center": [-35.36, 149.16], "radius": 80}, "inclusion": True}]),
     "not circles"),
    ("f.kml", "not xml at all", "not XML"),
    ("f.kml", _kml([_latlon([(-60, -60), (60, -60), (60, 60), (-60, 60), (0, -80), (-70, 0)])]), "self-intersecting"),
    ("nowhere.kml", None, "cannot read"),
])
def test_the_cli_refuses_a_bad_fence_file_with_exit_2_and_flies_nothing(tmp_path, capsys, command, name, content, why):
    plan = _plan_with_fence(tmp_path, "placeholder.kml", _kml())
    plan.write_text(plan.read_text().replace('file = "placeholder.kml"', f'file = "{name}"'))
    if content is not None:
        (tmp_path / name).write_text(content)
    logs = tmp_path / "logs"
    argv = [command, "--plan", str(plan)] + (["--log-dir", str(logs)] if command == "fly" else [])
    assert cli_main(argv) == 2
    captured = capsys.readouterr()
    _one_line_error(captured.err, f"swarmseek {command}: invalid plan in {plan}", "geofence.file", why)
    assert not logs.exists()  # refused before a mission log (or a link) was opened
    assert "geofence from" not in captured.out


def _unreachable(plan_path: Path, tmp_path: Path) -> Path:
    """The plan with its vehicles on free local UDP ports nobody serves (dry-run: not ready)."""
    from mission.sim.embedded import free_port_block

    text = plan_path.read_text()
    base = free_port_block(4, kinds=("udp",))
    for i, port in enumerate((5760, 5770, 5780, 5790)):
        text = text.replace(f'"tcp:127.0.0.1:{port}"', f'"udpin:127.0.0.1:{base + i}"')
    fence = EXAMPLES / ("fence.kml" if "fence.kml" in text else "fence.plan")
    (tmp_path / fence.name).write_bytes(fence.read_bytes())
    out = tmp_path / plan_path.name
    out.write_text(text)
    return out


@pytest.mark.parametrize("plan_path, expected_en_m", [(KML_PLAN, KML_EN_M), (QGC_PLAN, QGC_EN_M)],
                         ids=["kml", "qgc"])
def test_dry_run_shows_the_conversion_of_each_example(tmp_path, capsys, plan_path, expected_en_m):
    plan = _unreachable(plan_path, tmp_path)
    assert cli_main(["dry-run", "--plan", str(plan), "--timeout", "1"]) == 1  # nobody answers: not ready
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("geofence from ") and lines[2].split()[:3] == ["vertex", "lat_deg", "lon_deg"]
    rows = [line.split() for line in lines[3:3 + len(expected_en_m)]]
    assert [int(r[0]) for r in rows] == list(range(len(expected_en_m)))
    assert np.allclose([(float(r[5]), float(r[4])) for r in rows], expected_en_m, atol=0.02)  # east, north
    assert any(line.startswith("check start_in_fence  ok") for line in lines), lines
    assert cli_main(["dry-run", "--plan", str(plan), "--timeout", "1", "--json"]) == 1
    conv = json.loads(capsys.readouterr().out)["geofence_conversion"]
    assert conv["origin"] == list(CMAC) and conv["origin_from_file"] == (plan_path == QGC_PLAN)
    assert np.allclose([(v["east_m"], v["north_m"]) for v in conv["vertices"]], expected_en_m, atol=0.02)


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("plan_path", [KML_PLAN, QGC_PLAN], ids=["kml", "qgc"])
def test_a_plan_with_each_example_fence_is_ready_against_a_mock_fleet(plan_path):
    """The imported fence in a whole dry-run: a mock fleet at the file's origin, every vehicle
    ready, the start and the paths to the slots inside the imported fence, nothing armed."""
    from tests.support.fly_helpers import run_fleet
    from mission.cli.cmd_dryrun import dry_run
    from mission.sim.embedded import embedded_plan, fleet_ports
    from mission.sim.lockstep import VirtualClock
    from sitl_mock.fields_gaussian import sigma2
    from sitl_mock.fleet import MockFleet

    plan = load_plan(plan_path)
    ports = fleet_ports(4, "px4")
    embedded = embedded_plan(4, ports)
    plan = dataclasses.replace(plan, vehicles=embedded.vehicles, zenoh=embedded.zenoh)
    fleet = MockFleet(n=4, personality="px4", field=sigma2(np.array([10.0, 30.0, 14.0])), origin=plan.origin,
                      clock=VirtualClock(), seed=3, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0, fleet_name=plan.fleet,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    try:
        result = run_fleet(fleet, lambda _world: dry_run(plan, clock=fleet.clock))
    finally:
        fleet.stop()
    assert result.outcome == "ready", (result.message, result.readiness)
    checks = {c["name"]: c["ok"] for c in result.mission_checks}
    assert checks["start_in_fence"] and checks["path_in_fence"], result.mission_checks
    assert not any(v.armed for v in fleet.vehicles)


def test_resume_reads_an_imported_fence_back_from_the_log_plan_record():
    from mission.flight.phases.resume import plan_from_json
    from mission.telemetry.mission_log import to_jsonable

    plan = load_plan(QGC_PLAN)
    back = plan_from_json(json.loads(json.dumps(to_jsonable(plan))))
    assert back.geofence.source_latlon_deg == plan.geofence.source_latlon_deg  # degrees to 1e-9 in the log
    assert np.allclose(back.geofence.polygon_en_m, plan.geofence.polygon_en_m, atol=1e-6, rtol=0)
    assert (back.geofence.source, back.geofence.origin_from_file) == (plan.geofence.source, True)
    assert back.origin == plan.origin


def test_an_older_qgc_geofence_with_one_polygon_is_read():
    from mission.core.fence_file import parse_qgc_plan

    ring = [list(v) for v in _latlon(QGC_EN_M)]
    doc = {"fileType": "Plan", "geoFence": {"polygon": ring, "breachReturn": ring[0], "version": 1}, "version": 1}
    fence = parse_qgc_plan(json.dumps(doc).encode(), "old.plan")
    assert fence.polygon_latlon_deg == tuple(tuple(v) for v in ring) and fence.home is None
    assert np.allclose(fence_in_mission_frame(fence, CMAC), QGC_EN_M, atol=1e-6)
