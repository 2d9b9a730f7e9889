"""The audit's fast read paths give exactly what the plain ones give.

* tlog frames: ``audit_read._decode_frame`` (struct fast path, then pymavlink) against pymavlink's
  own ``decode`` on random valid, corrupted and truncated frames (hypothesis);
* a whole log: ``read_vehicle_setpoints`` and ``audit_mission`` with the fast path on and forced off;
* the mission log: ``iter_mission_log(prefilter=...)`` keeps every plan record the plain reading finds.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from pymavlink.dialects.v20 import common as mavlink

from mission.link.tlog import tlog_record
from mission.safety import audit_read
from mission.safety.audit import audit_mission
from mission.safety.audit_read import AuditError, _decode_frame, find_tlogs, read_vehicle_setpoints
from mission.telemetry.mission_log import iter_mission_log

ORIGIN = (45.1885, 5.7245, 212.0)
T0 = 1.8e9
_f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
_u8 = st.integers(0, 255)


def _frames(draw_kind, vals):
    """One packed frame of ``draw_kind`` (from the ground station or vehicle 7) with ``vals``."""
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    veh = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
    if draw_kind == "local":
        return gcs.set_position_target_local_ned_encode(vals["t"], vals["a"], 1, 1, vals["mask"], *vals["f"][:9],
                                                        vals["f"][9], vals["f"][10]).pack(gcs)
    if draw_kind == "global":
        return gcs.set_position_target_global_int_encode(vals["t"], vals["a"], 1, vals["frame"], vals["mask"],
                                                         vals["i"], -vals["i"], *vals["f"][:7],
                                                         vals["f"][7], vals["f"][8]).pack(gcs)
    return veh.heartbeat_encode(vals["a"], 12, vals["mask"] & 0xFF, vals["t"], vals["frame"]).pack(veh)


def _same(a, b) -> bool:
    """Same message: type, fields (NaN-aware through the packed payload), header and frame bytes."""
    return (a.get_type() == b.get_type() and a.get_payload() == b.get_payload()
            and bytes(a.get_msgbuf()) == bytes(b.get_msgbuf()) and a.get_srcSystem() == b.get_srcSystem()
            and a.get_srcComponent() == b.get_srcComponent() and a.get_seq() == b.get_seq()
            and a.get_crc() == b.get_crc()
            and json.dumps(a.to_dict(), default=str) == json.dumps(b.to_dict(), default=str))


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(["local", "global", "heartbeat"]),
       vals=st.fixed_dictionaries({"t": st.integers(0, 2**32 - 1), "a": _u8, "mask": st.integers(0, 0xFFFF),
                                   "frame": _u8, "i": st.integers(-2**31 + 1, 2**31 - 1),
                                   "f": st.lists(_f32, min_size=11, max_size=11)}),
       damage=st.one_of(st.none(), st.tuples(st.integers(0, 60), st.integers(1, 255)),
                        st.integers(1, 20).map(lambda k: -k)))
def test_frame_decode_fast_path_equals_pymavlink(kind, vals, damage):
    frame = bytearray(_frames(kind, vals))
    if isinstance(damage, tuple):            # one byte flipped
        pos = damage[0] % len(frame)
        frame[pos] ^= damage[1]
    elif isinstance(damage, int):            # cut short
        frame = frame[:damage]
    frame = bytes(frame)
    plain = mavlink.MAVLink(None)
    try:
        want = plain.decode(bytearray(frame))
    except Exception as exc:  # noqa: BLE001 - whatever pymavlink raises, the audit must refuse too
        want = exc
    try:
        got = _decode_frame(mavlink.MAVLink(None), frame, "x.tlog", 1.0, 0)
    except AuditError as exc:
        got = exc
    if isinstance(want, Exception):
        # pymavlink refuses it: the fast path must not have produced a message either
        assert isinstance(got, AuditError), (want, got)
    else:
        assert not isinstance(got, Exception), got
        assert _same(got, want)


def _write_log(tmp_path, n_vehicles=3, n_points=120):
    """A small mission dir: plan record, per vehicle a HOME_POSITION, heartbeats (OFFBOARD armed
    then disarmed), LOCAL_NED and GLOBAL_INT setpoints moving at 1 m/s, one MAVLink 1 frame."""
    (tmp_path / "tlogs").mkdir()
    plan = {"origin": list(ORIGIN), "geofence": {"polygon_en_m": [[-80, -80], [80, -80], [80, 80], [-80, 80]],
                                                 "min_alt_m": 2.0, "max_alt_m": 40.0},
            "max_speed_m_s": 3.0, "min_separation_m": 1.5}
    (tmp_path / "mission.jsonl").write_text(json.dumps({"t_s": T0, "type": "plan", "plan": plan}) + "\n")
    rng = np.random.default_rng(5)
    for sysid in range(1, n_vehicles + 1):
        veh = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        home = veh.home_position_encode(int(ORIGIN[0] * 1e7), int(ORIGIN[1] * 1e7), int(ORIGIN[2] * 1e3),
                                        0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
        out = [tlog_record(home.pack(veh), T0)]
        for k in range(n_points):
            t = T0 + 0.1 * (k + 1)
            if k % 10 == 0:
                hb = veh.heartbeat_encode(2, 12, 128 if k < n_points - 10 else 0, 6 << 16, 4)
                out.append(tlog_record(hb.pack(veh), t - 0.01))
            e, n, u = 10.0 * sysid + 0.1 * k, 0.05 * k + rng.normal(0, 0.01), 10.0
            if k % 7:
                sp = gcs.set_position_target_local_ned_encode(0, sysid, 1, 1, 0xDF8, n, e, -u, 0, 0, 0, 0, 0, 0, 0, 0)
            else:
                from formation.geodesy import enu_to_geodetic
                lat, lon, alt = enu_to_geodetic(np.array([e, n, u]), ORIGIN)
                sp = gcs.set_position_target_global_int_encode(0, sysid, 1, 5, 0xDF8, int(round(float(lat) * 1e7)),
                                                               int(round(float(lon) * 1e7)), float(alt),
                                                               0, 0, 0, 0, 0, 0, 0, 0)
            out.append(tlog_record(sp.pack(gcs), t))
        v1 = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        v1.WIRE_PROTOCOL_VERSION = "1.0"
        out.append(tlog_record(veh.heartbeat_encode(2, 12, 0, 0, 4).pack(v1, force_mavlink1=True), T0 + 20))
        (tmp_path / "tlogs" / f"vehicle-{sysid}.tlog").write_bytes(b"".join(out))
    return tmp_path


def _fields(sp):
    return (sp.t_s.tolist(), sp.enu_m.tolist(), sp.mode_t_s.tolist(), sp.following.tolist(), sp.homes)


def test_whole_log_read_same_with_fast_path_off(tmp_path, monkeypatch):
    log_dir = _write_log(tmp_path)
    tlogs = find_tlogs(log_dir)
    fast = {s: _fields(read_vehicle_setpoints(p, s, ORIGIN)) for s, p in tlogs.items()}
    report_fast = audit_mission(log_dir)
    monkeypatch.setattr(audit_read, "decode_single_frame", lambda frame: None)
    plain = {s: _fields(read_vehicle_setpoints(p, s, ORIGIN)) for s, p in tlogs.items()}
    report_plain = audit_mission(log_dir)
    assert fast == plain
    assert all(len(v[0]) > 100 for v in fast.values())   # the setpoints were read
    assert report_fast.violation_counts == report_plain.violation_counts
    assert str(report_fast.to_json() if hasattr(report_fast, "to_json") else vars(report_fast)) == \
        str(report_plain.to_json() if hasattr(report_plain, "to_json") else vars(report_plain))


def test_bad_crc_frame_still_refused(tmp_path):
    log_dir = _write_log(tmp_path, n_vehicles=1, n_points=20)
    path = log_dir / "tlogs" / "vehicle-1.tlog"
    data = bytearray(path.read_bytes())
    data[-3] ^= 0xFF      # the last record's CRC (a MAVLink 1 HEARTBEAT, wanted)
    path.write_bytes(bytes(data))
    with pytest.raises(AuditError, match="cannot be decoded"):
        read_vehicle_setpoints([path], 1, ORIGIN)


@pytest.mark.parametrize("line", [
    '{"t_s":1,"type":"plan","plan":{"a":1}}',
    '{"t_s":1, "type" : "plan", "plan":{"a":2}}',
    '{"t_s":1,"type":"pl\\u0061n","plan":{"a":3}}',
    '{"t_s":1,"\\u0074ype":"plan","dry_run":true}',
    '{"t_s":1,"type":"event","message":"no p-l-a-n here"}',
    '{"t_s":1,"type":"plan"',              # truncated: skipped by both
    'not json plan',
])
def test_mission_log_prefilter_keeps_every_plan_record(tmp_path, line):
    path = tmp_path / "mission.jsonl"
    path.write_text("\n".join(['{"t_s":0,"type":"event","message":"start"}', line,
                               '{"t_s":2,"type":"iteration","k":1}']) + "\n")
    want = [r for r in iter_mission_log(path) if r.get("type") == "plan"]
    got = [r for r in iter_mission_log(path, prefilter=audit_read._PLAN_LINE) if r.get("type") == "plan"]
    assert got == want


@pytest.mark.parametrize("cut", [0, 1, 5, 13])
def test_split_records_wanted_equals_filtered_plain(tmp_path, cut):
    """Skipping unwanted records uncopied gives the plain split, filtered (a cut last record too)."""
    log_dir = _write_log(tmp_path, n_vehicles=1, n_points=40)
    path = log_dir / "tlogs" / "vehicle-1.tlog"
    if cut:
        path.write_bytes(path.read_bytes()[:-cut])
    wanted = {mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT, mavlink.MAVLINK_MSG_ID_HEARTBEAT}

    def msgid(frame):
        return frame[5] if frame[0] == 0xFE else int.from_bytes(frame[7:10], "little")

    plain = audit_read._split_records(path)
    got = audit_read._split_records(path, wanted)
    assert got == [r for r in plain if msgid(r[1]) in wanted]
    assert 0 < len(got) < len(plain)
