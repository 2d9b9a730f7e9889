"""One whole mission against a real SITL fleet, measured: error, iterations, wall time, CPU.

    SWARMSEEK_PX4_SITL=/path/to/px4-sih python benchmarks/bench_sitl.py --flavour px4 --n 4 --speedup 3

Starts the fleet (:class:`mission.sim.sitl_fleet.SitlFleet`, free ports), writes the plan of
``tests/test_sitl_px4.py`` (CVT radius 2 m, source (6, 12, 13) m, start (0, 20, 15) m, noise
0.005), runs one ``swarmseek sensor`` per vehicle and ``swarmseek fly`` as subprocesses
(:func:`mission.sim.sitl_mission.fly_sitl_mission`) and prints one JSON line: outcome, error,
iterations, mission time, wall time of ``fly``, CPU seconds of ``fly``, of the sensors and of
each SITL process during the flight (from ``/proc``), and each as a share of one core.
"""
from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
from pathlib import Path

import numpy as np

SOURCE = (6.0, 12.0, 13.0)
SEEKING = {"eps": 50.0, "gamma_m": 1.0, "convergence_window": 10, "convergence_tol_m": 0.5,
           "arrival_tol_m": 0.7, "start_enu_m": [0.0, 20.0, 15.0]}


def main() -> int:
    from estimator.seekers import SEEKERS
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_mission import fly_sitl_mission

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flavour", choices=("px4", "ardupilot"), default="px4")
    parser.add_argument("--n", type=int, default=4)
    parser.add_argument("--speedup", type=float, default=1.0)
    parser.add_argument("--seeker", choices=SEEKERS, default="gradient",
                        help="the plan's [seeking] seeker (default gradient, the paper's)")
    parser.add_argument("--gamma", type=float, default=None, metavar="M",
                        help="the plan's gamma_m (default 1 m for gradient, 20 m otherwise, as swarmseek run)")
    parser.add_argument("--sampling", choices=("stop_and_go", "moving"), default="stop_and_go",
                        help="the plan's [seeking] sampling (moving: newton/model only)")
    args = parser.parse_args()
    seeking = dict(SEEKING, seeker=args.seeker, sampling=args.sampling,
                   gamma_m=args.gamma if args.gamma is not None else (1.0 if args.seeker == "gradient" else 20.0))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        zenoh = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    cfg = SitlFleetConfig(flavour=args.flavour, n=args.n, speedup=args.speedup).free()
    with tempfile.TemporaryDirectory(prefix="bench-sitl-") as tmp, SitlFleet(cfg) as fleet:
        plan = fleet.write_plan(Path(tmp) / "plan.toml", zenoh_endpoint=zenoh, overrides={"seeking": seeking})
        res = fly_sitl_mission(fleet, plan, Path(tmp) / "logs", SOURCE, zenoh=zenoh, timeout_s=900.0)
    summary = res.summary or {}
    est = summary.get("estimate_enu")
    wall = res.wall_s
    out = {
        "flavour": args.flavour, "n": args.n, "speedup": args.speedup, "seeker": args.seeker,
        "sampling": args.sampling, "gamma_m": seeking["gamma_m"], "returncode": res.returncode,
        "outcome": summary.get("outcome"), "iterations": summary.get("iterations"),
        "error_m": None if est is None else round(float(np.linalg.norm(np.subtract(est, SOURCE))), 3),
        "mission_time_s": summary.get("mission_time_s"), "seek_time_s": summary.get("seek_time_s"),
        "fly_wall_s": round(wall, 1),
        "cpu_s": res.cpu_s,
        "cpu_share_of_one_core": {"fly": round(res.cpu_s["fly"] / wall, 3),
                                  "sensors_total": round(res.cpu_s["sensors"] / wall, 3),
                                  "sitl": {k: round(v / wall, 3) for k, v in res.cpu_s["sitl"].items()}},
    }
    print(json.dumps(out))
    return 0 if res.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
