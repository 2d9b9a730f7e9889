"""How often the safety envelope lets vehicles flown straight to crossing goals arrive (docs/safety.md).

Each case flies the vehicles of a radius-2 m CVT formation (separation 1.5 m, 3 m/s, 10 Hz) straight
to their goals through :class:`mission.safety.gate.SafetyGate` and the envelope, checking every batch
(separation on the paths, fence, speed), for at most 90 s of the gate's time:

* ``reform``: 5-7 vehicles, one lost, the survivors' re-formed slots (``reformed_offsets``) rotated
  about the centre by a random yaw and tilt (as ``clear_offsets`` does around a lost vehicle);
* ``permute``: 4-8 vehicles sent to a random permutation of their slots; every third case inside
  a fence 0.3 m wider than the formation.

Prints, per kind, the cases that never arrived and the ticks (0.1 s) the others took::

    PYTHONPATH=. python benchmarks/bench_separation_liveness.py [--cases 60]
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mission.flight.targets import formation_offsets  # noqa: E402
from tests.support.separation_flight import BOX, CENTRE, fly as _fly, reformation_case  # noqa: E402

MAX_TICKS = 900


def fly(starts, goals, poly=BOX):
    """Ticks until every setpoint is at its goal (None: not within ``MAX_TICKS``); every batch checked."""
    return _fly(starts, goals, MAX_TICKS, poly)[0]


def reform_case(seed):
    return fly(*reformation_case(seed)[2:])


def permute_case(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 9))
    offsets = formation_offsets("cvt", n, 2.0)
    perm = rng.permutation(n)
    poly = np.array([(-2.3, -2.3), (2.3, -2.3), (2.3, 2.3), (-2.3, 2.3)]) if seed % 3 == 0 else BOX
    return fly([CENTRE + o for o in offsets], [CENTRE + offsets[p] for p in perm], poly)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=60, help="cases per kind (default 60)")
    args = parser.parse_args()
    for kind, case in (("reform", reform_case), ("permute", permute_case)):
        ticks = [case(seed) for seed in range(args.cases)]
        done = [t for t in ticks if t is not None]
        stuck = [seed for seed, t in enumerate(ticks) if t is None]
        print(f"{kind}: {len(stuck)} of {args.cases} never arrived {stuck}; the others in "
              f"{np.median(done) if done else float('nan'):.0f} ticks (median), {max(done, default=0)} at most")


if __name__ == "__main__":
    main()
