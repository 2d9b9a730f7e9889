"""One whole mission against real ArduCopter SITL: error, iterations, wall time, CPU per process.

Run from the repository root (the SITL folder from ``SWARMSEEK_ARDUPILOT_SITL``)::

    SWARMSEEK_ARDUPILOT_SITL=../shared/sitl/ardupilot python benchmarks/bench_sitl_ardupilot.py --n 4 --speedup 3
    # the pre-arm readiness case: six vehicles, fly started as soon as the fleet answers (EKFs not ready yet)
    SWARMSEEK_ARDUPILOT_SITL=../shared/sitl/ardupilot python benchmarks/bench_sitl_ardupilot.py --n 6 --speedup 1
    # ... with a dry run first, printed (it reports the vehicles NOT READY while their EKF starts)
    ... bench_sitl_ardupilot.py --n 6 --speedup 1 --dry-run 3

Starts the fleet (:class:`mission.sim.sitl_fleet.SitlFleet`, ``FS_GCS_TIMEOUT`` 5 s times the
speed-up), writes its plan (CVT, radius 2 m, start (0, 20, 15) m), starts one ``swarmseek sensor``
per vehicle (sigma_2, source (8, 28, 14) m, noise 0.005) and runs ``swarmseek fly --json``.
Prints the outcome, the error, the iterations, the wall time of ``fly`` and the CPU seconds of
``fly`` (the coordinator) and of each SITL instance during it, and the mission log's readiness
and arming events.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import subprocess
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

SOURCE = (8.0, 28.0, 14.0)


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(fields[i]) for i in (11, 12, 13, 14)) / os.sysconf("SC_CLK_TCK")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(n: int, speedup: float, dry_run_s: float | None, out: Path) -> dict:
    """Fly one mission; returns the figures."""
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig

    cli = [sys.executable, "-m", "mission"]
    zport = _free_port()
    cfg = SitlFleetConfig(flavour="ardupilot", n=n, speedup=speedup, params={"FS_GCS_TIMEOUT": 5.0 * max(1.0, speedup)},
                          run_dir=out / "sitl").free()
    t0 = time.monotonic()
    with SitlFleet(cfg) as fleet:
        print(f"{n} ArduCopter SITL instances answer after {time.monotonic() - t0:.1f} s", flush=True)
        plan = fleet.write_plan(out / "plan.toml", zenoh_endpoint=f"tcp/127.0.0.1:{zport}")
        if dry_run_s is not None:
            dr = subprocess.run(cli + ["dry-run", "--plan", str(plan), "--ready-timeout", str(dry_run_s)],
                                capture_output=True, text=True)
            print(f"dry-run (exit {dr.returncode}) {time.monotonic() - t0:.0f} s after the start:\n{dr.stdout}")
        lat, lon, alt = fleet.origin
        sensors = [subprocess.Popen(cli + [
            "sensor", "--connect", v.sensor_connection, "--sysid", str(v.sysid), "--fleet", "sitl", "--field", "sigma2",
            "--source=" + ",".join(map(str, SOURCE)), f"--origin={lat},{lon},{alt}", "--noise", "0.005",
            "--zenoh-connect", f"tcp/127.0.0.1:{zport}", "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for v in fleet.vehicles]
        sitl0 = [_cpu_s(p) for p in fleet.pids]
        cpu0, t1 = _children_cpu_s(), time.monotonic()
        fly = subprocess.run(cli + ["fly", "--plan", str(plan), "--log-dir", str(out / "logs"), "--json"],
                             capture_output=True, text=True, timeout=1200)
        fly_wall_s, fly_cpu_s = time.monotonic() - t1, _children_cpu_s() - cpu0
        sitl_cpu = [_cpu_s(p) - c for p, c in zip(fleet.pids, sitl0)]
        for p in sensors:
            p.terminate()
        for p in sensors:
            p.wait(timeout=10)
    r = json.loads(fly.stdout)
    est = r["estimate_enu"]
    error = None if est is None else sum((a - b) ** 2 for a, b in zip(est, SOURCE)) ** 0.5
    return {"n": n, "speedup": speedup, "outcome": r["outcome"], "message": r["message"], "error_m": error,
            "iterations": r["iterations"], "mission_time_s": r["mission_time_s"], "fly_wall_s": fly_wall_s,
            "coordinator_cpu_s": fly_cpu_s, "sitl_cpu_s": sitl_cpu, "lost": r["lost"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=4)
    parser.add_argument("--speedup", type=float, default=3.0)
    parser.add_argument("--dry-run", type=float, default=None, metavar="S",
                        help="run `dry-run --ready-timeout S` before the sensors and `fly`")
    args = parser.parse_args()
    with TemporaryDirectory(prefix="bench-sitl-ap-") as tmp:
        f = run(args.n, args.speedup, args.dry_run, Path(tmp))
        for line in (Path(tmp) / "logs" / "mission.jsonl").read_text().splitlines():
            rec = json.loads(line)
            m = rec.get("message", "")
            if rec["type"] == "event" and any(w in m for w in ("autopilot", "arming", "ground station dies")):
                print(f"  [{rec['level']}] {m[:240]}")
    err = "-" if f["error_m"] is None else f"{f['error_m']:.2f} m"
    print(f"\n{f['n']} vehicles, speed-up {f['speedup']:g}: {f['outcome']} ({f['message']})")
    print(f"error {err}, {f['iterations']} iterations, mission {f['mission_time_s']:.0f} s, fly wall "
          f"{f['fly_wall_s']:.0f} s, lost {f['lost']}")
    w = f["fly_wall_s"]
    print(f"CPU during fly: coordinator {f['coordinator_cpu_s']:.1f} s ({100 * f['coordinator_cpu_s'] / w:.0f} % "
          f"of a core); SITL instances {', '.join(f'{c:.1f}' for c in f['sitl_cpu_s'])} s "
          f"({100 * sum(f['sitl_cpu_s']) / len(f['sitl_cpu_s']) / w:.0f} % of a core each on average)")
    return 0 if f["outcome"] == "converged" else 1


if __name__ == "__main__":
    raise SystemExit(main())
