"""The first SECONDS of a mission's logs, to measure the audit's cost per vehicle-hour on one mission:
``python benchmarks/audit_log_prefix.py LOG_DIR OUT_DIR SECONDS``.

Copies ``mission.jsonl`` and every ``tlogs/*.tlog`` of LOG_DIR into OUT_DIR, keeping the records
stamped within SECONDS of the mission log's first record (tlog records are whole MAVLink frames:
the copy is a valid log, as if the logs had been copied while the mission flew). Auditing prefixes
of different lengths (``benchmarks/audit_time.py``) separates the audit's cost that grows with the
mission's length from the one that does not (the pairs of vehicles).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _prefix_tlog(src: Path, dst: Path, end_s: float) -> None:
    """Copy the records of ``src`` stamped at or before ``end_s`` (tlog records are time-ordered)."""
    from mission.safety.audit_fast import record_offsets

    data = src.read_bytes()
    buf = np.frombuffer(data, dtype=np.uint8)
    offsets = record_offsets(buf)
    if offsets is None:
        raise SystemExit(f"{src}: not a readable tlog")
    stamps = np.array([int.from_bytes(data[o:o + 8], "big") * 1e-6 for o in offsets])
    keep = int(np.searchsorted(stamps, end_s, side="right"))
    dst.write_bytes(data[:offsets[keep]] if keep < len(offsets) else data)


def main(argv=None) -> int:
    """Write the prefix of ``argv[0]`` into ``argv[1]``."""
    from mission.telemetry.mission_log import iter_mission_log

    argv = sys.argv[1:] if argv is None else argv
    src, dst, seconds = Path(argv[0]), Path(argv[1]), float(argv[2])
    (dst / "tlogs").mkdir(parents=True, exist_ok=False)
    t0 = min(r["t_s"] for r in iter_mission_log(src / "mission.jsonl") if isinstance(r.get("t_s"), (int, float)))
    with open(src / "mission.jsonl", encoding="utf-8") as fh, open(dst / "mission.jsonl", "w", encoding="utf-8") as out:
        out.writelines(line for line in fh if _stamp(line) <= t0 + seconds)
    for tlog in sorted((src / "tlogs").glob("*.tlog")):
        _prefix_tlog(tlog, dst / "tlogs" / tlog.name, t0 + seconds)
    return 0


def _stamp(line: str) -> float:
    """A mission-log line's ``t_s`` (its first field as the log writes it); inf if none."""
    import json

    try:
        return float(json.loads(line).get("t_s", float("inf")))
    except (ValueError, AttributeError, TypeError):
        return float("inf")


if __name__ == "__main__":
    sys.exit(main())
