"""Minimum-travel slot assignment (with rotation) and reconfiguration after a vehicle loss."""
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from formation import (
    assign_slots,
    constrained_centroids,
    cvt_sphere,
    kabsch_rotation,
    reconfigure,
    symmetric_cylinder,
)


def _brute_force(x, s):
    return min(
        float(np.sum((x - s[list(p)]) ** 2)) for p in itertools.permutations(range(len(s)), len(x))
    )


@settings(max_examples=25, deadline=None)
@given(m=st.integers(1, 6), extra=st.integers(0, 2), seed=st.integers(0, 2**31))
def test_assignment_is_optimal_against_brute_force(m, extra, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(m, 3)) * 5
    s = rng.normal(size=(m + extra, 3)) * 5
    perm, same = assign_slots(x, s)
    assert np.array_equal(same, s)
    assert len(set(perm.tolist())) == m
    assert float(np.sum((x - s[perm]) ** 2)) == pytest.approx(_brute_force(x, s), rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_recovers_a_rotated_formation(seed):
    s = cvt_sphere(9, radius=3.0)
    rot = Rotation.random(random_state=seed).as_matrix()
    order = np.random.default_rng(seed).permutation(9)
    x = (s @ rot.T)[order]
    perm, rotated = assign_slots(x, s, allow_rotation=True)
    np.testing.assert_allclose(rotated[perm], x, atol=1e-9)
    # the rotated slot set is the same formation: same pairwise distances
    d = lambda a: np.linalg.norm(a[:, None] - a[None], axis=2)  # noqa: E731
    np.testing.assert_allclose(np.sort(d(rotated).ravel()), np.sort(d(s).ravel()), atol=1e-9)


@pytest.mark.parametrize("seed", [3, 4])
def test_rotation_never_increases_travel(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(8, 3)) * 4 + np.array([10.0, -5.0, 2.0])
    s = symmetric_cylinder(8, 4.0) + np.array([10.0, -5.0, 2.0])
    p0, _ = assign_slots(x, s)
    p1, rs = assign_slots(x, s, allow_rotation=True, centre=[10.0, -5.0, 2.0])
    assert np.sum((x - rs[p1]) ** 2) <= np.sum((x - s[p0]) ** 2) + 1e-9
    np.testing.assert_allclose(np.linalg.norm(rs - [10.0, -5.0, 2.0], axis=1), 4.0)


def test_kabsch_is_a_proper_rotation():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(10, 3))
    b = -a  # a point reflection is not a rotation: det must stay +1
    r = kabsch_rotation(a, b)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("n", [5, 6, 8])
@pytest.mark.parametrize("lost", [0, "mask", "last"])
def test_reconfigure_after_loss(n, lost):
    radius = 4.0
    current = cvt_sphere(n, radius) + np.random.default_rng(n).normal(scale=0.05, size=(n, 3))
    if lost == "mask":
        lost = np.zeros(n, dtype=bool)
        lost[1] = True
        gone = 1
    elif lost == "last":
        lost, gone = n - 1, n - 1
    else:
        gone = lost
    rec = reconfigure(current, lost, radius)
    m = n - 1
    assert rec.slots.shape == (m, 3)
    assert gone not in rec.survivors.tolist() and len(rec.survivors) == m
    np.testing.assert_allclose(np.linalg.norm(rec.slots, axis=1), radius, rtol=1e-12)
    assert sorted(rec.assignment.tolist()) == list(range(m))
    # slots form a CVT (a rotated one is still a CVT)
    unit = rec.slots / radius
    assert np.max(np.linalg.norm(constrained_centroids(unit) - unit, axis=1)) < 1e-8
    xs = current[rec.survivors]
    np.testing.assert_allclose(rec.travel_m, np.linalg.norm(rec.slots[rec.assignment] - xs, axis=1))
    assert rec.total_sq_travel_m2 == pytest.approx(np.sum(rec.travel_m**2))
    # optimal for the chosen slots (brute force over all (n-1)! assignments)
    assert rec.total_sq_travel_m2 == pytest.approx(_brute_force(xs, rec.slots), rel=1e-9)
    np.testing.assert_allclose(rec.rotation @ rec.rotation.T, np.eye(3), atol=1e-10)


def test_reconfigure_travel_is_small_compared_to_radius():
    radius = 5.0
    current = cvt_sphere(12, radius)
    rec = reconfigure(current, 4, radius)
    # losing one of 12 needs only a local rearrangement, much less than a diameter each
    assert rec.travel_m.max() < radius
    assert math.sqrt(rec.total_sq_travel_m2 / 11) < 0.5 * radius


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"lost": [0, 1]}, "at least 4 survivors"),
        ({"lost": 7}, "out of range"),
        ({"lost": np.zeros(3, dtype=bool)}, "mask must have shape"),
        ({"lost": 1.5}, "integers"),
        ({"lost": True}, "index"),
        ({"lost": 0, "radius": 0.0}, "radius"),
    ],
)
def test_reconfigure_bad_arguments(kwargs, match):
    current = cvt_sphere(5, 2.0)
    kwargs.setdefault("radius", 2.0)
    with pytest.raises(ValueError, match=match):
        reconfigure(current, **kwargs)


def test_assign_bad_arguments():
    with pytest.raises(ValueError, match="more vehicles"):
        assign_slots(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="shape"):
        assign_slots(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        assign_slots(np.full((2, 3), np.inf), np.zeros((3, 3)))
