"""Link budget of a flown mission from its ``.tlog`` files: bytes per second per vehicle and direction.

Usage::

    python benchmarks/tlog_budget.py LOG_DIR        # LOG_DIR/tlogs/vehicle-*.tlog

For every vehicle: the span of its tlog, the frames and bytes per second sent by the ground
station (source system id 255: "up") and by the vehicle ("down"), and the three message types
that take the most bytes each way. Frame sizes are the whole MAVLink frames
(``msg.get_msgbuf()``: header, payload, CRC, signature when signed). Used for the link budget of
``docs/field-checklist.md``.
"""
from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

GCS_SYSID = 255


def tlog_budget(path: Path) -> dict:
    """Frames and bytes per direction (``up``: from the ground station) and per message type."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    frames, size, by_type = collections.Counter(), collections.Counter(), collections.Counter()
    t_first = t_last = None
    while (msg := conn.recv_match()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        way = "up" if msg.get_srcSystem() == GCS_SYSID else "down"
        n = len(msg.get_msgbuf())
        frames[way] += 1
        size[way] += n
        by_type[(way, msg.get_type())] += n
        t = getattr(msg, "_timestamp", None)
        if t is not None:
            t_first = t if t_first is None else min(t_first, t)
            t_last = t if t_last is None else max(t_last, t)
    span_s = (t_last - t_first) if t_first is not None else 0.0
    return {"span_s": span_s, "frames": frames, "bytes": size, "by_type": by_type}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log_dir", type=Path, help="a mission's --log-dir (with tlogs/)")
    args = parser.parse_args(argv)
    tlogs = sorted((args.log_dir / "tlogs").glob("vehicle-*.tlog"))
    if not tlogs:
        print(f"tlog_budget: no tlogs/vehicle-*.tlog under {args.log_dir}", file=sys.stderr)
        return 2
    for path in tlogs:
        b = tlog_budget(path)
        span = b["span_s"] or float("nan")
        print(f"{path.name}: {b['span_s']:.1f} s")
        for way in ("up", "down"):
            top = [(name, n) for (w, name), n in b["by_type"].most_common() if w == way][:3]
            tops = ", ".join(f"{name} {n / span:.0f} B/s" for name, n in top)
            print(f"  {way:4s} {b['frames'][way] / span:6.1f} frames/s {b['bytes'][way] / span:7.0f} B/s  ({tops})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
