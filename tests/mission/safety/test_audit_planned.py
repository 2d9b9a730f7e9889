"""``swarmseek audit`` counts only the plan's vehicles: a tlog of another system id (PX4 forwards
the sensors' heartbeats, system id 255) is listed as ignored, never audited or counted."""
from __future__ import annotations

import json

import pytest

from mission.cli import main as cli_main
from mission.safety.audit_read import AuditError
from mission.safety.audit import audit_mission
from tests.mission.safety.test_audit import _line, _plan, _write_log


def _planned(sysids):
    plan = _plan()
    plan["vehicles"] = [{"id": f"v{s}", "sysid": s, "connection": f"udpin:127.0.0.1:{14540 + s}"} for s in sysids]
    return plan


def test_tlog_of_an_unplanned_sysid_is_ignored_and_listed(tmp_path, capsys):
    # sysid 255's "track" would break the fence: it must not be audited at all
    tracks = {1: _line((0, 0, 0), (0, 0, 10), (2.0, 0, 0)), 2: _line((5, 5, 0), (0, 10, 10), (0, 2.9, 0)),
              255: _line((0, 0, 0), (100, 100, 100), (0, 0, 0))}
    log = _write_log(tmp_path, tracks, plan=_planned([1, 2]))
    report = audit_mission(log)
    assert report.ok, report.format_text()
    assert sorted(report.per_vehicle) == [1, 2]
    assert [p.rsplit("/", 1)[-1] for p in report.ignored_tlogs] == ["vehicle-255.tlog"]
    assert cli_main(["audit", str(log)]) == 0
    out = capsys.readouterr().out
    assert "2 vehicle(s)" in out and "ignored 1 tlog(s) of system ids not in the plan: vehicle-255.tlog" in out
    assert cli_main(["audit", str(log), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["ignored_tlogs"][0].endswith("vehicle-255.tlog")


def test_planned_vehicle_tlog_with_violation_still_caught(tmp_path):
    tracks = {1: _line((0, 0, 0), (0, 0, 10), (2.0, 0, 0)), 3: _line((0, 0, 0), (49, 0, 10), (3.0, 0, 0))}
    report = audit_mission(_write_log(tmp_path, tracks, plan=_planned([1, 3])))
    assert not report.ok and report.violation_counts.get("fence", 0) > 0
    assert sorted(report.per_vehicle) == [1, 3] and report.ignored_tlogs == []


def test_no_tlog_of_a_planned_vehicle_is_a_clear_error(tmp_path):
    log = _write_log(tmp_path, {255: _line((0, 0, 0), (0, 0, 10), (1.0, 0, 0))}, plan=_planned([1, 2]))
    with pytest.raises(AuditError, match=r"no \.tlog of a planned vehicle \(system ids \[1, 2\]\)"):
        audit_mission(log)
