"""``swarmseek audit`` CPU time on one log dir: ``python benchmarks/audit_time.py LOG_DIR [REPEATS] [--plain]``.

Runs ``audit_mission`` once to warm up, then REPEATS times (default 8) timed with
``time.process_time`` (CPU time: robust to a loaded machine); prints the min and median, the log's
vehicle-hours (the mission log's first to last stamp times the number of vehicle tlogs), its
sizes per vehicle-hour (mission log, tlogs) and the violation counts. ``--plain`` times the plain
path (``audit_mission(fast=False)``: pymavlink reader, every pair of tracks checked exactly),
which gives the same report.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path


def _vehicle_hours(log_dir: Path) -> float:
    """The mission log's span (first to last record stamp) times the number of vehicle tlogs."""
    from mission.safety.audit_read import find_tlogs
    from mission.telemetry.mission_log import iter_mission_log

    stamps = [r["t_s"] for r in iter_mission_log(log_dir / "mission.jsonl") if isinstance(r.get("t_s"), (int, float))]
    return (max(stamps) - min(stamps)) * len(find_tlogs(log_dir)) / 3600.0


def main(argv=None) -> int:
    """Time the audit of ``argv[0]`` and print the figures."""
    from mission.safety.audit import audit_mission

    argv = sys.argv[1:] if argv is None else argv
    plain = "--plain" in argv
    args = [a for a in argv if a != "--plain"]
    log_dir = Path(args[0])
    repeats = int(args[1]) if len(args) > 1 else 8
    audit_mission(log_dir, fast=not plain)
    times_s = []
    for _ in range(repeats):
        t0 = time.process_time()
        report = audit_mission(log_dir, fast=not plain)
        times_s.append(time.process_time() - t0)
    times_s.sort()
    log_mb = (log_dir / "mission.jsonl").stat().st_size / 1e6
    tlog_mb = sum(p.stat().st_size for p in log_dir.rglob("*.tlog")) / 1e6
    vh = _vehicle_hours(log_dir)
    median_s = times_s[len(times_s) // 2]
    print(f"{log_dir} ({'plain' if plain else 'fast'}): {vh:.2f} vehicle-hours; mission log {log_mb:.1f} MB "
          f"({log_mb / vh:.2f} MB per vehicle-hour), tlogs {tlog_mb:.1f} MB ({tlog_mb / vh:.2f} MB per vehicle-hour); "
          f"audit CPU s: min {times_s[0]:.3f} median {median_s:.3f} ({repeats} runs), "
          f"{median_s / vh:.3f} s per vehicle-hour; violations {dict(report.violation_counts)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
