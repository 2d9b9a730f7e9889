"""The audit's fast tlog reader: a whole ``.tlog`` split, checked and decoded with numpy.

:mod:`mission.safety.audit_read` reads a tlog record by record in Python (a loop over every
record, a pymavlink message object per wanted frame): about 0.3 s of CPU per vehicle-hour,
half a minute for a 1-hour, 100-vehicle mission. This module does the same work on whole arrays:

* :func:`record_offsets`: where the records start. The walk from record to record is sequential
  (each record's length is in its header), so it is done by pointer doubling over the byte
  offsets that *could* start a record (a MAVLink magic byte 8 bytes on): ``log2(records)`` numpy
  gathers instead of a Python step per record. It returns None whenever the walk would meet
  something the plain splitter reports (a record that is not a MAVLink frame); the caller then
  uses the plain splitter, which raises its usual error.
* :func:`v2_frames_valid`: the MAVLink 2 CRC (CRC-16/MCRF4XX with the message's ``CRC_EXTRA``) of
  many frames at once, one numpy step per byte column, frames grouped by payload length.
* :func:`decode_payloads`: the fields of many frames of one message at once, through a numpy
  structured dtype spelled from pymavlink's own ``struct`` format (MAVLink 2's truncated trailing
  zeros padded back, a longer payload cut, as pymavlink does).

Anything else (a MAVLink 1 frame, unknown incompatibility flags, a CRC that does not match) is
left to the plain reader, which decodes it with pymavlink (and refuses a bad CRC). Same results
as the plain reader: ``tests/mission/safety/test_audit_fast_path.py``.
"""
from __future__ import annotations

import re

import numpy as np

__all__ = ["record_offsets", "v2_frames_valid", "decode_payloads", "struct_dtype", "read_tlog_table", "table_from_events",
           "merged_columns", "event_order", "following_setpoints_array"]

_V2, _V1 = 0xFD, 0xFE
_STRUCT_TO_NUMPY = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8",
                    "Q": "<u8", "f": "<f4", "d": "<f8", "c": "S1"}


def _candidates(buf: np.ndarray):
    """Offsets ``i`` where a record could start (``i + 10 <= n`` and a magic byte at ``i + 8``)
    and the offset just past each one's record, as the plain splitter computes it."""
    n = len(buf)
    magic = buf[8:n - 1]                       # magic[i] = buf[i + 8] for i + 10 <= n
    cand = np.flatnonzero((magic == _V2) | (magic == _V1))
    length = buf[cand + 9].astype(np.int64)
    is_v2 = buf[cand + 8] == _V2
    flag_at = cand + 10
    signed = np.zeros(len(cand), dtype=bool)
    inside = flag_at < n
    signed[inside] = (buf[flag_at[inside]] & 0x01).astype(bool)
    size = np.where(is_v2, 12 + length + np.where(signed, 13, 0), 8 + length)
    return cand, cand + 8 + size


def record_offsets(buf: np.ndarray) -> np.ndarray | None:
    """Start offsets of the whole records of a tlog, as the plain splitter walks them.

    Parameters
    ----------
    buf : numpy.ndarray of uint8
        The file's bytes.

    Returns
    -------
    numpy.ndarray of int64 or None
        The offsets of the records the plain splitter returns (a truncated last record, or a tail
        shorter than a record header, is left out as it leaves it out); None when its walk would
        meet a record that is not a MAVLink frame (the plain splitter raises its error).
    """
    n = len(buf)
    if n < 10:
        return np.empty(0, dtype=np.int64)
    cand, after = _candidates(buf)
    if not len(cand) or cand[0] != 0:
        return None
    m = len(cand)
    pos = np.minimum(np.searchsorted(cand, after), m - 1)
    jump = np.where(cand[pos] == after, pos, m)            # next record's candidate index; m: none
    jump = np.append(jump, m)                              # m jumps to itself
    path = np.zeros(1, dtype=np.int64)                     # the first 2^k records of the walk
    while path[-1] != m:
        path = np.concatenate([path, jump[path]])
        jump = jump[jump]
    path = path[:np.argmax(path == m)]
    last_end = int(after[path[-1]])
    if last_end < n and last_end + 10 <= n:
        return None          # the walk goes on to a record that is not a frame: the plain error
    offsets = cand[path]
    return offsets if last_end <= n else offsets[:-1]     # a truncated last record is dropped


def _gather(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """``(K, width)`` bytes from each start (starts + width within ``buf``)."""
    if not len(starts):
        return np.empty((0, width), dtype=buf.dtype)
    return np.lib.stride_tricks.sliding_window_view(buf, width)[starts]


def v2_frames_valid(buf: np.ndarray, frame_at: np.ndarray, crc_extra: int) -> np.ndarray:
    """Whether each MAVLink 2 frame starting at ``frame_at`` (its magic byte) has a valid CRC.

    The CRC-16/MCRF4XX of the header without its magic, the payload and ``crc_extra``, compared
    with the two bytes after the payload; frames of the same payload length are checked together.
    """
    ok = np.zeros(len(frame_at), dtype=bool)
    mlen = buf[frame_at + 1].astype(np.int64)
    for length in np.unique(mlen):
        sel = np.flatnonzero(mlen == length)
        raw = _gather(buf, frame_at[sel] + 1, 9 + int(length) + 2)
        data = np.empty((len(sel), 9 + int(length) + 2), dtype=np.uint8)   # checked bytes, CRC_EXTRA, a pad
        data[:, :-2], data[:, -2], data[:, -1] = raw[:, :-2], crc_extra, 0
        n_bytes = 10 + int(length)
        words = np.ascontiguousarray(data[:, :n_bytes & ~1]).view("<u2").T.copy()   # (steps, K): 2 bytes a step
        crc = np.full(len(sel), 0xFFFF, dtype=np.uint16)
        for column in words:
            crc = _CRC_TABLE16[crc ^ column]
        if n_bytes & 1:
            crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ data[:, n_bytes - 1]) & 0xFF].astype(np.uint16)
        ok[sel] = crc == (raw[:, -2].astype(np.uint16) | raw[:, -1].astype(np.uint16) << 8)
    return ok


def _crc_step(crc: np.ndarray, byte) -> np.ndarray:
    """One byte of CRC-16/MCRF4XX (X.25), as pymavlink's ``x25crc.accumulate``."""
    tmp = (byte ^ (crc & 0xFF)) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


#: one byte of CRC-16/MCRF4XX: ``crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ byte) & 0xFF]``
_CRC_TABLE = _crc_step(np.arange(256, dtype=np.uint32), np.uint32(0)).astype(np.uint32)
#: two bytes at once (a 16-bit register shifts both out): ``crc = _CRC_TABLE16[crc ^ little_endian_word]``
_CRC_TABLE16 = _crc_step(_crc_step(np.arange(65536, dtype=np.uint32), np.uint32(0)), np.uint32(0)).astype(np.uint16)


def struct_dtype(fmt: str, names) -> np.dtype:
    """The packed numpy dtype of a pymavlink ``struct`` format (``<IfffH4f...``) with field ``names``."""
    parts = re.findall(r"(\d*)([a-zA-Z])", fmt.lstrip("<"))
    if len(parts) != len(names):
        raise ValueError(f"format {fmt!r} has {len(parts)} fields, not {len(names)}")
    formats = []
    for count, code in parts:
        if code == "s":
            formats.append(f"S{count or 1}")
        else:
            base = _STRUCT_TO_NUMPY[code]
            formats.append((base, (int(count),)) if count and int(count) > 1 else base)
    return np.dtype({"names": list(names), "formats": formats})


def decode_payloads(buf: np.ndarray, frame_at: np.ndarray, cls) -> np.ndarray:
    """The fields of MAVLink 2 frames of message class ``cls`` (a structured array, wire order).

    A payload shorter than the message (trailing zeros truncated) is zero-padded, a longer one cut.
    """
    dtype = struct_dtype(cls.unpacker.format, cls.ordered_fieldnames)
    size = dtype.itemsize
    if not len(frame_at):
        return np.empty(0, dtype=dtype)
    mlen = buf[frame_at + 1].astype(np.int64)
    padded = np.concatenate([buf, np.zeros(size, dtype=np.uint8)])   # a short last payload reads zeros
    mat = _gather(padded, frame_at + 10, size)                       # a copy, (K, size)
    short = np.flatnonzero(mlen < size)
    if len(short):   # MAVLink 2 truncated the payload's trailing zeros: put them back
        mat[short] = np.where(np.arange(size) < mlen[short, None], mat[short], 0)
    return mat.view(dtype).ravel()


# ------------------------------------------------------------------ one vehicle's setpoints, fast
def _header(buf: np.ndarray, offsets: np.ndarray, wanted) -> dict:
    """Per record of a ``wanted`` message id (in file order): stamp (s), MAVLink 2 or not, incompatibility
    flags, message id, source system and component, frame offset."""
    at = offsets + 8
    v2 = buf[at] == _V2
    msgid = np.where(v2, buf[at + 7].astype(np.int64) | buf[at + 8].astype(np.int64) << 8
                     | buf[at + 9].astype(np.int64) << 16, buf[at + 5])
    keep = np.flatnonzero(np.logical_or.reduce([msgid == m for m in wanted]))
    at, v2 = at[keep], v2[keep]
    stamps = _gather(buf, offsets[keep], 8).view(">u8").ravel().astype(np.float64) * 1e-6
    return {"t_s": stamps, "at": at, "v2": v2, "flags": np.where(v2, buf[at + 2], 0), "msgid": msgid[keep],
            "src": np.where(v2, buf[at + 5], buf[at + 3]), "comp": np.where(v2, buf[at + 6], buf[at + 4])}


def following_setpoints_array(fields: np.ndarray) -> np.ndarray:
    """:func:`mission.safety.audit_read.following_setpoints` of many HEARTBEATs (structured array)."""
    custom = fields["custom_mode"].astype(np.int64)
    px4 = fields["autopilot"] == _AUTOPILOT_PX4
    mode_ok = np.where(px4, (custom >> 16) & 0xFF == _PX4_MAIN_OFFBOARD, np.isin(custom, _ARDUPILOT_GUIDED))
    return (fields["base_mode"] & _ARMED).astype(bool) & mode_ok


def read_tlog_table(data: bytes, sysid: int, gcs_sysid: int) -> dict | None:
    """The audit's events of one tlog as arrays, or None when the file holds anything the fast path
    leaves to pymavlink (a MAVLink 1 or otherwise unusual wanted frame, a bad CRC, a record that is
    not a frame): the caller reads that file with the plain reader.

    Returns
    -------
    dict or None
        ``mode`` (the vehicle's own HEARTBEATs: ``following``), ``home`` (its HOME_POSITIONs:
        ``latitude`` ... ``z``) and ``sp`` (the setpoints the ground station sent it:
        :func:`_setpoint_columns`), each a dict of columns with ``seq`` (order in the file) and ``t_s``.
    """
    from pymavlink.dialects.v20 import common as mavlink

    buf = np.frombuffer(data, dtype=np.uint8)
    offsets = record_offsets(buf)
    if offsets is None:
        return None
    classes = {mavlink.MAVLINK_MSG_ID_HEARTBEAT: mavlink.MAVLink_heartbeat_message,
               mavlink.MAVLINK_MSG_ID_HOME_POSITION: mavlink.MAVLink_home_position_message,
               mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: mavlink.MAVLink_set_position_target_local_ned_message,
               mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: mavlink.MAVLink_set_position_target_global_int_message}
    h = _header(buf, offsets, classes)         # the wanted records only, in file order (``seq``: their rank)
    parts = {}
    for msgid, cls in classes.items():
        sel = np.flatnonzero(h["msgid"] == msgid)
        if not (np.all(h["v2"][sel]) and np.all(h["flags"][sel] <= 1)
                and np.all(v2_frames_valid(buf, h["at"][sel], cls.crc_extra))):
            return None
        parts[msgid] = (sel, decode_payloads(buf, h["at"][sel], cls))
    sel, hb = parts[mavlink.MAVLINK_MSG_ID_HEARTBEAT]
    mine = (h["src"][sel] == sysid) & (h["comp"][sel] == 1)
    table = {"mode": {"seq": sel[mine], "following": following_setpoints_array(hb[mine])}}
    sel, home = parts[mavlink.MAVLINK_MSG_ID_HOME_POSITION]
    mine = h["src"][sel] == sysid
    table["home"] = {"seq": sel[mine], **{k: home[k][mine] for k in _HOME_FIELDS}}
    table["sp"] = _setpoint_columns(h, parts, sysid, gcs_sysid, mavlink)
    for part in table.values():
        part["t_s"] = h["t_s"][part["seq"]]
    return table


_HOME_FIELDS = ("latitude", "longitude", "altitude", "x", "y", "z")
_AUTOPILOT_PX4, _PX4_MAIN_OFFBOARD, _ARMED = 12, 6, 128
_ARDUPILOT_GUIDED = (4, 20)


def _setpoint_columns(h: dict, parts: dict, sysid: int, gcs_sysid: int, mavlink) -> dict:
    """The setpoints sent to ``sysid`` by ``gcs_sysid``, LOCAL_NED and GLOBAL_INT, as columns
    ``seq, msgid, type_mask, frame, a, b, c`` (x, y, z or lat_int, lon_int, alt)."""
    cols = {k: [] for k in ("seq", "msgid", "type_mask", "frame", "a", "b", "c")}
    for msgid, names in ((mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, ("x", "y", "z")),
                         (mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT, ("lat_int", "lon_int", "alt"))):
        sel, f = parts[msgid]
        mine = (h["src"][sel] == gcs_sysid) & ((f["target_system"] == sysid) | (f["target_system"] == 0))
        cols["seq"].append(sel[mine])
        cols["msgid"].append(np.full(int(mine.sum()), msgid))
        cols["type_mask"].append(f["type_mask"][mine].astype(np.int64))
        cols["frame"].append(f["coordinate_frame"][mine].astype(np.int64))
        for key, name in zip("abc", names):
            cols[key].append(f[name][mine].astype(np.float64))
    return {k: np.concatenate(v) for k, v in cols.items()}


def table_from_events(events) -> dict:
    """The plain reader's events of one tlog (``(t_s, kind, message)``, see
    :func:`mission.safety.audit_read._read_tlog`) as the table :func:`read_tlog_table` returns."""
    rows = {"mode": [], "home": [], "sp": []}
    for seq, (t_s, kind, msg) in enumerate(events):
        if kind == "mode":
            rows["mode"].append((seq, t_s, msg))
        elif kind == "home":
            rows["home"].append((seq, t_s, *(getattr(msg, k) for k in _HOME_FIELDS)))
        else:
            abc = (msg.x, msg.y, msg.z) if msg.get_type() == _SP_LOCAL else (msg.lat_int, msg.lon_int, msg.alt)
            rows["sp"].append((seq, t_s, msg.get_msgId(), msg.type_mask, msg.coordinate_frame, *abc))
    names = {"mode": ("seq", "t_s", "following"), "home": ("seq", "t_s", *_HOME_FIELDS),
             "sp": ("seq", "t_s", "msgid", "type_mask", "frame", "a", "b", "c")}
    table = {}
    for kind, cols in names.items():
        arr = list(zip(*rows[kind])) or [()] * len(cols)
        table[kind] = {c: np.asarray(v, dtype=_COLUMN_TYPES.get(c, np.float64)) for c, v in zip(cols, arr)}
    return table


_COLUMN_TYPES = {"seq": np.int64, "following": bool, "msgid": np.int64, "type_mask": np.int64, "frame": np.int64,
                 "latitude": np.int64, "longitude": np.int64, "altitude": np.int64}


_SP_LOCAL = "SET_POSITION_TARGET_LOCAL_NED"
_SP_NAMES = {84: _SP_LOCAL, 86: "SET_POSITION_TARGET_GLOBAL_INT"}


def merged_columns(tables: list, kind: str) -> tuple[dict, np.ndarray]:
    """One kind's columns of several files' tables, and each row's (file, seq) order key."""
    cols = {c: np.concatenate([t[kind][c] for t in tables]) for c in tables[0][kind]}
    file_no = np.concatenate([np.full(len(t[kind]["seq"]), i, dtype=np.int64) for i, t in enumerate(tables)])
    return cols, file_no


def event_order(tables: list) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """Home and setpoint columns of a vehicle's files, and their events in the plain reader's order
    (stable by stamp, then file, then record): ``kind_sorted`` (1 home, 2 setpoint) and
    ``row_sorted`` (the row of its kind)."""
    homes, home_file = merged_columns(tables, "home")
    sps, sp_file = merged_columns(tables, "sp")
    t = np.concatenate([homes["t_s"], sps["t_s"]])
    file_no = np.concatenate([home_file, sp_file])
    seq = np.concatenate([homes["seq"], sps["seq"]])
    kind = np.concatenate([np.ones(len(home_file), dtype=np.int8), np.full(len(sp_file), 2, dtype=np.int8)])
    row = np.concatenate([np.arange(len(home_file)), np.arange(len(sp_file))])
    order = np.lexsort((seq, file_no, t))
    return homes, sps, kind[order], row[order]
