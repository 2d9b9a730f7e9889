"""A re-formation's transfer when no plan keeps clear of a lost vehicle still flying
(``mission.flight.obstacles.plan_survivor_transfer``): the survivors still keep their separation
between themselves, instead of flying straight under the safety envelope, which on ArduCopter
SITL held two crossing survivors against each other until the mission aborted (32 s, the
formation never settled: tests/sitl/test_sitl_faults_ardupilot_link.py, docs/faults.md)."""
from __future__ import annotations

import numpy as np
import pytest

from mission.flight.obstacles import plan_clear_transfer, plan_survivor_transfer
from mission.safety.transfer import TransferError

_SEP_M = 1.5


def _min_pair_distance(tp, samples: int = 200) -> float:
    """Closest approach of any two movers along the plan's straight legs (sampled)."""
    wps = np.asarray(tp.waypoints_enu, dtype=float)
    best = np.inf
    for a, b in zip(wps[:-1], wps[1:]):
        for u in np.linspace(0.0, 1.0, samples):
            p = a + u * (b - a)
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
            best = min(best, float(d[np.triu_indices(len(p), 1)].min()))
    return best


def test_an_obstacle_on_a_goal_leaves_a_plan_that_keeps_the_survivors_apart():
    # two vehicles swap sides; the lost one hovers exactly where one of them must go
    start = np.array([[-5.0, 0.0, 12.0], [5.0, 0.0, 12.0]])
    goal = start[::-1].copy()
    obstacle = np.array([[5.0, 0.0, 12.0]])
    with pytest.raises(TransferError, match="lost vehicles still flying"):
        plan_clear_transfer(start, goal, obstacle, _SEP_M, 2.0)
    tp, why = plan_survivor_transfer(start, goal, obstacle, _SEP_M, 2.0)
    assert why is not None and "lost vehicles still flying" in why
    wps = np.asarray(tp.waypoints_enu)
    assert np.allclose(wps[0], start) and np.allclose(wps[-1], goal)
    assert _min_pair_distance(tp) >= _SEP_M - 1e-6  # not straight through each other


def test_a_clear_plan_is_kept_and_said_clear():
    start = np.array([[-5.0, 0.0, 12.0], [5.0, 0.0, 12.0]])
    goal = start[::-1].copy()
    tp, why = plan_survivor_transfer(start, goal, np.array([[0.0, 0.0, 12.0]]), _SEP_M, 2.0)
    assert why is None and np.asarray(tp.waypoints_enu).shape[1] == 2


def test_without_obstacles_a_failure_is_the_planners():
    start = np.array([[-5.0, 0.0, 12.0], [5.0, 0.0, 12.0]])
    goal = np.array([[0.0, 0.0, 12.0], [0.5, 0.0, 12.0]])  # goals closer than the separation
    with pytest.raises(TransferError):
        plan_survivor_transfer(start, goal, np.empty((0, 3)), _SEP_M, 2.0)
