"""Cost of one WGS-84 conversion: pymap3d's array functions against the scalar TangentFrame.

Run from the repository root::

    python benchmarks/bench_geodesy.py [--calls 20000]

Prints microseconds per call (wall time, best of 5) for one point at a time, the way the ground
station converts each sensor reading (geodetic -> ENU) and the mock autopilot each reported
position (NED -> geodetic):

1. :func:`formation.geodesy.geodetic_to_enu` (pymap3d on 0-d arrays) and
   :meth:`formation.geodesy.TangentFrame.geodetic_to_enu_m` (the same maths on floats);
2. :func:`formation.geodesy.enu_to_geodetic` and :meth:`~formation.geodesy.TangentFrame.ned_to_geodetic`;

and what each costs per second at N vehicles (``--vehicles``, default 100) sending readings
at 20 Hz and reporting positions at 50 Hz.
"""
from __future__ import annotations

import argparse
import os
import sys
import timeit

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import numpy as np  # noqa: E402

from formation.geodesy import TangentFrame, enu_to_geodetic, geodetic_to_enu  # noqa: E402

ORIGIN = (45.19, 5.72, 230.0)


def _best_us(fn, calls: int) -> float:
    return min(timeit.repeat(fn, number=calls, repeat=5)) / calls * 1e6


def main(argv=None) -> int:
    """Print the per-call costs; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20000, help="calls per timing (default 20000)")
    parser.add_argument("--vehicles", type=int, default=100, help="fleet size for the per-second cost")
    args = parser.parse_args(argv)
    frame = TangentFrame(ORIGIN)
    enu = np.array([100.0, 200.0, 10.0])
    rows = [
        ("geodetic->ENU  pymap3d geodetic_to_enu", 20, lambda: geodetic_to_enu(45.2, 5.73, 240.0, ORIGIN)),
        ("geodetic->ENU  TangentFrame.geodetic_to_enu_m", 20, lambda: frame.geodetic_to_enu_m(45.2, 5.73, 240.0)),
        ("ENU->geodetic  pymap3d enu_to_geodetic", 50, lambda: enu_to_geodetic(enu, ORIGIN)),
        ("NED->geodetic  TangentFrame.ned_to_geodetic", 50, lambda: frame.ned_to_geodetic(200.0, 100.0, -10.0)),
    ]
    print(f"{'conversion':48s} {'us/call':>8s} {'ms per s at N=' + str(args.vehicles):>18s}")
    for name, rate_hz, fn in rows:
        us = _best_us(fn, args.calls)
        print(f"{name:48s} {us:8.2f} {us * rate_hz * args.vehicles / 1e3:18.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
