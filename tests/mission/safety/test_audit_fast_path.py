"""The audit's fast paths give the plain paths' report, to the last digit.

* ``audit_mission(fast=True)`` (numpy tlog reader, pair pruning) against ``fast=False`` (the
  pymavlink reader, every pair of tracks checked exactly) on a 12-vehicle formation with planted
  violations (a setpoint outside the fence and one below the band, a too-fast step, two vehicles
  steered into each other, a setpoint before any home, a partially ignored position, one in a
  frame the audit cannot place), GLOBAL_INT and relative-altitude setpoints, a vehicle whose
  heartbeat leaves OFFBOARD still armed, a vehicle with two tracks, a resumed mission (two tlogs),
  a MAVLink 1 frame (the fast reader hands that file to the plain one) and a truncated last record;
* the record walk (:func:`mission.safety.audit_fast.record_offsets`) against the plain splitter on
  damaged files, the batch CRC against pymavlink's, a bad setpoint CRC still refused;
* pair pruning really skips pairs, and still finds a planted separation break among them.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from pymavlink.dialects.v20 import common as mavlink

from formation.geodesy import enu_to_geodetic
from mission.link.tlog import tlog_record
from mission.safety import audit_fast, audit_read
from mission.safety.audit import AuditReport, _check_pair, _tracks, audit_mission
from mission.safety.audit_pairs import check_pairs_fast
from mission.safety.audit_read import AuditError, find_tlogs, read_vehicle_setpoints, read_vehicle_setpoints_fast

ORIGIN = (45.1885, 5.7245, 212.0)
T0 = 1.8e9
_PX4_OFFBOARD, _PX4_RTL = 6 << 16, (4 << 16) | (5 << 24)
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
_MASK = 0x1F8 | 0x800 | 0x400


def _plan(sysids):
    return {"origin": list(ORIGIN), "vehicles": [{"sysid": s} for s in sysids],
            "geofence": {"polygon_en_m": [[-60, -60], [60, -60], [60, 60], [-60, 60]], "min_alt_m": 2.0,
                         "max_alt_m": 40.0},
            "max_speed_m_s": 3.0, "min_separation_m": 1.5}


def _home(enu):
    lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), ORIGIN)
    return int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)), int(round(float(alt) * 1e3))


def _formation_positions(n, steps, rng):
    """``(steps, n, 3)`` ENU: a ring of radius 6 m drifting east at 1 m/s, jittered (10 Hz)."""
    angle = 2 * np.pi * np.arange(n) / n
    ring = np.stack([6 * np.cos(angle), 6 * np.sin(angle), 15 + 0.5 * (np.arange(n) % 3)], axis=1)
    drift = np.stack([0.1 * np.arange(steps), np.zeros(steps), np.zeros(steps)], axis=1)
    return ring[None] + drift[:, None] - np.array([20.0, 0, 0]) + rng.normal(0, 0.01, (steps, n, 3))


def _setpoint(gcs, sysid, home_enu, enu, kind, home_geo):
    """One setpoint frame of ``kind``: local (LOCAL_NED from the home), global, relative, partial, body."""
    if kind in ("global", "relative"):
        lat, lon, alt = enu_to_geodetic(np.asarray(enu, dtype=float), ORIGIN)
        alt = float(alt) - (home_geo[2] * 1e-3 if kind == "relative" else 0.0)
        return gcs.set_position_target_global_int_encode(0, sysid, 1, 5 if kind == "global" else 6, _MASK,
                                                         int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)),
                                                         alt, 0, 0, 0, 0, 0, 0, 0, 0)
    d = np.asarray(enu, dtype=float) - np.asarray(home_enu, dtype=float)
    mask = {"partial": 0x4 | 0x1F8, "velocity": 0x7 | 0x1C0 | 0xC00}.get(kind, _MASK)
    frame = 8 if kind == "body" else 1
    return gcs.set_position_target_local_ned_encode(0, sysid, 1, frame, mask, d[1], d[0], -d[2], 0, 0, 0, 0, 0, 0, 0, 0)


def _vehicle_records(sysid, track, plants, resumed_at=None):
    """The tlog records of one vehicle (a list of files' record lists)."""
    veh = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    home_enu = track[0] - np.array([0, 0, 15.0])
    home_geo = _home(home_enu)
    files, out = [], []
    if "setpoint_before_home" in plants:
        out.append(tlog_record(_setpoint(gcs, sysid, home_enu, track[0], "local", home_geo).pack(gcs), T0 - 0.5))
    out.append(tlog_record(veh.home_position_encode(*home_geo, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0).pack(veh), T0))
    home_enu = np.asarray(audit_read._local_to_mission([0, 0, 0], audit_read._local_origin(
        (home_geo[0] * 1e-7, home_geo[1] * 1e-7, home_geo[2] * 1e-3), (0, 0, 0)), ORIGIN), dtype=float)
    for k, enu in enumerate(track):
        t = T0 + 1.0 + 0.1 * k
        if resumed_at is not None and k == resumed_at:
            files.append(out)
            out = [tlog_record(veh.home_position_encode(*home_geo, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0).pack(veh), t - 0.05)]
        if "gap" in plants and 60 <= k < 90:
            continue                                     # two tracks: 3 s without setpoints
        if k % 10 == 0:
            mode = _PX4_RTL if ("leaves_offboard" in plants and k >= len(track) - 20) else _PX4_OFFBOARD
            out.append(tlog_record(veh.heartbeat_encode(2, 12, _ARMED, mode, 4).pack(veh), t - 0.02))
        if k % 25 == 0:   # HOME_POSITION at 0.4 Hz, as PX4 sends it
            out.append(tlog_record(veh.home_position_encode(*home_geo, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0).pack(veh), t - 0.03))
        kind = plants.get(k, "global" if k % 7 == 3 else "relative" if k % 11 == 5 else "local")
        out.append(tlog_record(_setpoint(gcs, sysid, home_enu, enu, kind, home_geo).pack(gcs), t))
    files.append(out)
    return files


def _write_mission(tmp_path, n=12, steps=200, variant="plain"):
    """A formation of ``n`` vehicles with planted violations; ``variant``: ``plain``, ``mavlink1``
    (one MAVLink 1 HEARTBEAT in vehicle 2's tlog), ``truncated`` (vehicle 3's last record cut)."""
    rng = np.random.default_rng(11)
    pos = _formation_positions(n, steps, rng)
    pos[50, 0] = (70.0, 0.0, 15.0)                       # outside the fence (and two too-fast steps)
    pos[120, 1, 2] = 1.0                                 # below the band
    pos[150:160, 3] = np.linspace(pos[150, 3], pos[150, 4], 10)   # vehicle 4 steered into 5
    plants = {1: {"setpoint_before_home": True, 30: "partial", 40: "body", 41: "velocity"},
              5: {"gap": True}, 6: {"leaves_offboard": True}}
    (tmp_path / "tlogs").mkdir()
    (tmp_path / "mission.jsonl").write_text(json.dumps({"t_s": T0, "type": "plan", "plan": _plan(range(1, n + 1))}) + "\n")
    for i in range(n):
        sysid = i + 1
        files = _vehicle_records(sysid, pos[:, i], plants.get(sysid, {}), resumed_at=100 if sysid == 7 else None)
        if variant == "mavlink1" and sysid == 2:
            v1 = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
            v1.WIRE_PROTOCOL_VERSION = "1.0"
            files[0].insert(5, tlog_record(v1.heartbeat_encode(2, 12, _ARMED, _PX4_OFFBOARD, 4).pack(v1, force_mavlink1=True),
                                           T0 + 1.33))
        for k, records in enumerate(files):
            data = b"".join(records)
            if variant == "truncated" and sysid == 3:
                data = data[:-7]
            name = f"vehicle-{sysid}.tlog" if k == 0 else f"vehicle-{sysid}-{k}.tlog"
            (tmp_path / "tlogs" / name).write_bytes(data)
    return tmp_path


@pytest.mark.parametrize("variant", ["plain", "mavlink1", "truncated"])
def test_fast_audit_gives_the_plain_report_with_planted_violations(tmp_path, variant):
    log_dir = _write_mission(tmp_path, variant=variant)
    fast, plain = audit_mission(log_dir), audit_mission(log_dir, fast=False)
    assert fast.to_dict() == plain.to_dict()
    assert fast.format_text() == plain.format_text()
    # the planted violations are there (both paths could not simply be blind)
    counts = fast.violation_counts
    assert counts.get("fence") == 1 and counts.get("altitude") == 1 and counts.get("no_home") == 1
    assert counts.get("frame") == 2 and counts.get("speed", 0) >= 2 and counts.get("separation", 0) >= 1
    assert {v.sysids for v in fast.violations if v.kind == "separation"} == {(4, 5)}
    assert fast.per_vehicle[5]["tracks"] == 2 and fast.setpoints_skipped == 1
    assert fast.setpoints_checked > 12 * 180 and fast.separation_instants_checked > 0


def test_fast_reader_equals_plain_per_vehicle(tmp_path):
    log_dir = _write_mission(tmp_path, variant="mavlink1")
    for sysid, paths in find_tlogs(log_dir).items():
        a = read_vehicle_setpoints(paths, sysid, ORIGIN)
        b = read_vehicle_setpoints_fast(paths, sysid, ORIGIN)
        assert a.t_s.tolist() == b.t_s.tolist() and a.enu_m.tolist() == b.enu_m.tolist()
        assert a.mode_t_s.tolist() == b.mode_t_s.tolist() and a.following.tolist() == b.following.tolist()
        assert (a.homes, a.skipped, a.problems) == (b.homes, b.skipped, b.problems)
    # vehicle 2's file held a MAVLink 1 frame: read by the plain reader; the others by the fast one
    data = (log_dir / "tlogs" / "vehicle-2.tlog").read_bytes()
    assert audit_fast.read_tlog_table(data, 2, 255) is None
    assert audit_fast.read_tlog_table((log_dir / "tlogs" / "vehicle-4.tlog").read_bytes(), 4, 255) is not None


def test_bad_setpoint_crc_is_still_refused_by_the_fast_reader(tmp_path):
    log_dir = _write_mission(tmp_path, n=6)
    path = log_dir / "tlogs" / "vehicle-2.tlog"
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x55                                     # the last record: a setpoint's CRC
    path.write_bytes(bytes(data))
    assert audit_fast.read_tlog_table(bytes(data), 2, 255) is None
    with pytest.raises(AuditError, match="cannot be decoded"):
        read_vehicle_setpoints_fast([path], 2, ORIGIN)


@pytest.mark.parametrize("keep", [0, 9, 10, 30])
def test_empty_and_short_tlogs_read_as_the_plain_reader_reads_them(tmp_path, keep):
    log_dir = _write_mission(tmp_path, n=6)
    path = log_dir / "tlogs" / "vehicle-2.tlog"
    path.write_bytes(path.read_bytes()[:keep])
    a, b = read_vehicle_setpoints([path], 2, ORIGIN), read_vehicle_setpoints_fast([path], 2, ORIGIN)
    assert (a.t_s.tolist(), a.mode_t_s.tolist(), a.homes, a.problems) == (b.t_s.tolist(), b.mode_t_s.tolist(), b.homes,
                                                                          b.problems)
    assert audit_mission(log_dir).to_dict() == audit_mission(log_dir, fast=False).to_dict()


def _plain_split(data, tmp_path):
    path = tmp_path / "x.tlog"
    path.write_bytes(data)
    try:
        return [t for t, _ in audit_read._split_records(path)]
    except AuditError:
        return "error"


@settings(max_examples=60, deadline=None)
@given(cut=st.integers(0, 60), junk_at=st.one_of(st.none(), st.integers(0, 2000)), junk=st.integers(0, 255))
def test_record_walk_equals_the_plain_splitter_on_damaged_files(tmp_path_factory, cut, junk_at, junk):
    tmp_path = tmp_path_factory.mktemp("walk")
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    records = []
    for k in range(40):
        records.append(tlog_record(gcs.set_position_target_local_ned_encode(k, 1, 1, 1, _MASK, k, 0, -10, 0, 0, 0, 0, 0, 0,
                                                                           0, 0).pack(gcs), T0 + k))
        records.append(tlog_record(veh.heartbeat_encode(2, 12, _ARMED, _PX4_OFFBOARD, 4).pack(veh), T0 + k + 0.5))
    data = bytearray(b"".join(records))
    if junk_at is not None:
        data[min(junk_at, len(data) - 1)] = junk
    data = bytes(data[:len(data) - cut])
    offsets = audit_fast.record_offsets(np.frombuffer(data, dtype=np.uint8))
    want = _plain_split(data, tmp_path)
    if offsets is None:
        assert want == "error"
    else:
        got = [int.from_bytes(data[o:o + 8], "big") * 1e-6 for o in offsets]
        assert got == want


def _frames_of(kind, rng, count=60):
    """Frames of one message with random fields, some zero at the end (MAVLink 2 truncates those)."""
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    frames = []
    for k in range(count):
        tail = 0 if k % 3 == 0 else 1
        if kind == "setpoint":
            msg = gcs.set_position_target_local_ned_encode(k, tail * 3, tail, tail * 1, int(rng.integers(0, 4096)),
                                                           *rng.normal(0, 50, 3), 0, 0, 0, 0, 0, 0, 0, 0)
        elif kind == "home":
            msg = gcs.home_position_encode(*(int(v) for v in rng.integers(-2 ** 31, 2 ** 31, 3)), *rng.normal(0, 9, 3),
                                           [1, 0, 0, 0], 0, 0, 0, int(rng.integers(0, 2 ** 40)) * tail)
        else:
            msg = gcs.heartbeat_encode(2, 12, int(rng.integers(0, 256)), int(rng.integers(0, 2 ** 32)), 4)
        frames.append(msg.pack(gcs))
    return frames


@pytest.mark.parametrize("kind, cls", [("setpoint", mavlink.MAVLink_set_position_target_local_ned_message),
                                       ("home", mavlink.MAVLink_home_position_message),
                                       ("heartbeat", mavlink.MAVLink_heartbeat_message)])
def test_batch_crc_and_decode_equal_pymavlink(kind, cls):
    frames = _frames_of(kind, np.random.default_rng(3))
    frames[7] = frames[7][:-1] + bytes([frames[7][-1] ^ 1])          # a bad CRC
    assert len({len(f) for f in frames}) > 1 or kind == "heartbeat"   # truncated payloads among them
    buf = np.frombuffer(b"".join(frames), dtype=np.uint8)
    at = np.cumsum([0] + [len(f) for f in frames[:-1]])
    ok = audit_fast.v2_frames_valid(buf, at, cls.crc_extra)
    assert ok.tolist() == [k != 7 for k in range(len(frames))]
    fields = audit_fast.decode_payloads(buf, at, cls)
    parser = mavlink.MAVLink(None)
    for k, frame in enumerate(frames):
        if k == 7:
            continue
        msg = parser.decode(bytearray(frame))
        for name in cls.ordered_fieldnames:
            got, want = fields[name][k], getattr(msg, name)
            assert np.asarray(got).tolist() == (list(want) if isinstance(want, (list, tuple)) else want), name


def test_pair_pruning_skips_far_pairs_and_keeps_a_planted_break(tmp_path):
    log_dir = _write_mission(tmp_path, n=12, steps=200)
    plan = audit_read.load_plan_limits(log_dir)
    vehicles = []
    for sysid, paths in sorted(find_tlogs(log_dir).items()):
        sp = read_vehicle_setpoints_fast(paths, sysid, plan["origin"])
        vehicles.append((sp, _tracks(sp.t_s, 1.0)))
    fast, plain = AuditReport(log_dir=str(log_dir), tlogs=[]), AuditReport(log_dir=str(log_dir), tlogs=[])
    exact = check_pairs_fast(fast, vehicles, 1.5, 0.01, 1.0, 0.01)
    pairs = 0
    for i, (a, tracks_a) in enumerate(vehicles):
        for b, tracks_b in vehicles[i + 1:]:
            _check_pair(plain, a, b, tracks_a, tracks_b, 1.5, 0.01, 1.0, burst_s=0.01)
            pairs += len(tracks_a) * len(tracks_b)
    assert exact < pairs / 2, (exact, pairs)          # most pairs of a 6 m ring are cleared by the bound
    assert fast.to_dict() == plain.to_dict()
    assert fast.violation_counts.get("separation", 0) > 0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), shared=st.booleans(), size=st.integers(1, 300))
def test_batch_instant_counts_equal_the_exact_checks_instants(seed, shared, size):
    """The skipped pairs' instants, counted all at once from the bit sets, are ``len(tq)`` of the exact
    check: the distinct stamps of either vehicle in ``[lo, hi]``, and ``hi``. Stamps shared by all
    vehicles (the lock-step clock's ticks) or each its own (real time), spans on word edges."""
    from mission.safety.audit_pairs import _count_instants_many, _instant_bits

    rng = np.random.default_rng(seed)
    ticks = np.round(np.sort(rng.uniform(0.0, 50.0, size)), 3)
    vehicles = []
    for _ in range(4):
        t_s = np.unique(rng.choice(ticks, size=rng.integers(1, size + 1)) if shared
                        else np.round(rng.uniform(0.0, 50.0, rng.integers(1, size + 1)), 4))
        vehicles.append((audit_read.VehicleSetpoints(1, t_s, np.zeros((len(t_s), 3))), None))
    stamps, bits = _instant_bits(vehicles)
    spans = []
    for _ in range(40):
        i, j = sorted(rng.choice(4, 2, replace=False))
        a, b = vehicles[i][0].t_s, vehicles[j][0].t_s
        lo = max(a[0], b[0])
        edge = stamps[min(len(stamps) - 1, 64 * int(rng.integers(0, len(stamps) // 64 + 1)))]
        hi = max(lo, rng.choice([edge, lo + rng.uniform(0.0, 50.0), float(rng.choice(np.concatenate([a, b])))]))
        spans.append((int(i), int(j), float(lo), float(hi)))
    got = _count_instants_many(stamps, np.stack(bits), spans)
    for (i, j, lo, hi), n in zip(spans, got):
        tq = np.concatenate([vehicles[i][0].t_s, vehicles[j][0].t_s, [lo, hi]])
        assert n == len(np.unique(tq[(tq >= lo) & (tq <= hi)])), (i, j, lo, hi)


def test_track_bounds_are_the_window_box_distances(tmp_path):
    """The pair bounds computed a slice of later tracks at a time equal, per pair of tracks, the
    smallest box distance (:func:`_box_distance`) over the windows both are commanded in; and no
    bound exceeds the pair's true smallest distance (a vehicle with two tracks included)."""
    from mission.safety.audit_pairs import _box_distance, _grid, _pair_items, _span_bound, track_pair

    log_dir = _write_mission(tmp_path, n=12, steps=200)
    plan = audit_read.load_plan_limits(log_dir)
    vehicles = []
    for sysid, paths in sorted(find_tlogs(log_dir).items()):
        sp = read_vehicle_setpoints_fast(paths, sysid, plan["origin"])
        vehicles.append((sp, _tracks(sp.t_s, 1.0)))
    edges = _grid(vehicles, 1.0, 0.01, 1.0)
    items, boxes = _pair_items(vehicles, 1.0, 0.01, edges)
    assert len(items) == sum(len(ta) * len(tb) for k, (_, ta) in enumerate(vehicles) for _, tb in vehicles[k + 1:])
    for i, j, ra, rb, lo, hi, bound in items:
        box_a, box_b = boxes[i][vehicles[i][1].index(ra)], boxes[j][vehicles[j][1].index(rb)]
        want = _span_bound(_box_distance(box_a, box_b)[None], edges, np.array([lo]), np.array([hi + 0.01]))[0]
        assert bound == want
        exact = track_pair(vehicles[i][0], vehicles[j][0], ra, rb, 1.5, 0.01, 1.0, 0.01)
        if exact is not None:
            assert bound <= exact[1] + 1e-9


def _fence_reference(sp, plan, tol_m):
    """The fence check as it was (every point's boundary distance): (smallest margin, outside indices)."""
    from mission.safety.geometry import boundary_distance, point_in_polygon

    poly, p = plan["polygon_en_m"], sp.enu_m
    inside = point_in_polygon(p[:, :2], poly, tol_m)
    margin_h = boundary_distance(p[:, :2], poly)
    margin_h = np.where(point_in_polygon(p[:, :2], poly, 0.0), margin_h, -margin_h)
    margin = np.minimum(margin_h, np.minimum(p[:, 2] - plan["min_alt_m"], plan["max_alt_m"] - p[:, 2]))
    return float(margin.min()), np.flatnonzero(~inside).tolist(), -margin_h[~inside]


@pytest.mark.parametrize("tol_m", [0.01, 0.0])
@pytest.mark.parametrize("low_m", [2.0, 19.0, 29.5])
def test_fence_margins_computed_near_the_boundary_only_equal_every_points(tol_m, low_m):
    """The fence check computes the boundary distance only of points outside or near an edge's line
    (within the smallest vertical margin): the same smallest margin, the same violations and values
    as every point's distance, on an L-shaped (non-convex) fence with points inside, outside, on
    and just off its edges, and a band that puts the vertical margin below and above them."""
    from mission.safety.audit import _check_fence

    rng = np.random.default_rng(7)
    poly = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 40.0], [40.0, 40.0], [40.0, 100.0], [0.0, 100.0]])
    plan = {"polygon_en_m": poly, "min_alt_m": low_m, "max_alt_m": 80.0}
    edge_points = np.concatenate([poly + rng.normal(0.0, s, poly.shape) for s in (0.0, 0.003, 0.02, 0.5)])
    xy = np.concatenate([rng.uniform(-5.0, 105.0, (3000, 2)), edge_points, [[20.0, 20.0], [70.0, 20.0]]])
    enu = np.column_stack([xy, rng.uniform(20.0, 40.0, len(xy))])
    sp = audit_read.VehicleSetpoints(3, np.arange(len(xy), dtype=float), enu)
    report = AuditReport(log_dir="x", tlogs=[])
    _check_fence(report, sp, plan, tol_m)
    want_margin, want_out, want_values = _fence_reference(sp, plan, tol_m)
    assert report.min_fence_margin_m == want_margin
    fence = [v for v in report.violations if v.kind == "fence"]          # the first 200 are listed
    assert report.violation_counts["fence"] == len(want_out) > len(fence) > 100
    assert [int(v.t_s) for v in fence] == want_out[:len(fence)]
    assert [v.value for v in fence] == want_values[:len(fence)].tolist()


def test_fence_margin_of_an_interior_point_nearer_the_fence_than_the_band():
    """Every point well inside, the nearest 11 m from an edge and the band 12 m away at the closest:
    the smallest margin is that point's horizontal one (found although no point is outside)."""
    from mission.safety.audit import _check_fence

    rng = np.random.default_rng(3)
    poly = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 40.0], [40.0, 40.0], [40.0, 100.0], [0.0, 100.0]])
    plan = {"polygon_en_m": poly, "min_alt_m": 2.0, "max_alt_m": 80.0}
    xy = np.concatenate([rng.uniform(14.0, 26.0, (500, 2)), [[11.0, 30.0]]])
    enu = np.column_stack([xy, rng.uniform(14.0, 30.0, len(xy))])
    sp = audit_read.VehicleSetpoints(3, np.arange(len(xy), dtype=float), enu)
    report = AuditReport(log_dir="x", tlogs=[])
    _check_fence(report, sp, plan, 0.01)
    assert report.min_fence_margin_m == _fence_reference(sp, plan, 0.01)[0] == pytest.approx(11.0)
    assert not report.violations


def test_runs_of_identical_setpoint_rows_are_converted_once_with_the_same_result():
    """A held target resent at the stream's rate is converted once per run of identical rows: the
    same mission ENU, to the bit, as converting each row alone (LOCAL_NED in two home frames and
    geodetic rows; a 0.0 next to a -0.0 is not the same row)."""
    from mission.safety.audit_read import _local_origin, _rows_to_enu

    rng = np.random.default_rng(5)
    origins = {_local_origin((45.1886, 5.7246, 212.5), (1.0, -2.0, -0.3)): 0,
               _local_origin((45.1884, 5.7243, 211.0), (0.0, 0.0, 0.0)): 1}
    distinct = np.column_stack([rng.integers(-1, 2, 40).astype(float), rng.uniform(-50.0, 50.0, (40, 3))])
    distinct[distinct[:, 0] < 0, 1:] = [45.1885, 5.7245, 230.0] + rng.uniform(-1e-4, 1e-4, (int((distinct[:, 0] < 0).sum()), 3))
    distinct[5, 1:], distinct[6, 1:], distinct[6, 0] = (0.0, 1.0, -2.0), (-0.0, 1.0, -2.0), distinct[5, 0]
    data = np.repeat(distinct, rng.integers(1, 12, len(distinct)), axis=0)
    got = _rows_to_enu(data, origins, ORIGIN)
    alone = np.concatenate([_rows_to_enu(data[k:k + 1], origins, ORIGIN) for k in range(len(data))])
    assert got.tobytes() == alone.tobytes() and len(data) > 2 * len(distinct)
