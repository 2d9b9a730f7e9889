"""One whole mission against a real SITL fleet, measured: error, iterations, wall time, CPU.

    SWARMSEEK_PX4_SITL=/path/to/px4-sih python benchmarks/bench_sitl.py --flavour px4 --n 4 --speedup 3
    # the intermittent plume (release at the sigma2 source, wind from 270 deg), the ste seeker
    SWARMSEEK_PX4_SITL=/path/to/px4-sih python benchmarks/bench_sitl.py --flavour px4 --n 4 --speedup 1 \
        --seeker ste --sampling moving --field intermittent

Starts the fleet (:class:`mission.sim.sitl_fleet.SitlFleet`, free ports), writes the plan of
``tests/sitl/test_sitl_px4.py`` (CVT radius 2 m, source (6, 12, 13) m, start (0, 20, 15) m, noise
0.005), runs one ``swarmseek sensor`` per vehicle and ``swarmseek fly`` as subprocesses
(:func:`mission.sim.sitl_mission.fly_sitl_mission`) and prints one JSON line: outcome, error,
iterations, mission time, wall time of ``fly``, CPU seconds of ``fly``, of the sensors and of
each SITL process during the flight (from ``/proc``), and each as a share of one core.

``--field plume|intermittent``: the sensors sample that plume (``--wind-from``, default 270,
``--wind-speed``), release at the same source, noise 0.01; the plan starts 25 m downwind of it,
3 m lower, with a formation radius of 4 m (``swarmseek run``'s mission), and its ``[seeking]`` gets
the ``ste`` seeker (default), sampling while moving, ``plume_mode`` (``intermittent`` on the
intermittent plume) and the sensor's noise; the wind only with ``--seek-wind-from``.
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
PLUMES = ("plume", "intermittent")
PLUME_NOISE = 0.01            # the sensors' noise on a plume (swarmseek run's default)
PLUME_START_DOWNWIND_M = 25.0  # the start's distance downwind of the release (swarmseek run's)
PLUME_RADIUS_M = 4.0          # the formation radius on a plume (swarmseek run's default)


def parse_args(argv=None) -> argparse.Namespace:
    """The benchmark's options; exit 2 with a one-line message for an inconsistent set."""
    from estimator.seekers import SEEKERS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flavour", choices=("px4", "ardupilot"), default="px4")
    parser.add_argument("--n", type=int, default=4)
    parser.add_argument("--speedup", type=float, default=1.0)
    parser.add_argument("--field", choices=("sigma2", *PLUMES), default="sigma2",
                        help="the sensors' field (default sigma2; plume/intermittent: the release at the "
                             "sigma2 source, the start 25 m downwind)")
    parser.add_argument("--wind-from", type=float, default=None, metavar="DEG",
                        help="plumes: the simulated wind's direction (from, degrees clockwise from north; default 270)")
    parser.add_argument("--wind-speed", type=float, default=None, metavar="M_S",
                        help="plumes: the simulated wind's speed (default: swarmseek sensor's, 2 m/s)")
    parser.add_argument("--seek-wind-from", type=float, default=None, metavar="DEG",
                        help="give the plume/ste seeker this wind direction in the plan (default: not given)")
    parser.add_argument("--seeker", choices=SEEKERS, default=None,
                        help="the plan's [seeking] seeker (default gradient, the paper's; ste on a plume)")
    parser.add_argument("--gamma", type=float, default=None, metavar="M",
                        help="the plan's gamma_m (default 1 m for gradient, 20 m otherwise, as swarmseek run)")
    parser.add_argument("--sampling", choices=("stop_and_go", "moving"), default=None,
                        help="the plan's [seeking] sampling (moving: newton/model/ste only; default "
                             "stop_and_go, moving on a plume)")
    parser.add_argument("--fly-timeout", type=float, default=None, metavar="S",
                        help="swarmseek fly is killed after S wall seconds (default 900; 1800 on a plume: "
                             "300 iterations of ste took about 900 s on PX4 SIH at 1x)")
    args = parser.parse_args(argv)
    plume = args.field in PLUMES
    if args.fly_timeout is None:
        args.fly_timeout = 1800.0 if plume else 900.0
    elif args.fly_timeout <= 0:
        parser.error(f"--fly-timeout must be > 0, got {args.fly_timeout:g}")
    if not plume and (args.wind_from is not None or args.wind_speed is not None):
        parser.error("--wind-from/--wind-speed need --field plume or intermittent")
    args.seeker = args.seeker or ("ste" if plume else "gradient")
    args.sampling = args.sampling or ("moving" if plume else "stop_and_go")
    if args.seek_wind_from is not None and args.seeker not in ("plume", "ste"):
        parser.error(f"--seek-wind-from needs --seeker plume or ste, not {args.seeker}")
    if plume and args.wind_from is None:
        args.wind_from = 270.0
    return args


def mission_settings(args: argparse.Namespace) -> dict:
    """The plan's overrides and the sensors' field for ``args`` (no SITL needed).

    Returns
    -------
    dict
        ``overrides`` (for ``SitlFleet.write_plan``), ``field`` and ``field_args`` (the sensors'
        ``--field`` and further flags), ``noise`` (the sensors'), ``source`` (mission ENU m).
    """
    seeking = dict(SEEKING, seeker=args.seeker, sampling=args.sampling,
                   gamma_m=args.gamma if args.gamma is not None else (1.0 if args.seeker == "gradient" else 20.0))
    out = {"overrides": {"seeking": seeking}, "field": args.field, "field_args": [], "noise": 0.005,
           "source": SOURCE}
    if args.field not in PLUMES:
        return out
    out["noise"] = PLUME_NOISE
    out["field_args"] = ["--wind-from", f"{args.wind_from:g}"]
    if args.wind_speed is not None:
        out["field_args"] += ["--wind-speed", f"{args.wind_speed:g}"]
    downwind_en = -np.array([np.sin(np.radians(args.wind_from)), np.cos(np.radians(args.wind_from))])
    start = np.asarray(SOURCE) + np.array([*(PLUME_START_DOWNWIND_M * downwind_en), -3.0])
    seeking["start_enu_m"] = [round(float(x), 3) for x in start]
    out["overrides"]["formation"] = {"radius_m": PLUME_RADIUS_M}
    if args.seeker in ("plume", "ste"):
        seeking["plume_mode"] = "intermittent" if args.field == "intermittent" else "steady"
        if args.seek_wind_from is not None:
            seeking["wind_from_deg"] = args.seek_wind_from
    if args.seeker == "ste":  # what the operator knows of the sensor (its datasheet), as swarmseek run
        seeking.update(sensor_noise_std=PLUME_NOISE, sensor_detection_floor=0.0)
    return out


def main(argv=None) -> int:
    from mission.core.plan_types import PlanError
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    from mission.sim.sitl_mission import fly_sitl_mission

    args = parse_args(argv)
    setting = mission_settings(args)
    seeking = setting["overrides"]["seeking"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        zenoh = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    cfg = SitlFleetConfig(flavour=args.flavour, n=args.n, speedup=args.speedup).free()
    with tempfile.TemporaryDirectory(prefix="bench-sitl-") as tmp, SitlFleet(cfg) as fleet:
        try:
            plan = fleet.write_plan(Path(tmp) / "plan.toml", zenoh_endpoint=zenoh, overrides=setting["overrides"])
        except PlanError as exc:
            print(f"bench_sitl.py: the plan does not validate: {exc}", file=sys.stderr)
            return 2
        res = fly_sitl_mission(fleet, plan, Path(tmp) / "logs", SOURCE, zenoh=zenoh, timeout_s=args.fly_timeout,
                               noise=setting["noise"], field=setting["field"], field_args=setting["field_args"])
    summary = res.summary or {}
    est = summary.get("estimate_enu")
    wall = res.wall_s
    out = {
        "flavour": args.flavour, "n": args.n, "speedup": args.speedup, "seeker": args.seeker,
        "sampling": args.sampling, "gamma_m": seeking["gamma_m"], "field": args.field,
        "field_args": setting["field_args"], "start_enu_m": seeking["start_enu_m"],
        "seek_wind_from_deg": args.seek_wind_from, "returncode": res.returncode,
        "outcome": summary.get("outcome"), "iterations": summary.get("iterations"),
        "error_m": None if est is None else round(float(np.linalg.norm(np.subtract(est, SOURCE))), 3),
        "estimate_enu": est, "region95_m": summary.get("estimate_region95_m"),
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
