"""Vehicles flown straight to their goals through the real safety gate and envelope, every batch
checked (separation, fence, speed): shared by tests/mission/safety/test_separation_liveness.py and
benchmarks/bench_separation_liveness.py."""
from __future__ import annotations

import numpy as np

from mission.flight.faults.loss import reformed_offsets
from mission.flight.targets import formation_offsets
from mission.safety.envelope import SafetyEnvelope, pairwise_path_separation
from mission.safety.fence import Geofence
from mission.safety.gate import SafetyGate

SEP_M = 1.5
SPEED_M_S = 3.0
DT_S = 0.1
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


def fly(starts, goals, max_ticks: int = 600, poly=BOX):
    """``(ticks, gate)``: ticks until every setpoint is at its goal (None: not within ``max_ticks``);
    every batch sent is checked (AssertionError naming the tick): every pair at the separation (or at
    its start distance for a pair that started closer), inside the fence, within the speed limit."""
    env = SafetyEnvelope(Geofence(poly, 5.0, 60.0), max_speed_m_s=SPEED_M_S, min_separation_m=SEP_M,
                         formation_radius_m=0.0)
    gate = SafetyGate(_Streamer(), _Clock(), SPEED_M_S, envelope=env, max_vertical_speed_m_s=1.0)
    n = len(starts)
    for i, p in enumerate(starts):
        gate.add(i, p)
    gate.set_goals({i: np.asarray(g, dtype=float) for i, g in enumerate(goals)})
    for tick in range(max_ticks):
        prev = np.array([gate.setpoint(i) for i in range(n)])
        gate.step(DT_S)
        cur = np.array([gate.setpoint(i) for i in range(n)])
        start = np.linalg.norm(prev[:, None] - prev[None], axis=-1) + np.eye(n) * 1e9
        path = pairwise_path_separation(prev, cur)
        assert np.all(path >= np.minimum(SEP_M, start) * (1 - 1e-9)), (tick, path.min())
        assert np.all(env.fence.contains(cur)), tick
        assert np.all(np.linalg.norm(cur - prev, axis=1) <= SPEED_M_S * DT_S * (1 + 1e-9)), tick
        if all(gate.at_goal(i) for i in range(n)):
            return tick + 1, gate
    return None, gate


def _rotation(yaw_rad, tilt_rad):
    cy, sy, ct, st = np.cos(yaw_rad), np.sin(yaw_rad), np.cos(tilt_rad), np.sin(tilt_rad)
    return np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])


def reformation_case(seed: int) -> tuple[int, int, list, list]:
    """``(n, lost, starts, goals)``: a radius-2 m CVT of ``n`` (5-7) re-formed around vehicle ``lost``
    with its new slots rotated (as ``clear_offsets`` does), drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 8))
    lost = int(rng.integers(1, n + 1))
    offsets = formation_offsets("cvt", n, 2.0)
    new, _ = reformed_offsets("cvt", {s + 1: offsets[s] for s in range(n)}, [lost], 2.0)
    rot = _rotation(rng.uniform(0, 2 * np.pi), rng.uniform(-0.5, 0.5))
    survivors = [s for s in range(1, n + 1) if s != lost]
    return n, lost, [CENTRE + offsets[s - 1] for s in survivors], [CENTRE + rot @ new[s] for s in survivors]
