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

import numpy as np

from mission.flight.faults.loss import reformed_offsets
from mission.flight.targets import formation_offsets
from mission.safety.envelope import SafetyEnvelope, pairwise_path_separation
from mission.safety.fence import Geofence
from mission.safety.gate import SafetyGate

SEP_M, SPEED_M_S, DT_S, MAX_TICKS = 1.5, 3.0, 0.1, 900
CENTRE = np.array([0.0, 0.0, 15.0])
BOX = np.array([(-50.0, -50.0), (50.0, -50.0), (50.0, 50.0), (-50.0, 50.0)])


class _Streamer:
    rate_hz = 10.0

    def set_target(self, sysid, p, yaw_rad=None):
        pass

    def remove(self, sysid):
        pass

    def tick(self):
        return 0


class _Clock:
    t = 0.0

    def time(self):
        return self.t


def fly(starts, goals, poly=BOX):
    """Ticks until every setpoint is at its goal (None: not within ``MAX_TICKS``); every batch checked."""
    env = SafetyEnvelope(Geofence(poly, 5.0, 60.0), max_speed_m_s=SPEED_M_S, min_separation_m=SEP_M,
                         formation_radius_m=0.0)
    gate = SafetyGate(_Streamer(), _Clock(), SPEED_M_S, envelope=env, max_vertical_speed_m_s=1.0)
    n = len(starts)
    for i, p in enumerate(starts):
        gate.add(i, p)
    gate.set_goals({i: np.asarray(g, dtype=float) for i, g in enumerate(goals)})
    for tick in range(MAX_TICKS):
        prev = np.array([gate.setpoint(i) for i in range(n)])
        gate.step(DT_S)
        cur = np.array([gate.setpoint(i) for i in range(n)])
        start = np.linalg.norm(prev[:, None] - prev[None], axis=-1) + np.eye(n) * 1e9
        if not (np.all(pairwise_path_separation(prev, cur) >= np.minimum(SEP_M, start) * (1 - 1e-9))
                and np.all(env.fence.contains(cur))
                and np.all(np.linalg.norm(cur - prev, axis=1) <= SPEED_M_S * DT_S * (1 + 1e-9))):
            raise AssertionError(f"unsafe batch at tick {tick}")
        if all(gate.at_goal(i) for i in range(n)):
            return tick + 1
    return None


def _rotation(yaw_rad, tilt_rad):
    cy, sy, ct, st = np.cos(yaw_rad), np.sin(yaw_rad), np.cos(tilt_rad), np.sin(tilt_rad)
    return np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])


def reform_case(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 8))
    lost = int(rng.integers(1, n + 1))
    offsets = formation_offsets("cvt", n, 2.0)
    new, _ = reformed_offsets("cvt", {s + 1: offsets[s] for s in range(n)}, [lost], 2.0)
    rot = _rotation(rng.uniform(0, 2 * np.pi), rng.uniform(-0.5, 0.5))
    survivors = [s for s in range(1, n + 1) if s != lost]
    return fly([CENTRE + offsets[s - 1] for s in survivors], [CENTRE + rot @ new[s] for s in survivors])


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
