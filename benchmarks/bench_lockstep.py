"""Lock-step against wall-clock missions: wall time, reproducibility, behaviour on a busy host.

Runs ``swarmseek run`` (each run a fresh process, as a user would) several times with one seed:

* ``lockstep``: the default, the fleet and the coordinator on one simulated clock;
* ``realtime``: ``--speedup S``, the fleet on its own thread against the wall clock;

optionally with ``--busy K`` processes spinning on the CPU beside it. Prints, per mode, the wall
time of each run, the outcome, the error, the vehicles lost and re-engaged, and whether the
mission logs of the runs are identical record for record (loopback ports, chosen at run time,
and the log's own path normalised).

Usage::

    python benchmarks/bench_lockstep.py                    # 3 runs per mode, seed 13
    python benchmarks/bench_lockstep.py --busy 2 --speedup 30 --runs 2
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def _normalised(path: Path) -> list[dict]:
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        rec = json.loads(re.sub(r"127\.0\.0\.1:\d+", "127.0.0.1:PORT", line))
        rec.pop("log_path", None)
        out.append(rec)
    return out


def _run_once(args, mode: str, log_dir: Path) -> dict:
    argv = [sys.executable, "-m", "mission", "run", "--seed", str(args.seed), "--n", str(args.n),
            "--json", "--no-tlog", "--log-dir", str(log_dir)]
    if mode == "realtime":
        argv += ["--speedup", str(args.speedup)]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=1800)
    wall_s = time.perf_counter() - t0
    try:
        summary = json.loads(proc.stdout)
    except json.JSONDecodeError:
        return {"wall_s": wall_s, "outcome": f"no summary (exit {proc.returncode}): {proc.stderr[-300:]}"}
    return {"wall_s": wall_s, "outcome": summary["outcome"], "error_m": summary.get("error_m"),
            "iterations": summary["iterations"], "lost": [x["sysid"] for x in summary["lost"]],
            "reengaged": sum(summary.get("reengaged", {}).values()),
            "mission_time_s": summary["mission_time_s"]}


def _fmt(row: dict) -> str:
    err = row.get("error_m")
    return (f"{row['wall_s']:6.1f} s wall  {row['outcome']:<16} error "
            f"{'-' if err is None else f'{err:.3f}'} m  it {row.get('iterations', '-')}  "
            f"lost {row.get('lost', '-')}  re-engaged {row.get('reengaged', '-')}  "
            f"mission {row.get('mission_time_s', 0):.1f} s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=13)
    parser.add_argument("--n", type=int, default=8)
    parser.add_argument("--speedup", type=float, default=10.0, help="speed-up of the realtime runs")
    parser.add_argument("--busy", type=int, default=0, help="CPU-spinning processes beside the runs")
    parser.add_argument("--modes", default="lockstep,realtime")
    args = parser.parse_args(argv)
    stop = mp.Event()
    spinners = [mp.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.busy)]
    for p in spinners:
        p.start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for mode in args.modes.split(","):
                print(f"{mode} (seed {args.seed}, n {args.n}"
                      f"{f', x{args.speedup:g}' if mode == 'realtime' else ''}, {args.busy} busy processes):")
                logs = []
                for k in range(args.runs):
                    log_dir = Path(tmp) / f"{mode}{k}"
                    print("  " + _fmt(_run_once(args, mode, log_dir)), flush=True)
                    logs.append(log_dir / "mission.jsonl")
                records = [_normalised(p) if p.exists() else None for p in logs]
                same = all(r == records[0] for r in records[1:]) and records[0] is not None
                print(f"  mission logs identical across the {args.runs} runs: {same}")
    finally:
        stop.set()
        for p in spinners:
            p.join(timeout=5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
