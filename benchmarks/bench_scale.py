"""Scale: ``swarmseek run --n N`` (lock-step) for N = 8, 50, 100 by default.

Each run is a fresh process, as a user would start it. Per N: outcome, error, false losses
(the summary's ``lost`` list: must be empty), re-engagements, the ``swarmseek audit`` violations
of the run's log dir (must be 0), the setpoint interval per vehicle from the ``.tlog`` stamps
(the worst vehicle's p99 while it was commanded, against ``1 / setpoint_rate_hz``: target within
10 %), and the wall time.

Usage::

    python benchmarks/bench_scale.py                 # N = 8, 50, 100, seed 0
    python benchmarks/bench_scale.py --n 8 50 --seed 3
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _setpoint_intervals(log_dir: Path, plan: dict) -> tuple[float, float]:
    """``(worst vehicle's p99 interval, median of the vehicles' p99)`` in seconds, from the tlogs.

    Intervals longer than 1 s are gaps between commanded periods (before takeoff, after landing),
    not stream intervals, and are left out.
    """
    from mission.safety.audit_read import find_tlogs, read_vehicle_setpoints

    p99 = []
    for sysid, paths in find_tlogs(log_dir).items():
        sp = read_vehicle_setpoints(paths, sysid, plan["origin"])
        dt = np.diff(np.asarray(sp.t_s, dtype=float))
        dt = dt[dt < 1.0]
        if len(dt):
            p99.append(float(np.percentile(dt, 99)))
    return (max(p99), float(np.median(p99))) if p99 else (float("nan"), float("nan"))


def _audit(log_dir: Path) -> int:
    from mission.safety.audit import audit_mission

    return sum(audit_mission(log_dir).violation_counts.values())


def run_one(n: int, seed: int, log_dir: Path) -> dict:
    """Fly ``swarmseek run --n n`` into ``log_dir``; the figures of one table row."""
    argv = [sys.executable, "-m", "mission", "run", "--n", str(n), "--seed", str(seed), "--json",
            "--log-dir", str(log_dir)]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=3600)
    wall_s = time.perf_counter() - t0
    try:
        s = json.loads(proc.stdout)
    except json.JSONDecodeError:
        return {"n": n, "wall_s": wall_s, "outcome": f"no summary (exit {proc.returncode}): {proc.stderr[-300:]}"}
    plan = next(json.loads(line)["plan"] for line in (log_dir / "mission.jsonl").open()
                if '"type":"plan"' in line)
    worst_p99, median_p99 = _setpoint_intervals(log_dir, plan)
    return {"n": n, "outcome": s["outcome"], "error_m": s.get("error_m"), "iterations": s["iterations"],
            "lost": [x["sysid"] for x in s["lost"]], "reengaged": sum(s.get("reengaged", {}).values()),
            "violations": _audit(log_dir), "period_s": 1.0 / plan["setpoint_rate_hz"],
            "p99_worst_s": worst_p99, "p99_median_s": median_p99, "mission_time_s": s["mission_time_s"],
            "wall_s": wall_s}


def _row(r: dict) -> str:
    if "violations" not in r:
        return f"| {r['n']} | {r['outcome']} | | | | | | | {r['wall_s']:.0f} |"
    ok = r["p99_worst_s"] <= 1.1 * r["period_s"]
    return (f"| {r['n']} | {r['outcome']} ({r['iterations']} it.) | {r['error_m']:.3f} | {len(r['lost'])} | "
            f"{r['reengaged']} | {r['violations']} | {r['p99_worst_s'] * 1e3:.1f} / {r['p99_median_s'] * 1e3:.1f} ms "
            f"vs {r['period_s'] * 1e3:.0f} ms ({'ok' if ok else 'over 10 %'}) | {r['mission_time_s']:.0f} | "
            f"{r['wall_s']:.0f} |")


def main(argv=None) -> int:
    """Run the missions and print the table; exit 1 if any row misses a target."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[8, 50, 100])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, default=None, help="keep the log dirs under this directory")
    args = ap.parse_args(argv)
    print("| N | outcome | error m | lost | re-engaged | audit violations | setpoint p99 worst / median "
          "| mission s (sim) | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    bad = False
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        for n in args.n:
            r = run_one(n, args.seed, root / f"n{n}")
            print(_row(r), flush=True)
            bad |= (r.get("outcome") != "converged" or bool(r.get("lost")) or r.get("violations", 1) != 0
                    or not r.get("p99_worst_s", np.inf) <= 1.1 * r.get("period_s", 0.0))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
