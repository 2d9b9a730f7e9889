"""``mission.safety.audit`` on synthetic tlogs: each kind of broken rule is caught, clean logs pass, bad
input is a clear error (and ``swarmseek audit`` exits 0 / 1 / 2)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from formation.geodesy import geodetic_to_enu
from mission.safety.audit_read import AuditError
from mission.safety.audit import audit_mission
from mission.cli import main as cli_main
from mission.link.tlog import tlog_record

ORIGIN = (45.1885, 5.7245, 212.0)
T0 = 1.8e9
_SPEED = 3.0
_SEP = 1.5


def _plan(polygon=((-50, -50), (50, -50), (50, 50), (-50, 50)), lo=2.0, hi=40.0):
    return {"origin": list(ORIGIN), "geofence": {"polygon_en_m": [list(p) for p in polygon],
                                                "min_alt_m": lo, "max_alt_m": hi},
            "max_speed_m_s": _SPEED, "min_separation_m": _SEP}


def _home_for(enu):
    from formation.geodesy import enu_to_geodetic
    lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), ORIGIN)
    return int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)), int(round(float(alt) * 1e3))


def _write_log(tmp_path, tracks, plan=None, mask=0x1F8 | 0x800 | 0x400, heartbeats=None):
    """``tracks``: sysid -> (home_enu, [(t_s, east, north, up), ...]) in the mission frame;
    ``heartbeats``: sysid -> [(t_s, autopilot, base_mode, custom_mode), ...] sent by the vehicle."""
    (tmp_path / "tlogs").mkdir()
    with open(tmp_path / "mission.jsonl", "w") as fh:
        fh.write(json.dumps({"t_s": T0, "type": "plan", "plan": plan or _plan()}) + "\n")
    for sysid, (home_enu, points) in tracks.items():
        veh = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        lat, lon, alt = _home_for(home_enu)
        home = veh.home_position_encode(lat, lon, alt, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
        out = [tlog_record(home.pack(veh), T0)]
        h = geodetic_to_enu(lat * 1e-7, lon * 1e-7, alt * 1e-3, ORIGIN)
        for t_s, e, n, u in points:
            sp = gcs.set_position_target_local_ned_encode(0, sysid, 1, 1, mask, n - h[1], e - h[0], -(u - h[2]),
                                                          0, 0, 0, 0, 0, 0, 0, 0)
            out.append(tlog_record(sp.pack(gcs), T0 + t_s))
        for t_s, autopilot, base_mode, custom_mode in (heartbeats or {}).get(sysid, []):
            hb = veh.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, autopilot, base_mode, custom_mode,
                                      mavlink.MAV_STATE_ACTIVE)
            out.append(tlog_record(hb.pack(veh), T0 + t_s))
        (tmp_path / "tlogs" / f"vehicle-{sysid}.tlog").write_bytes(b"".join(out))
    return tmp_path


def _line(sysid_home, start, velocity, n=50, dt=0.1):
    start, velocity = np.asarray(start, float), np.asarray(velocity, float)
    return (sysid_home, [(1 + k * dt, *(start + velocity * k * dt)) for k in range(n)])


def test_clean_log_passes_and_counts(tmp_path):
    tracks = {1: _line((0, 0, 0), (0, 0, 10), (2.0, 0, 0)), 2: _line((5, 5, 0), (0, 10, 10), (0, 2.9, 0))}
    report = audit_mission(_write_log(tmp_path, tracks))
    assert report.ok, report.format_text()
    assert report.setpoints_checked == 100
    assert report.speed_steps_checked == 98
    assert 2.8 < report.max_step_speed_m_s <= _SPEED
    assert report.separation_segments_checked > 0 and report.min_separation_seen_m > _SEP


@pytest.mark.parametrize("point, kind", [
    ((60.0, 0.0, 10.0), "fence"),
    ((0.0, -50.5, 10.0), "fence"),
    ((0.0, 0.0, 1.5), "altitude"),
    ((0.0, 0.0, 41.0), "altitude"),
])
def test_setpoint_outside_fence_is_caught(tmp_path, point, kind):
    tracks = {1: ((0, 0, 0), [(1.0, 0, 0, 10), (40.0, *point), (80.0, 0, 0, 10)])}
    report = audit_mission(_write_log(tmp_path, tracks))
    assert report.violation_counts == {kind: 1}, report.format_text()
    v = report.violations[0]
    assert v.sysids == (1,) and v.t_s == pytest.approx(T0 + 40.0)


def test_boundary_within_a_centimetre_passes(tmp_path):
    tracks = {1: ((3, -7, 1), [(1.0, 0, 0, 10), (20.0, 50.0, 0, 10), (40.0, 50.0, 0, 2.0),
                               (60.0, 0, 49.995, 40.0)])}
    report = audit_mission(_write_log(tmp_path, tracks))
    assert report.ok, report.format_text()
    assert abs(report.min_fence_margin_m) < 0.01


@pytest.mark.parametrize("speed_m_s, caught", [(2.95, False), (3.5, True), (6.0, True)])
def test_too_fast_step_is_caught(tmp_path, speed_m_s, caught):
    points = [(1.0, 0, 0, 10), (1.1, 0, 0, 10), (1.2, 0.1 * speed_m_s, 0, 10)]
    report = audit_mission(_write_log(tmp_path, {1: ((0, 0, 0), points)}))
    assert (report.violation_counts.get("speed", 0) == 1) is caught, report.format_text()
    assert report.max_step_speed_m_s == pytest.approx(speed_m_s, rel=1e-3)


def test_two_vehicles_crossing_are_caught(tmp_path):
    # both at 2 m/s, heading for the same point from opposite sides: end points 10 m apart, the
    # paths cross; the pair's closest approach is on a path segment
    a = _line((0, 0, 0), (-5, 0, 10), (2.0, 0, 0), n=60)
    b = _line((9, 9, 0), (5, 0, 10), (-2.0, 0, 0), n=60)
    report = audit_mission(_write_log(tmp_path, {1: a, 2: b}))
    assert report.violation_counts.get("separation", 0) > 0, report.format_text()
    assert set(report.violation_counts) == {"separation"}
    assert report.min_separation_seen_m < 0.2
    assert all(v.sysids == (1, 2) for v in report.violations)


def test_paths_checked_not_only_instants(tmp_path):
    # swap places in one step (2.95 m/s): every setpoint instant is 2.8 m apart, the paths cross
    a = ((0, 0, 0), [(1.0, -1.4, 0, 10), (2.0, -1.4, 0, 10), (2.95, 1.4, 0, 10)])
    b = ((9, 9, 0), [(1.0, 1.4, 0, 10), (2.0, 1.4, 0, 10), (2.95, -1.4, 0, 10)])
    report = audit_mission(_write_log(tmp_path, {1: a, 2: b}))
    assert report.violation_counts == {"separation": 1}, report.format_text()
    assert "paths" in report.violations[0].detail


def test_stale_vehicle_does_not_count(tmp_path):
    # vehicle 1 stops being commanded at t = 2; vehicle 2 is commanded at its spot from t = 10
    a = ((0, 0, 0), [(1.0, 0, 0, 10), (2.0, 0, 0, 10)])
    b = ((9, 9, 0), [(10.0, 0, 0, 10), (11.0, 0, 0, 10)])
    report = audit_mission(_write_log(tmp_path, {1: a, 2: b}))
    assert report.ok, report.format_text()
    assert report.separation_instants_checked == 0


_PX4, _APM = mavlink.MAV_AUTOPILOT_PX4, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
_PX4_OFFBOARD, _PX4_RTL = 6 << 16, (4 << 16) | (5 << 24)
_APM_GUIDED, _APM_RTL = 4, 6


@pytest.mark.parametrize("heartbeat, caught", [
    (None, True),                                   # no word from the vehicle: its last setpoint holds 1 s
    ((2.0, _PX4, _ARMED, _PX4_RTL), False),          # PX4 says AUTO.RTL when its last setpoint is sent
    ((2.2, _PX4, _ARMED, _PX4_RTL), True),           # ... only after the other came close (2.1 s)
    ((2.0, _PX4, _ARMED, _PX4_OFFBOARD), True),      # still OFFBOARD: still holding that setpoint
    ((2.0, _APM, _ARMED, _APM_RTL), False),          # ArduPilot RTL
    ((2.0, _APM, _ARMED, _APM_GUIDED), True),        # ArduPilot GUIDED
    ((2.0, _APM, 0, _APM_GUIDED), False),            # disarmed
])
def test_a_vehicle_that_left_setpoints_no_longer_holds_its_last_one(tmp_path, heartbeat, caught):
    """Vehicle 1's last setpoint is at (0, 0, 10) at t = 2 s; vehicle 2 is sent (0.5, 0, 10) at
    t = 2.1 s: closer than 1.5 m, within the 1 s that vehicle 1 would hold its last setpoint --
    unless vehicle 1 said (HEARTBEAT in its tlog) that it left OFFBOARD/GUIDED by then."""
    a = ((0, 0, 0), [(1.0, 0, 0, 10), (2.0, 0, 0, 10)])
    b = ((9, 9, 0), [(2.1, 0.5, 0, 10), (2.2, 0.5, 0, 10)])
    hbs = {1: [(1.0, heartbeat[1], _ARMED, _PX4_OFFBOARD if heartbeat[1] == _PX4 else _APM_GUIDED), heartbeat]} \
        if heartbeat else None
    report = audit_mission(_write_log(tmp_path, {1: a, 2: b}, heartbeats=hbs))
    assert (report.violation_counts.get("separation", 0) > 0) == caught, report.format_text()


def test_velocity_only_setpoints_are_skipped(tmp_path):
    report = audit_mission(_write_log(tmp_path, {1: ((0, 0, 0), [(1.0, 900, 0, 10)])}, mask=0x7 | 0x1C0 | 0xC00))
    assert report.clean and report.setpoints_skipped == 1 and report.setpoints_checked == 0
    # nothing was checked: the audit says so instead of passing (exit status 3)
    assert not report.ok and report.exit_status == 3 and "nothing was checked" in report.incomplete[0]


def test_setpoint_before_home_is_reported(tmp_path):
    _write_log(tmp_path, {1: ((0, 0, 0), [(1.0, 0, 0, 10)])})
    path = tmp_path / "tlogs" / "vehicle-1.tlog"
    from mission.link.tlog import read_tlog_records, tlog_record as rec
    records = read_tlog_records(path)
    (_, home), (t_sp, setpoint) = records
    path.write_bytes(rec(setpoint, t_sp) + rec(home, t_sp + 1.0))   # the home comes after the setpoint
    report = audit_mission(tmp_path)
    assert report.violation_counts == {"no_home": 1}


def _broken(log_dir, how):
    """A log directory broken in one way."""
    if how == "missing":
        return log_dir / "missing"
    if how == "empty":
        return log_dir
    _write_log(log_dir, {1: ((0, 0, 0), [(1.0, 0, 0, 10)])},
               plan={"origin": list(ORIGIN)} if how == "no_limits" else None)
    if how == "no_log":
        (log_dir / "mission.jsonl").unlink()
    elif how == "no_plan":
        (log_dir / "mission.jsonl").write_text('{"t_s": 1, "type": "phase", "phase": "connect"}\n')
    elif how == "bad_name":
        (log_dir / "tlogs" / "vehicle-1.tlog").rename(log_dir / "tlogs" / "flight.tlog")
    return log_dir


@pytest.mark.parametrize("how, message", [
    ("missing", "no such directory"),
    ("empty", "no .tlog files"),
    ("no_log", "no mission log"),
    ("no_plan", "no plan record"),
    ("no_limits", "lacks the safety limits"),
    ("bad_name", "not a vehicle tlog name"),
])
def test_bad_input_is_a_clear_error(tmp_path, how, message):
    with pytest.raises(AuditError, match=message):
        audit_mission(_broken(tmp_path, how))


def test_cli_exit_codes(tmp_path, capsys):
    clean = tmp_path / "clean"
    clean.mkdir()
    _write_log(clean, {1: ((0, 0, 0), [(1.0, 0, 0, 10)])})
    assert cli_main(["audit", str(clean)]) == 0
    assert "OK: no violation" in capsys.readouterr().out
    bad = tmp_path / "bad"
    bad.mkdir()
    _write_log(bad, {1: ((0, 0, 0), [(1.0, 0, 0, 10), (2.0, 90, 0, 10)])})
    assert cli_main(["audit", str(bad), "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["ok"] is False and out["violation_counts"]["fence"] == 1
    assert cli_main(["audit", str(tmp_path / "nowhere")]) == 2
    assert "no such directory" in capsys.readouterr().err


@pytest.mark.parametrize("frame, up_m, kind", [
    (mavlink.MAV_FRAME_GLOBAL_INT, 10.0, None),
    (mavlink.MAV_FRAME_GLOBAL_INT, 60.0, "altitude"),
    (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 10.0, None),
    (mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, 10.0, "frame"),
])
def test_global_int_setpoints_are_placed(tmp_path, frame, up_m, kind):
    from formation.geodesy import enu_to_geodetic
    _write_log(tmp_path, {1: ((0, 0, 0), [])})
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    lat, lon, alt = enu_to_geodetic(np.array([20.0, -10.0, up_m]), ORIGIN)
    if frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
        alt = up_m                                     # the home is at the origin's altitude
    sp = gcs.set_position_target_global_int_encode(0, 1, 1, frame, 0x1F8 | 0xC00, int(round(float(lat) * 1e7)),
                                                   int(round(float(lon) * 1e7)), float(alt), 0, 0, 0, 0, 0, 0, 0, 0)
    with open(tmp_path / "tlogs" / "vehicle-1.tlog", "ab") as fh:
        fh.write(tlog_record(sp.pack(gcs), T0 + 5.0))
    report = audit_mission(tmp_path)
    assert report.violation_counts == ({} if kind is None else {kind: 1}), report.format_text()
    if kind is None:
        assert report.setpoints_checked == 1
        assert report.min_fence_margin_m == pytest.approx(min(50.0 - 20.0, up_m - 2.0), abs=0.02)


def test_zero_time_jump_is_infinitely_fast_and_json_stays_strict(tmp_path, capsys):
    _write_log(tmp_path, {1: ((0, 0, 0), [(1.0, 0, 0, 10), (1.0, 1.0, 0, 10)])})
    report = audit_mission(tmp_path)
    assert report.violation_counts == {"speed": 1}
    assert report.max_step_speed_m_s == float("inf")
    assert cli_main(["audit", str(tmp_path), "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["max_step_speed_m_s"] is None and out["violations"][0]["value"] is None


def test_each_setpoint_uses_the_last_home_before_it(tmp_path):
    # same LOCAL_NED setpoint (10 m east of the local origin) before and after the vehicle's home
    # moves from (0, 0) to (45, 0): the second one is at 55 m east, outside the fence
    _write_log(tmp_path, {1: ((0, 0, 0), [(1.0, 10.0, 0, 10)])})
    veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    lat, lon, alt = _home_for((45.0, 0.0, 0.0))
    home = veh.home_position_encode(lat, lon, alt, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    sp = gcs.set_position_target_local_ned_encode(0, 1, 1, 1, 0x1F8 | 0xC00, 0.0, 10.0, -10.0, 0, 0, 0, 0, 0, 0, 0, 0)
    with open(tmp_path / "tlogs" / "vehicle-1.tlog", "ab") as fh:
        fh.write(tlog_record(home.pack(veh), T0 + 50.0) + tlog_record(sp.pack(gcs), T0 + 60.0))
    report = audit_mission(tmp_path)
    assert report.violation_counts == {"fence": 1}, report.format_text()
    assert report.violations[0].t_s == pytest.approx(T0 + 60.0)
    assert report.violations[0].value == pytest.approx(5.0, abs=0.05)


def test_tlogs_of_a_resumed_mission_are_merged(tmp_path):
    # a resume appends vehicle-1-2.tlog: its setpoints continue the first file's track
    _write_log(tmp_path, {1: _line((0, 0, 0), (0, 0, 10), (2.0, 0, 0), n=20)})
    first = tmp_path / "tlogs" / "vehicle-1.tlog"
    second = tmp_path / "second"
    second.mkdir()
    _write_log(second, {1: ((0, 0, 0), [(3.0, 4.1, 0, 10), (3.1, 4.3, 0, 10)])})
    (second / "tlogs" / "vehicle-1.tlog").rename(tmp_path / "tlogs" / "vehicle-1-2.tlog")
    report = audit_mission(tmp_path)
    assert first.exists() and len(report.tlogs) == 2
    assert report.setpoints_checked == 22 and report.per_vehicle[1]["tracks"] == 1
    assert report.ok, report.format_text()


@pytest.mark.parametrize("b_delay_s, flagged", [(0.0002, False), (0.05, True)])
def test_latest_vs_latest_counts_one_burst_as_sent_together(b_delay_s, flagged):
    """Two vehicles 1.6 m apart in a line both step 0.9 m along it (synchronous paths never closer
    than 1.6 m). Sent in one burst (0.2 ms apart) the instant between the two datagrams is no state
    a vehicle can be in: not a violation. The second datagram 50 ms late (longer than the stamp
    jitter, e.g. a stalled sender): the first vehicle's new setpoint and the second's old one are
    0.7 m apart for 50 ms, a violation."""
    from mission.safety.audit import AuditReport, _check_pair
    from mission.safety.audit_read import VehicleSetpoints

    t_a = np.array([0.0, 0.1, 0.2])
    a = VehicleSetpoints(1, t_a, np.array([[0.0, 0, 10], [0.9, 0, 10], [0.9, 0, 10]]))
    t_b = np.array([0.0, 0.1 + b_delay_s, 0.2 + b_delay_s])
    b = VehicleSetpoints(2, t_b, np.array([[1.6, 0, 10], [2.5, 0, 10], [2.5, 0, 10]]))
    report = AuditReport(log_dir="-", tlogs=[])
    _check_pair(report, a, b, [(0, 3)], [(0, 3)], 1.5, 0.01, 1.0, burst_s=0.01)
    kinds = [v.kind for v in report.violations]
    assert bool(kinds) is flagged, report.violations
    if flagged:
        assert min(v.value for v in report.violations) == pytest.approx(0.7)
    else:
        assert report.min_separation_seen_m > 1.59  # the paths: a is 0.2 ms ahead of b
