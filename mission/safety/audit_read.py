"""Reading a flown mission for :mod:`mission.safety.audit`: the plan's safety limits from
``mission.jsonl`` and, from each vehicle's ``.tlog``, the position setpoints the ground station
sent, placed in the mission ENU frame with :mod:`formation.geodesy` only (independent of the
code that produced them).

A tlog record is an 8-byte big-endian microsecond stamp then one MAVLink frame
(:mod:`mission.link.tlog`); records are split here (a truncated last record, as a crash leaves, is
dropped; a record that is not a MAVLink frame is an error) and only the frames the audit needs
are decoded, with pymavlink (a frame that fails its CRC is an error, never skipped silently).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from formation.geodesy import enu_to_geodetic, geodetic_to_enu, ned_to_enu
from wire.fast_decode import decode_single_frame
from mission.safety import audit_fast

__all__ = ["AuditError", "AuditViolation", "VehicleSetpoints", "load_plan_limits", "find_tlogs",
           "read_vehicle_setpoints", "read_vehicle_setpoints_fast"]

#: the ground station's quarantine log (``mission.link.tlog.QUARANTINE_NAME``; spelled out here:
#: the audit reads the files independently of the code that wrote them)
_QUARANTINE_STEM = "quarantine"
_PLAN_LINE = ("plan", "\\u")           # a plan record's line holds its type's text, or a JSON escape
_POS_IGNORE = 0x7                      # type_mask bits 0..2: ignore x, y, z
_FRAME_LOCAL_NED = 1
_FRAME_GLOBAL_INT = 5
_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
_SP_LOCAL = "SET_POSITION_TARGET_LOCAL_NED"
_SP_GLOBAL = "SET_POSITION_TARGET_GLOBAL_INT"


_ARMED = 128                      # MAV_MODE_FLAG_SAFETY_ARMED
_AUTOPILOT_PX4 = 12               # MAV_AUTOPILOT_PX4
_PX4_MAIN_OFFBOARD = 6            # PX4_CUSTOM_MAIN_MODE_OFFBOARD
_ARDUPILOT_GUIDED = frozenset({4, 20})  # COPTER_MODE_GUIDED, COPTER_MODE_GUIDED_NOGPS


class AuditError(ValueError):
    """The log directory cannot be audited (missing, no tlogs, unreadable log or plan)."""


@dataclass(frozen=True)
class AuditViolation:
    """One broken rule.

    Attributes
    ----------
    kind : str
        ``fence`` (outside the polygon), ``altitude`` (outside the band), ``speed``,
        ``separation``, ``frame`` (a setpoint the audit cannot place), ``no_home``.
    t_s : float
        Tlog stamp (mission clock, Unix-epoch seconds).
    sysids : tuple of int
        The vehicle, or the pair.
    value : float
        The offending figure (metres outside, m/s, metres apart).
    limit : float
        The limit it was compared with (tolerance excluded).
    detail : str
        Human-readable description.
    """

    kind: str
    t_s: float
    sysids: tuple
    value: float
    limit: float
    detail: str


@dataclass
class VehicleSetpoints:
    """Position setpoints the ground station sent to one vehicle, in the mission ENU frame.

    Attributes
    ----------
    sysid : int
    t_s : numpy.ndarray, shape (K,)
        Tlog stamps, non-decreasing.
    enu_m : numpy.ndarray, shape (K, 3)
    skipped : int
        Setpoints that command no position (velocity/acceleration only).
    problems : list of AuditViolation
        ``frame`` and ``no_home`` findings.
    homes : int
        HOME_POSITION frames received.
    mode_t_s : numpy.ndarray, shape (M,)
        Stamps of the vehicle's own HEARTBEATs.
    following : numpy.ndarray of bool, shape (M,)
        Whether each of them says the vehicle flies the setpoints (:func:`following_setpoints`).
    """

    sysid: int
    t_s: np.ndarray
    enu_m: np.ndarray
    skipped: int = 0
    problems: list = field(default_factory=list)
    homes: int = 0
    mode_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    following: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))

    def commanded_until(self, t_last_s: float, stale_after_s: float) -> float:
        """When the setpoint sent at ``t_last_s`` (the last of a track) stops counting.

        ``stale_after_s`` later (PX4 leaves offboard after about a second without setpoints),
        or earlier: when the vehicle's own HEARTBEAT says it no longer flies setpoints (a
        failsafe, RTL, LAND): then it is not holding that setpoint any more. If its last
        HEARTBEAT at or before ``t_last_s`` already said so, at ``t_last_s``.
        """
        end = t_last_s + stale_after_s
        if not len(self.mode_t_s):
            return end
        k = int(np.searchsorted(self.mode_t_s, t_last_s, side="right"))
        if k > 0 and not self.following[k - 1]:
            return t_last_s
        released = np.flatnonzero(~self.following[k:])
        return end if not len(released) else min(end, float(self.mode_t_s[k + released[0]]))


def load_plan_limits(log_dir: Path) -> dict:
    """The safety limits of the first (non dry-run) ``plan`` record of ``log_dir/mission.jsonl``.

    Returns
    -------
    dict
        ``origin``, ``polygon_en_m`` (K, 2), ``min_alt_m``, ``max_alt_m``, ``max_speed_m_s``,
        ``min_separation_m``, ``sysids`` (the planned vehicles; None in an old log), ``missions``
        (plan records not written by a resume: more than one is several missions in one
        directory) and ``plan_sysid_sets`` (the distinct vehicle sets of all plan records).

    Raises
    ------
    AuditError
        No log, no plan record, or a plan record without these fields.
    """
    from mission.telemetry.mission_log import iter_mission_log

    path = log_dir / "mission.jsonl"
    if not path.is_file():
        raise AuditError(f"{log_dir}: no mission log (mission.jsonl) to take the plan from")
    try:
        # only lines that can hold a plan record are parsed (a long mission's log is mostly others)
        plans = [r for r in iter_mission_log(path, prefilter=_PLAN_LINE)
                 if r.get("type") == "plan" and not r.get("dry_run")]
    except OSError as exc:
        raise AuditError(f"{path}: cannot be read: {exc}") from None
    if not plans:
        raise AuditError(f"{path}: no plan record (was the mission flown?)")
    out = _limits_of(path, plans[0].get("plan"))
    # a resume appends its own plan record (``resumed``: true); any other is another mission
    out["missions"] = sum(1 for r in plans if not r.get("resumed"))
    out["plan_sysid_sets"] = sorted({s for s in (_plan_sysids(r.get("plan")) for r in plans) if s is not None})
    return out


def _plan_sysids(plan) -> tuple | None:
    """The sorted system ids of a ``plan`` record's vehicles (None: no or malformed vehicle list)."""
    try:
        return tuple(sorted(int(v["sysid"]) for v in plan["vehicles"]))
    except (KeyError, TypeError, ValueError):
        return None


def _limits_of(path: Path, plan) -> dict:
    """The safety limits of one ``plan`` record (see :func:`load_plan_limits`)."""
    try:
        gf = plan["geofence"]
        out = {
            "origin": tuple(float(v) for v in plan["origin"]),
            "polygon_en_m": np.asarray(gf["polygon_en_m"], dtype=float).reshape(-1, 2),
            "min_alt_m": float(gf["min_alt_m"]),
            "max_alt_m": float(gf["max_alt_m"]),
            "max_speed_m_s": float(plan["max_speed_m_s"]),
            "min_separation_m": float(plan["min_separation_m"]),
            # the plan's vehicles: only their tlogs are audited (None: an old log without them)
            "sysids": (frozenset(int(v["sysid"]) for v in plan["vehicles"]) if "vehicles" in plan else None),
        }
    except (KeyError, TypeError, ValueError) as exc:
        raise AuditError(f"{path}: the plan record lacks the safety limits: {type(exc).__name__}: {exc}") from None
    if len(out["origin"]) != 3 or len(out["polygon_en_m"]) < 3:
        raise AuditError(f"{path}: the plan record has no usable origin or geofence polygon")
    return out


def _local_origin(home_geo, home_local_ned):
    """The LOCAL_NED origin: the home moved back by the home's local coordinates."""
    lat, lon, alt = enu_to_geodetic(-ned_to_enu(np.asarray(home_local_ned, dtype=float)), home_geo)
    return float(lat), float(lon), float(alt)


def _local_to_mission(ned, local_origin, mission_origin) -> np.ndarray:
    lat, lon, alt = enu_to_geodetic(ned_to_enu(np.asarray(ned, dtype=float)), local_origin)
    return geodetic_to_enu(lat, lon, alt, mission_origin)


def _split_records(path: Path, wanted=None):
    """``(t_s, frame)`` records; a truncated last record (a crash while writing) is dropped.

    ``wanted``: a set of message ids; the records of other messages are checked and skipped
    (not copied out), the fast path of a reader that decodes a few message types.

    Raises
    ------
    AuditError
        Unreadable file, or a record that is not a MAVLink frame.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise AuditError(f"{path}: cannot be read: {exc}") from None
    out, i, n = [], 0, len(data)
    while i + 10 <= n:
        magic, length = data[i + 8], data[i + 9]
        if magic == 0xFD:
            size = 12 + length + (13 if i + 10 < n and data[i + 10] & 0x01 else 0)
        elif magic == 0xFE:
            size = 8 + length
        else:
            raise AuditError(f"{path}: record at byte {i} starts with 0x{magic:02X}, not a MAVLink frame "
                             f"(not a tlog, or corrupt)")
        if i + 8 + size > n:
            break
        if wanted is None or (data[i + 13] if magic == 0xFE else
                              data[i + 15] | data[i + 16] << 8 | data[i + 17] << 16) in wanted:
            out.append((int.from_bytes(data[i:i + 8], "big") * 1e-6, data[i + 8:i + 8 + size]))
        i += 8 + size
    return out


def following_setpoints(heartbeat) -> bool:
    """Whether a vehicle's HEARTBEAT says it flies the ground station's setpoints: armed, and in
    PX4's OFFBOARD (main mode 6) or ArduPilot's GUIDED (custom mode 4) or GUIDED_NOGPS (20)."""
    if not heartbeat.base_mode & _ARMED:
        return False
    if heartbeat.autopilot == _AUTOPILOT_PX4:
        return (heartbeat.custom_mode >> 16) & 0xFF == _PX4_MAIN_OFFBOARD
    return heartbeat.custom_mode in _ARDUPILOT_GUIDED


def _decode_frame(mav, frame, path, t_s: float, msgid: int):
    """The message of one tlog frame (``mav``: a pymavlink parser of the ``common`` dialect).

    A valid MAVLink 2 frame of a fixed-layout message is decoded with ``struct`` by
    :func:`~wire.fast_decode.decode_single_frame` (the same fields as pymavlink's decode:
    ``tests/mission/safety/test_audit_fast_read.py``); anything else (MAVLink 1, bad CRC, ...) by pymavlink.

    Raises
    ------
    AuditError
        pymavlink cannot decode the frame.
    """
    msg = decode_single_frame(frame)
    if msg is not None:
        return msg
    try:
        return mav.decode(bytearray(frame))
    except Exception as exc:  # noqa: BLE001 - pymavlink raises MAVError, struct.error...
        raise AuditError(f"{path}: a frame stamped {t_s:.3f} (message id {msgid}) cannot be decoded: "
                         f"{exc}") from None


def _read_tlog(path, sysid, gcs_sysid):
    """Decode the setpoints, HOME_POSITION and the vehicle's own HEARTBEAT frames of one tlog."""
    from pymavlink.dialects.v20 import common as mavlink

    wanted = {mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
              mavlink.MAVLINK_MSG_ID_HOME_POSITION, mavlink.MAVLINK_MSG_ID_HEARTBEAT}
    mav = mavlink.MAVLink(None)
    events = []
    for t_s, frame in _split_records(path, wanted):
        msgid = frame[5] if frame[0] == 0xFE else int.from_bytes(frame[7:10], "little")
        msg = _decode_frame(mav, frame, path, t_s, msgid)
        src = msg.get_srcSystem()
        if msgid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            if src == sysid and msg.get_srcComponent() == 1:
                events.append((t_s, "mode", following_setpoints(msg)))
        elif msgid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            if src == sysid:
                events.append((t_s, "home", msg))
        elif src == gcs_sysid and msg.target_system in (sysid, 0):
            events.append((t_s, "sp", msg))
    return events


def read_vehicle_setpoints(paths, sysid: int, mission_origin, gcs_sysid: int = 255) -> VehicleSetpoints:
    """Decode the position setpoints sent to ``sysid`` in its tlog(s), in the mission ENU frame.

    Parameters
    ----------
    paths : list of path-like
        The vehicle's tlog files (several after a resume), read in time order.
    sysid : int
        The vehicle.
    mission_origin : tuple of float
        ``(lat_deg, lon_deg, alt_m)`` of the mission frame.
    gcs_sysid : int
        System id of the ground station (whose frames are the ones sent).

    Raises
    ------
    AuditError
        A file cannot be read or decoded.
    """
    events = []          # (t_s, kind, message)
    for path in paths:
        events.extend(_read_tlog(path, sysid, gcs_sysid))
    events.sort(key=lambda e: e[0])
    out = VehicleSetpoints(sysid, np.empty(0), np.empty((0, 3)))
    t_list, rows = [], []        # rows: (group, x, y, z); group -1 = geodetic
    origins: dict[tuple, int] = {}
    home = None
    group = None
    modes = [(t_s, msg) for t_s, kind, msg in events if kind == "mode"]
    out.mode_t_s = np.array([t for t, _ in modes], dtype=float)
    out.following = np.array([f for _, f in modes], dtype=bool)
    for t_s, kind, msg in events:
        if kind == "mode":
            continue
        if kind == "home":
            out.homes += 1
            home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
            origin = _local_origin(home, (msg.x, msg.y, msg.z))
            group = origins.setdefault(origin, len(origins))
            continue
        row = _setpoint_row(msg, t_s, sysid, home, group, out)
        if row is not None:
            t_list.append(t_s)
            rows.append(row)
    if not t_list:
        return out
    out.t_s = np.asarray(t_list, dtype=float)
    out.enu_m = _rows_to_enu(np.asarray(rows, dtype=float), origins, mission_origin)
    return out


def _rows_to_enu(data: np.ndarray, origins: dict, mission_origin) -> np.ndarray:
    """Mission ENU of setpoint rows ``(group, x, y, z)``: LOCAL_NED in the frame of ``origins``'
    group, or group -1 and geodetic. A run of rows identical to the bit (a held target the
    streamer resends at its rate: about 4 rows in 5) is converted once."""
    data = np.ascontiguousarray(data, dtype=float)
    if len(data) > 1:
        word = data.view(np.uint64)
        new = np.concatenate([[True], np.any(word[1:] != word[:-1], axis=1)])
        if not new.all():
            return _rows_to_enu(data[new], origins, mission_origin)[np.cumsum(new) - 1]
    enu = np.empty((len(data), 3))
    geo = data[:, 0] < 0
    if np.any(geo):
        enu[geo] = geodetic_to_enu(data[geo, 1], data[geo, 2], data[geo, 3], mission_origin)
    for origin, g in origins.items():
        sel = data[:, 0] == g
        if np.any(sel):
            enu[sel] = _local_to_mission(data[sel, 1:], origin, mission_origin)
    return enu


def _setpoint_row(msg, t_s, sysid, home, group, out):
    """``(group, x, y, z)`` of one setpoint (LOCAL_NED in ``group``'s frame, or -1 and geodetic),
    or None after counting it as skipped or as a problem."""
    ignored = msg.type_mask & _POS_IGNORE
    if ignored == _POS_IGNORE:
        out.skipped += 1
        return None
    frame = msg.coordinate_frame
    name = msg.get_type()
    if ignored:
        out.problems.append(AuditViolation("frame", t_s, (sysid,), float(msg.type_mask), 0.0,
                                           f"{name} ignores only some position axes (type_mask 0x{msg.type_mask:X})"))
        return None
    if name == _SP_LOCAL and frame == _FRAME_LOCAL_NED:
        if group is None:
            out.problems.append(AuditViolation("no_home", t_s, (sysid,), math.nan, math.nan,
                                               "LOCAL_NED setpoint sent before any HOME_POSITION was received"))
            return None
        return (group, msg.x, msg.y, msg.z)
    if name == _SP_GLOBAL and frame in (_FRAME_GLOBAL_INT, _FRAME_GLOBAL_RELATIVE_ALT_INT):
        alt = float(msg.alt)
        if frame == _FRAME_GLOBAL_RELATIVE_ALT_INT:
            if home is None:
                out.problems.append(AuditViolation("no_home", t_s, (sysid,), math.nan, math.nan,
                                                   "relative-altitude setpoint sent before any HOME_POSITION"))
                return None
            alt += home[2]
        return (-1, msg.lat_int * 1e-7, msg.lon_int * 1e-7, alt)
    out.problems.append(AuditViolation("frame", t_s, (sysid,), float(frame), 0.0,
                                       f"{name} in coordinate frame {frame}, which the audit cannot place"))
    return None


def read_vehicle_setpoints_fast(paths, sysid: int, mission_origin, gcs_sysid: int = 255) -> VehicleSetpoints:
    """:func:`read_vehicle_setpoints` on whole arrays (:mod:`mission.safety.audit_fast`): the same
    result, each home's LOCAL_NED origin computed once per distinct HOME_POSITION; a file the fast
    path leaves to pymavlink (see :func:`~mission.safety.audit_fast.read_tlog_table`) is read by
    the plain reader. Same results: ``tests/mission/safety/test_audit_fast_path.py``."""
    tables = []
    for path in paths:
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise AuditError(f"{path}: cannot be read: {exc}") from None
        table = audit_fast.read_tlog_table(data, sysid, gcs_sysid)
        tables.append(table if table is not None else audit_fast.table_from_events(_read_tlog(path, sysid, gcs_sysid)))
    out = VehicleSetpoints(sysid, np.empty(0), np.empty((0, 3)))
    modes, mode_file = audit_fast.merged_columns(tables, "mode")
    mode_order = np.lexsort((modes["seq"], mode_file, modes["t_s"]))
    out.mode_t_s = modes["t_s"][mode_order].astype(float)
    out.following = modes["following"][mode_order].astype(bool)
    homes, sps, kind, row = audit_fast.event_order(tables)
    out.homes = len(homes["seq"])
    home_group, origins = _home_groups(homes, kind, row)
    is_home = kind == 1
    last = np.maximum.accumulate(np.where(is_home, np.arange(len(kind)), -1)) if len(kind) else kind
    at_sp = ~is_home
    sp_row = row[at_sp]
    home_row = np.where(last[at_sp] >= 0, row[np.maximum(last[at_sp], 0)], -1)
    cols = {k: v[sp_row] for k, v in sps.items()}
    data, keep = _setpoint_rows_fast(cols, home_row, home_group, homes, sysid, out)
    if not len(data):
        return out
    out.t_s = cols["t_s"][keep].astype(float)
    out.enu_m = _rows_to_enu(data, origins, mission_origin)
    return out


def _home_groups(homes: dict, kind: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, dict]:
    """Each HOME_POSITION row's LOCAL_NED origin group (numbered in the order the plain reader
    meets them) and ``origin -> group``; :func:`_local_origin` once per distinct frame content."""
    group = np.full(len(homes["seq"]), -1, dtype=np.int64)
    origins: dict[tuple, int] = {}
    if not len(group):
        return group, origins
    in_order = row[kind == 1]
    values = np.column_stack([homes[k].astype(np.float64) for k in ("latitude", "longitude", "altitude",
                                                                    "x", "y", "z")])[in_order]
    keys = np.ascontiguousarray(values).view(np.dtype((np.void, values.shape[1] * 8))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    unique_group = np.empty(len(first), dtype=np.int64)
    for u in np.argsort(first, kind="stable"):
        r = in_order[first[u]]
        home = (int(homes["latitude"][r]) * 1e-7, int(homes["longitude"][r]) * 1e-7, int(homes["altitude"][r]) * 1e-3)
        local = (float(homes["x"][r]), float(homes["y"][r]), float(homes["z"][r]))
        unique_group[u] = origins.setdefault(_local_origin(home, local), len(origins))
    group[in_order] = unique_group[inverse.ravel()]
    return group, origins


def _setpoint_rows_fast(cols: dict, home_row: np.ndarray, home_group: np.ndarray, homes: dict, sysid: int,
                        out: VehicleSetpoints) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_setpoint_row` of every setpoint at once: the ``(group, x, y, z)`` rows and which
    setpoints they are; skipped ones counted and problems added to ``out`` in the plain order."""
    mask, frame, msgid = cols["type_mask"], cols["frame"], cols["msgid"]
    ignored = mask & _POS_IGNORE
    skipped = ignored == _POS_IGNORE
    partial = (ignored != 0) & ~skipped
    placed = ~skipped & ~partial
    has_home = home_row >= 0
    local = placed & (msgid == _MSG_LOCAL) & (frame == _FRAME_LOCAL_NED)
    glob = placed & (msgid == _MSG_GLOBAL) & np.isin(frame, (_FRAME_GLOBAL_INT, _FRAME_GLOBAL_RELATIVE_ALT_INT))
    rel = glob & (frame == _FRAME_GLOBAL_RELATIVE_ALT_INT)
    keep = (local & has_home) | (glob & (~rel | has_home))
    out.skipped += int(skipped.sum())
    for i in np.flatnonzero((placed & ~keep) | partial):
        out.problems.append(_fast_problem(cols, i, bool(partial[i]), bool(local[i] or rel[i]), bool(local[i]), sysid))
    home_alt = np.where(has_home, homes["altitude"][np.maximum(home_row, 0)].astype(np.float64) * 1e-3, 0.0) \
        if len(homes["altitude"]) else np.zeros(len(mask))
    group = np.where(local, home_group[np.maximum(home_row, 0)] if len(home_group) else -1, -1)
    scale = np.where(local, 1.0, 1e-7)
    alt = np.where(rel, cols["c"] + home_alt, cols["c"])
    data = np.column_stack([group.astype(np.float64), np.where(local, cols["a"], cols["a"] * scale),
                            np.where(local, cols["b"], cols["b"] * scale), alt])[keep]
    return data, keep


_MSG_LOCAL, _MSG_GLOBAL = 84, 86      # SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT


def _fast_problem(cols: dict, i: int, partial: bool, no_home: bool, local: bool, sysid: int) -> AuditViolation:
    """The violation :func:`_setpoint_row` adds for setpoint ``i`` (one it could not place)."""
    t_s, mask, frame = float(cols["t_s"][i]), int(cols["type_mask"][i]), int(cols["frame"][i])
    name = _SP_LOCAL if cols["msgid"][i] == _MSG_LOCAL else _SP_GLOBAL
    if partial:
        return AuditViolation("frame", t_s, (sysid,), float(mask), 0.0,
                              f"{name} ignores only some position axes (type_mask 0x{mask:X})")
    if no_home:
        why = ("LOCAL_NED setpoint sent before any HOME_POSITION was received" if local
               else "relative-altitude setpoint sent before any HOME_POSITION")
        return AuditViolation("no_home", t_s, (sysid,), math.nan, math.nan, why)
    return AuditViolation("frame", t_s, (sysid,), float(frame), 0.0,
                          f"{name} in coordinate frame {frame}, which the audit cannot place")


def find_tlogs(log_dir: Path) -> dict[int, list[Path]]:
    """``sysid -> [tlog paths]`` in ``log_dir/tlogs`` (or ``log_dir`` itself), by file name.

    The quarantine log (``quarantine[-k].tlog``: frames of unknown or suspect senders,
    :class:`mission.link.tlog.QuarantineLog`) is no vehicle's and is ignored.

    Raises
    ------
    AuditError
        A ``.tlog`` not named ``vehicle-<sysid>[-k].tlog``.
    """
    tdir = log_dir / "tlogs"
    files = sorted(tdir.glob("*.tlog")) if tdir.is_dir() else []
    if not files:
        files = sorted(log_dir.glob("*.tlog"))
    by_sysid: dict[int, list[Path]] = {}
    for f in files:
        stem = f.stem
        if stem == _QUARANTINE_STEM or stem.startswith(_QUARANTINE_STEM + "-"):
            continue
        try:
            sysid = int(stem.split("-")[1])
        except (IndexError, ValueError):
            raise AuditError(f"{f}: not a vehicle tlog name (expected vehicle-<sysid>[-k].tlog)") from None
        by_sysid.setdefault(sysid, []).append(f)
    return by_sysid

