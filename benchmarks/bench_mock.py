"""Benchmark of the mock fleet: vehicles kept in real time, and the highest speed-up for 8.

Run from the repository root::

    python benchmarks/bench_mock.py            # full run (~2 minutes)
    python benchmarks/bench_mock.py --quick    # fewer points

Part 1 runs N vehicles at speed-up 1 (50 Hz physics, default telemetry streamed over UDP to a
sink process that drains every port, sensors sampling sigma1 at 10 Hz, no zenoh) and reports the
fleet thread's busy fraction, the worst lag behind the clock and dropped physics steps. A fleet
keeps real time when it drops no step and its lag stays under 0.1 s.

Part 2 runs 8 vehicles at increasing speed-ups and reports the simulated-time rate achieved.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from sitl_mock.fields_gaussian import sigma1
from sitl_mock.fleet import PHYSICS_RATE_HZ, MockFleet  # noqa: E402

_SINK = textwrap.dedent("""
    import selectors, socket, sys
    base, n = int(sys.argv[1]), int(sys.argv[2])
    sel = selectors.DefaultSelector()
    for i in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        s.bind(("127.0.0.1", base + i)); s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)
    print("ready", flush=True)
    while True:
        for key, _ in sel.select(1.0):
            try:
                while True:
                    key.fileobj.recv(65536)
            except BlockingIOError:
                pass
""")


def _run(n: int, speedup: float, seconds: float, base: int) -> dict:
    sink = subprocess.Popen([sys.executable, "-c", _SINK, str(base), str(n)], stdout=subprocess.PIPE,
                            text=True)
    try:
        sink.stdout.readline()
        fleet = MockFleet(n, personality="px4", speedup=speedup, field=sigma1(), udp_base_port=base,
                          udp_bind_base_port=base + 1000, tcp_base_port=0, zenoh=False)
        worst_lag = 0.0
        with fleet:
            time.sleep(1.0)  # warm-up
            ticks0, busy0, wall0 = (fleet.stats["ticks"], fleet.stats["busy_wall_s"],
                                    fleet.stats["wall_s"])
            cpu0 = time.process_time()
            t_end = time.monotonic() + seconds
            while time.monotonic() < t_end:
                time.sleep(0.05)
                worst_lag = max(worst_lag, fleet.stats["lag_s"])
            stats = dict(fleet.stats)
            cpu = time.process_time() - cpu0
        wall = stats["wall_s"] - wall0
        tx = sum(v.counters.get("tx_frames", 0) for v in fleet.vehicles)
        return {
            "n": n, "speedup": speedup, "wall_s": wall,
            "sim_rate": (stats["ticks"] - ticks0) / PHYSICS_RATE_HZ / wall,
            "busy": (stats["busy_wall_s"] - busy0) / wall, "cpu": cpu / wall,
            "lag_s": worst_lag, "dropped": stats["dropped_steps"], "errors": len(fleet.errors),
            "tx_per_s": tx / (stats["wall_s"]),
        }
    finally:
        sink.kill()
        sink.wait()


def main() -> int:
    """Run both parts and print a table per part."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer, shorter points")
    ap.add_argument("--base-port", type=int, default=31000)
    args = ap.parse_args()
    seconds = 4.0 if args.quick else 8.0
    counts = (50, 100, 150) if args.quick else (25, 50, 100, 150, 200, 255)
    speedups = (10, 30, 60) if args.quick else (10, 20, 30, 40, 50, 60, 80, 100)

    print(f"Part 1: vehicles in real time (50 Hz physics, default telemetry over UDP, sensors 10 Hz), "
          f"{seconds:g} s per point")
    print(f"{'vehicles':>8} {'busy':>6} {'cpu':>6} {'sim/wall':>9} {'max lag s':>9} {'dropped':>8} "
          f"{'frames/s':>9}  real time?")
    best_n = 0
    for n in counts:
        r = _run(n, 1.0, seconds, args.base_port)
        ok = r["dropped"] == 0 and r["lag_s"] < 0.1 and r["errors"] == 0
        best_n = n if ok else best_n
        print(f"{n:>8} {r['busy']:>6.2f} {r['cpu']:>6.2f} {r['sim_rate']:>9.3f} {r['lag_s']:>9.3f} "
              f"{r['dropped']:>8} {r['tx_per_s']:>9.0f}  {'yes' if ok else 'NO'}")
    print(f"=> largest fleet kept in real time: {best_n} vehicles (target 100; 255 system ids "
          f"is the most one fleet can have)")
    cost = r["cpu"] / r["n"]
    print(f"=> CPU cost at {r['n']} vehicles: {cost * 1e6:.0f} us of CPU per vehicle per second, "
          f"i.e. about {1.0 / cost:.0f} vehicles per fully available core\n")

    print(f"Part 2: 8 vehicles at increasing speed-up, {seconds:g} s per point")
    print(f"{'speedup':>8} {'achieved':>9} {'busy':>6} {'cpu':>6} {'max lag s':>9} {'dropped':>8}  keeps up?")
    best_s, failed, estimates = 0.0, False, []
    for s in speedups:
        r = _run(8, float(s), seconds, args.base_port)
        ok = r["dropped"] == 0 and r["sim_rate"] >= 0.95 * s and r["errors"] == 0
        if ok and not failed:
            best_s = s
        failed = failed or not ok
        if r["cpu"] > 0:
            estimates.append(r["sim_rate"] / r["cpu"])
        print(f"{s:>8} {r['sim_rate']:>9.1f} {r['busy']:>6.2f} {r['cpu']:>6.2f} {r['lag_s']:>9.3f} "
              f"{r['dropped']:>8}  {'yes' if ok else 'NO'}")
    print(f"=> highest speed-up kept by 8 vehicles (every lower point kept up too): {best_s:g}x")
    if estimates:
        print(f"=> CPU-bound estimate for 8 vehicles on a fully available core: "
              f"~{float(np.median(estimates)):.0f}x (achieved rate / CPU fraction, median)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
