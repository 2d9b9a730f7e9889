"""plan_transfer: assembly, reconfiguration and return keep separation along the paths."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from formation import cvt_sphere, symmetric_cylinder
from mission.safety.fence import Geofence
from mission.safety.transfer import leg_separation, TransferError, plan_transfer

SEP_M = 2.0


def _sampled_min_separation(plan, samples_per_leg=400):
    """Independent check: sample the plan in time with position_at."""
    best = np.inf
    for t0, t1 in zip(plan.times_s[:-1], plan.times_s[1:]):
        for t in np.linspace(t0, t1, samples_per_leg):
            p = plan.position_at(t)
            d = np.linalg.norm(p[:, None] - p[None, :], axis=-1)
            np.fill_diagonal(d, np.inf)
            best = min(best, d.min())
    return best


def _assert_valid(plan, start, goal, sep):
    assert np.allclose(plan.waypoints_enu[0], start)
    assert np.allclose(plan.waypoints_enu[-1], goal)
    assert np.all(np.diff(plan.times_s) > 0)
    for a, b in zip(plan.waypoints_enu[:-1], plan.waypoints_enu[1:]):
        assert leg_separation(a, b) >= sep * (1 - 1e-9)
    assert plan.min_separation_m >= sep * (1 - 1e-9)
    assert _sampled_min_separation(plan) >= sep * (1 - 1e-9)


def _grid(n, spacing):
    k = int(np.ceil(np.sqrt(n)))
    idx = np.arange(n)
    return np.c_[(idx % k) * spacing, (idx // k) * spacing, np.full(n, 10.0)]


@pytest.mark.parametrize("n, formation", [(4, "cvt"), (7, "cvt"), (8, "cvt"), (4, "symmetric"), (8, "symmetric")])
@pytest.mark.parametrize("strategy", ["auto", "layered"])
def test_assembly_and_return_keep_separation(n, formation, strategy):
    offsets = cvt_sphere(n, 4.0, 0) if formation == "cvt" else symmetric_cylinder(n, 4.0)
    start = _grid(n, 3.0)
    goal = np.array([15.0, 20.0, 25.0]) + offsets
    for a, b in ((start, goal), (goal, start)):
        plan = plan_transfer(a, b, SEP_M, max_speed_m_s=5.0, strategy=strategy)
        if strategy != "auto":
            assert plan.strategy == strategy
        _assert_valid(plan, a, b, SEP_M)


def test_sequenced_assembly_flies_groups_one_after_another():
    start = _grid(8, 3.0)
    goal = np.array([15.0, 20.0, 25.0]) + cvt_sphere(8, 4.0, 0)
    plan = plan_transfer(start, goal, SEP_M, strategy="sequenced")
    assert len(plan.times_s) > 2  # more than one leg: not everyone at once
    _assert_valid(plan, start, goal, SEP_M)


def test_swap_needs_more_than_a_direct_move():
    a = np.array([[0.0, 0.0, 10.0], [10.0, 0.0, 10.0]])
    b = a[::-1].copy()
    with pytest.raises(TransferError, match="no transfer keeping 2 m separation found"):
        plan_transfer(a, b, SEP_M, strategy="direct")
    plan = plan_transfer(a, b, SEP_M)
    assert plan.strategy == "layered"
    _assert_valid(plan, a, b, SEP_M)


def test_leg_durations_respect_the_speed():
    start = _grid(4, 5.0)
    goal = start + [20.0, 0.0, 5.0]
    plan = plan_transfer(start, goal, SEP_M, max_speed_m_s=2.5)
    steps = np.linalg.norm(np.diff(plan.waypoints_enu, axis=0), axis=-1).max(axis=1)
    assert np.allclose(steps / np.diff(plan.times_s), 2.5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(4, 10), radius=st.floats(2.5, 8.0))
def test_reconfiguration_keeps_separation(seed, n, radius):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-20, 20, 3) + [0, 0, 40]
    a = centre + Rotation.random(random_state=seed).apply(cvt_sphere(n, radius, seed % 3))
    b = centre + rng.uniform(-10, 10, 3) + Rotation.random(random_state=seed + 1).apply(cvt_sphere(n, radius, 0))
    # the strategy builds only valid formations (radius >= 2.5 m keeps n <= 10 CVT points over
    # SEP_M apart): a generated case is never dropped
    assert leg_separation(a, a) >= SEP_M and leg_separation(b, b) >= SEP_M
    plan = plan_transfer(a, b, SEP_M, max_speed_m_s=3.0)
    _assert_valid(plan, a, b, SEP_M)


def test_transfer_inside_a_fence_uses_the_band():
    fence = Geofence([(-50, -50), (80, -50), (80, 80), (-50, 80)], 5, 40)
    a = np.array([[0.0, 0.0, 10.0], [10.0, 0.0, 10.0]])
    plan = plan_transfer(a, a[::-1].copy(), SEP_M, fence=fence)
    assert np.all(fence.contains(plan.waypoints_enu.reshape(-1, 3)))
    _assert_valid(plan, a, a[::-1], SEP_M)


@pytest.mark.parametrize(
    "start, goal, kwargs, exc, match",
    [
        ([[0, 0, 10], [1, 0, 10]], [[0, 0, 10], [5, 0, 10]], {}, TransferError, "start positions are only 1.00 m"),
        ([[0, 0, 10], [5, 0, 10]], [[0, 0, 10], [0, 1, 10]], {}, TransferError, "goal positions"),
        ([[0, 0, 10]], [[0, 0]], {}, ValueError, "both be"),
        ([[0, 0, np.nan]], [[0, 0, 1]], {}, ValueError, "finite"),
        ([[0, 0, 10]], [[0, 0, 1]], {"strategy": "teleport"}, ValueError, "unknown strategy"),
        ([[0, 0, 10]], [[0, 0, 1]], {"max_speed_m_s": 0}, ValueError, "max_speed_m_s"),
        ([[0, 0, 10]], [[0, 0, 100]], {"fence": Geofence([(-5, -5), (5, -5), (0, 5)], 0, 50)},
         TransferError, "not all inside the geofence"),
    ],
)
def test_plan_transfer_rejects_bad_input(start, goal, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        plan_transfer(np.array(start, float), np.array(goal, float), SEP_M, **kwargs)


def test_position_at_interpolates_and_clamps():
    a = np.array([[0.0, 0.0, 10.0], [10.0, 0.0, 10.0]])
    plan = plan_transfer(a, a + [0, 10, 0], SEP_M, max_speed_m_s=2.0)
    assert plan.duration_s == pytest.approx(5.0)
    assert np.allclose(plan.position_at(2.5), a + [0, 5, 0])
    assert np.allclose(plan.position_at(-1), a) and np.allclose(plan.position_at(99), a + [0, 10, 0])
