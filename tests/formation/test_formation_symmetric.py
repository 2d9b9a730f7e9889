"""Symmetric Cylindrical formation (paper eq. 1) and its exact properties (eq. 2)."""
import math

import numpy as np
import pytest

from formation import THETA_F_RAD, metrics, symmetric_cylinder, symmetric_cylinder_dmin


@pytest.mark.parametrize("n", [4, 6, 8, 10, 20, 30, 64])
@pytest.mark.parametrize("radius", [1.0, 4.0, 7.0])
def test_sum_zero_and_m_isotropic(n, radius):
    r = symmetric_cylinder(n, radius)
    assert r.shape == (n, 3)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), radius, rtol=1e-14)
    np.testing.assert_allclose(r.sum(axis=0), 0.0, atol=1e-13 * n * radius)
    np.testing.assert_allclose(r.T @ r, n * radius**2 / 3.0 * np.eye(3), atol=1e-13 * n * radius**2)


@pytest.mark.parametrize("n", [4, 8, 12])
def test_follows_equation_1(n):
    r = symmetric_cylinder(n, 2.0)
    i = np.arange(1, n + 1)
    theta = np.arccos(r[:, 2] / 2.0)
    expected = np.where(i % 2 == 1, THETA_F_RAD, math.pi - THETA_F_RAD)
    np.testing.assert_allclose(theta, expected, atol=1e-12)
    phi = np.arctan2(r[:, 1], r[:, 0])
    dphi = np.angle(np.exp(1j * (phi - 2 * math.pi * i / n)))  # wrapped difference
    np.testing.assert_allclose(dphi, 0.0, atol=1e-12)
    assert math.isclose(math.sin(THETA_F_RAD), math.sqrt(2.0 / 3.0), rel_tol=1e-15)


@pytest.mark.parametrize("n", [4, 6, 8, 10, 20, 40])
def test_dmin_closed_form_matches_positions(n):
    assert metrics(symmetric_cylinder(n, 3.0)).d_min == pytest.approx(
        symmetric_cylinder_dmin(n, 3.0), rel=1e-12
    )


@pytest.mark.parametrize("n", [6, 8, 10, 20])
def test_paper_dmin_formula_underestimates(n):
    """The paper's 2 D cos(theta_F) sin(2 pi / N) is below the true minimum distance."""
    paper = 2.0 * math.cos(THETA_F_RAD) * math.sin(2.0 * math.pi / n)
    assert metrics(symmetric_cylinder(n)).d_min > paper * 1.3


@pytest.mark.parametrize(
    ("n", "match"),
    [(2, "n >= 4"), (0, "n >= 4"), (5, "even"), (7, "even"), (6.0, "integer"), (True, "integer")],
)
def test_bad_n(n, match):
    with pytest.raises(ValueError, match=match):
        symmetric_cylinder(n)


@pytest.mark.parametrize("radius", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_radius(radius):
    with pytest.raises(ValueError, match="radius"):
        symmetric_cylinder(8, radius)
