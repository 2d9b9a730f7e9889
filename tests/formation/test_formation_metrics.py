"""formation.metrics: d_min, r_bar, M, M_alpha and the scaled inverse norm."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation import metrics, symmetric_cylinder


def test_known_values_octahedron_scaled():
    r = 2.0 * np.vstack([np.eye(3), -np.eye(3)])
    m = metrics(r)
    assert m.n == 6
    assert m.radius == pytest.approx(2.0)
    assert m.d_min == pytest.approx(2.0 * np.sqrt(2.0))
    np.testing.assert_allclose(m.M, 8.0 * np.eye(3))
    assert m.norm_M_alpha == pytest.approx(0.0, abs=1e-12)
    assert m.norm_scaled_Minv == pytest.approx(1.0)
    assert m.cond_M == pytest.approx(1.0)


def test_anisotropic_formation():
    # triangular bipyramid: M = diag(1.5, 1.5, 2), n D^2 / 3 = 5/3
    ang = 2 * np.pi * np.arange(3) / 3
    r = np.vstack([np.c_[np.cos(ang), np.sin(ang), np.zeros(3)], [[0, 0, 1], [0, 0, -1]]])
    m = metrics(r)
    np.testing.assert_allclose(m.M, np.diag([1.5, 1.5, 2.0]), atol=1e-12)
    assert m.norm_M_alpha == pytest.approx(1.0 / 3.0)
    assert m.norm_scaled_Minv == pytest.approx((5.0 / 3.0) / 1.5)
    assert m.cond_M == pytest.approx(2.0 / 1.5)
    assert m.r_bar_norm == pytest.approx(0.0, abs=1e-12)


def test_planar_formation_is_singular():
    ang = 2 * np.pi * np.arange(5) / 5
    m = metrics(np.c_[np.cos(ang), np.sin(ang), np.zeros(5)])
    assert m.norm_scaled_Minv == float("inf")
    assert m.cond_M == float("inf")


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(min_value=4, max_value=40),
    seed=st.integers(min_value=0, max_value=2**31),
    shift=st.floats(min_value=-5, max_value=5),
)
def test_properties_random(n, seed, shift):
    r = np.random.default_rng(seed).normal(size=(n, 3))
    m = metrics(r)
    np.testing.assert_allclose(m.r_bar, r.sum(axis=0))
    np.testing.assert_allclose(m.M_alpha, m.M - n * m.radius**2 / 3 * np.eye(3))
    eig = np.linalg.eigvalsh(m.M)
    assert m.norm_scaled_Minv == pytest.approx(n * m.radius**2 / 3 / eig[0], rel=1e-9)
    assert m.cond_M >= 1.0
    d = np.linalg.norm(r[:, None] - r[None], axis=2) + np.diag(np.full(n, np.inf))
    assert m.d_min == pytest.approx(d.min())
    # d_min is translation invariant; r_bar is not
    assert metrics(r + shift).d_min == pytest.approx(m.d_min, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("n", [4, 8, 16])
def test_symmetric_is_isotropic(n):
    m = metrics(symmetric_cylinder(n, 5.0))
    assert m.norm_M_alpha < 1e-12 * n * 25
    assert m.norm_scaled_Minv == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (np.zeros((4, 2)), "shape"),
        (np.zeros((1, 3)), "at least 2"),
        (np.array([[0, 0, 0], [1, np.nan, 0]]), "finite"),
        ("abc", "numeric|shape"),
    ],
)
def test_bad_input(bad, match):
    with pytest.raises(ValueError, match=match):
        metrics(bad)
