"""``swarmseek audit`` CPU time on one log dir: ``python benchmarks/audit_time.py LOG_DIR [REPEATS]``.

Runs ``audit_mission`` once to warm up, then REPEATS times (default 8) timed with
``time.process_time`` (CPU time: robust to a loaded machine); prints the min and median, the log's
size and the violation counts.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    """Time the audit of ``argv[0]`` and print the figures."""
    from mission.safety.audit import audit_mission

    argv = sys.argv[1:] if argv is None else argv
    log_dir = Path(argv[0])
    repeats = int(argv[1]) if len(argv) > 1 else 8
    audit_mission(log_dir)
    times_s = []
    for _ in range(repeats):
        t0 = time.process_time()
        report = audit_mission(log_dir)
        times_s.append(time.process_time() - t0)
    times_s.sort()
    size_mb = sum(p.stat().st_size for p in log_dir.rglob("*") if p.is_file()) / 1e6
    print(f"{log_dir}: {size_mb:.1f} MB; audit CPU s: min {times_s[0]:.3f} median {times_s[len(times_s) // 2]:.3f} "
          f"({repeats} runs); violations {dict(report.violation_counts)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
