"""Gradient estimators: exactness on linear fields, Theorem 1/2 bounds on quadratic fields,
batched = single, and the documented errors."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import formation
from estimator import GeometryError, estimator_weights, gradient, gradient_batch

_SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_finite = st.floats(-50.0, 50.0, allow_nan=False)
_vec3 = st.tuples(_finite, _finite, _finite).map(np.array)
_seed = st.integers(0, 2**31 - 1)


def _rotation(seed: int) -> np.ndarray:
    return Rotation.random(random_state=seed).as_matrix()


def _linear(a, g, x):
    return a + x @ g


def _quadratic(a, b, q, x):
    """sigma(x) = a + b.x + x^T Q x; Hessian 2Q."""
    return a + x @ b + np.einsum("...i,ij,...j->...", x, q, x)


def _lipschitz_l(q: np.ndarray) -> float:
    """L of Assumption 1 for a quadratic field.

    The first-order Taylor remainder about c is exactly phi(r, c) = (r - c)^T Q (r - c)
    = 1/2 (r - c)^T H (r - c) with H = 2Q, so |phi| <= ||Q||_2 ||r - c||^2 and the tightest L is
    ||Q||_2 = max |eigenvalue of H| / 2.
    """
    return float(np.max(np.abs(np.linalg.eigvalsh(q))))


_CVT_CACHE: dict = {}


def _cvt(n: int) -> np.ndarray:
    if n not in _CVT_CACHE:
        _CVT_CACHE[n] = formation.cvt_sphere(n, 1.0, seed=0)
    return _CVT_CACHE[n]


@_SETTINGS
@given(seed=_seed, n=st.integers(4, 12), centre=_vec3, grad=_vec3, a=_finite)
def test_cvt_estimator_is_exact_on_linear_fields_for_any_geometry(seed, n, centre, grad, a):
    rng = np.random.default_rng(seed)
    offsets = rng.normal(size=(n, 3)) * rng.uniform(0.5, 5.0, size=(1, 3))
    assume(np.linalg.cond(offsets.T @ offsets) < 1e3)
    positions = centre + offsets
    values = _linear(a, grad, positions)
    est = gradient(positions, values, centre, method="cvt", sigma_c=_linear(a, grad, centre))
    np.testing.assert_allclose(est, grad, atol=1e-7 * (1 + np.abs(grad).max() + abs(a)))


@_SETTINGS
@given(seed=_seed, half=st.integers(2, 10), radius=st.floats(0.1, 20.0), centre=_vec3,
       grad=_vec3, a=_finite, method=st.sampled_from(["cvt", "symmetric"]))
def test_both_estimators_exact_on_linear_fields_on_the_symmetric_formation(
        seed, half, radius, centre, grad, a, method):
    offsets = formation.symmetric_cylinder(2 * half, radius) @ _rotation(seed).T
    positions = centre + offsets
    est = gradient(positions, _linear(a, grad, positions), centre, method=method)  # sigma_c = mean
    np.testing.assert_allclose(est, grad, atol=1e-7 * (1 + np.abs(grad).max() + abs(a) / radius))


@_SETTINGS
@given(seed=_seed, n=st.integers(4, 12), centre=_vec3, grad=_vec3, a=st.floats(-5, 5))
def test_cvt_estimator_with_mean_reading_has_the_documented_bias(seed, n, centre, grad, a):
    """With sigma_c = mean of the readings, on a linear field the estimate is
    grad - M^-1 r_bar (r_bar . grad) / N exactly (zero bias when r_bar = 0)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(size=(n, 3)) + rng.normal(size=3)  # r_bar far from zero
    m = offsets.T @ offsets
    assume(np.linalg.cond(m) < 1e3)
    centred_offsets = offsets - offsets.mean(axis=0)
    assume(np.linalg.cond(centred_offsets.T @ centred_offsets) < 1e3)
    positions = centre + offsets
    # the paper's Remark: uncentred M with sigma_c = mean (the default, centred, is exact)
    paper = estimator_weights(offsets, "cvt", centred=False)
    est = gradient_batch(None, _linear(a, grad, positions), weights=paper)
    r_bar = offsets.sum(axis=0)
    expected = grad - np.linalg.solve(m, r_bar) * (r_bar @ grad) / n
    centred = gradient(positions, _linear(a, grad, positions), centre, method="cvt")
    np.testing.assert_allclose(centred, grad, atol=1e-7 * (1 + np.abs(grad).max() + abs(a)))
    np.testing.assert_allclose(est, expected, atol=1e-7 * (1 + np.abs(grad).max() + abs(a)))


@pytest.mark.parametrize("n", [4, 6, 7, 8, 10, 12])
def test_cvt_estimator_with_mean_reading_on_cvt_formations(n):
    """The CVT formations' r_bar is tiny, so the Remark's sigma_c = mean costs (almost) nothing."""
    offsets = _cvt(n) * 3.0 @ _rotation(n).T
    grad = np.array([0.3, -1.2, 0.7])
    centre = np.array([10.0, -5.0, 2.0])
    positions = centre + offsets
    est = gradient(positions, _linear(50.0, grad, positions), centre, method="cvt")
    r_bar_norm = formation.metrics(offsets).r_bar_norm
    assert np.linalg.norm(est - grad) <= 1e-9 + r_bar_norm**2 * np.linalg.norm(grad)


def _random_quadratic(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal()
    b = rng.normal(size=3)
    q = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 1)
    return a, b, 0.5 * (q + q.T)


@_SETTINGS
@given(seed=_seed, half=st.integers(2, 10), radius=st.floats(0.05, 10.0), centre=_vec3)
def test_theorem1_bound_on_quadratic_fields(seed, half, radius, centre):
    a, b, q = _random_quadratic(seed)
    offsets = formation.symmetric_cylinder(2 * half, radius) @ _rotation(seed + 1).T
    positions = centre + offsets
    est = gradient(positions, _quadratic(a, b, q, positions), centre, method="symmetric")
    exact = b + 2.0 * q @ centre
    err = np.linalg.norm(est - exact)
    bound = 3.0 * _lipschitz_l(q) * radius
    assert err <= bound * (1 + 1e-9) + 1e-9 * (1 + np.linalg.norm(exact))


@_SETTINGS
@given(seed=_seed, n=st.sampled_from([4, 5, 7, 8, 9, 12, 20]), radius=st.floats(0.05, 10.0),
       centre=_vec3)
def test_theorem2_bound_on_quadratic_fields(seed, n, radius, centre):
    a, b, q = _random_quadratic(seed)
    offsets = _cvt(n) * radius @ _rotation(seed + 1).T
    positions = centre + offsets
    sigma_c = _quadratic(a, b, q, centre)
    est = gradient(positions, _quadratic(a, b, q, positions), centre, method="cvt", sigma_c=sigma_c)
    exact = b + 2.0 * q @ centre
    m = offsets.T @ offsets
    bound = np.linalg.norm(np.linalg.inv(m), 2) * n * _lipschitz_l(q) * radius**3
    assert np.linalg.norm(est - exact) <= bound * (1 + 1e-9) + 1e-9 * (1 + np.linalg.norm(exact))


@pytest.mark.parametrize("n", [5, 11, 13])
def test_quadratic_field_error_grows_linearly_with_radius(n):
    """On a quadratic field Theorem 2's error is M^-1 sum phi_i d_i with phi_i ~ D^2 and
    M ~ D^2: linear in D, as the bound ||M^-1|| N L D^3 says (and nonzero for these CVT
    formations, which are not centrally symmetric)."""
    _, b, q = _random_quadratic(11)
    centre = np.array([1.0, -2.0, 0.5])
    errors = []
    for radius in (0.5, 1.0, 2.0):
        positions = centre + _cvt(n) * radius
        values = _quadratic(0.0, b, q, positions)
        est = gradient(positions, values, centre, sigma_c=_quadratic(0.0, b, q, centre))
        errors.append(np.linalg.norm(est - (b + 2.0 * q @ centre)))
    assert errors[0] > 1e-6
    np.testing.assert_allclose(np.array(errors[1:]) / errors[:-1], 2.0, rtol=1e-6)


@pytest.mark.parametrize("method", ["cvt", "symmetric"])
def test_gradient_batch_matches_single_estimates(method):
    rng = np.random.default_rng(3)
    offsets = formation.symmetric_cylinder(8, 2.0) @ _rotation(5).T
    offsets = np.stack([offsets + rng.normal(scale=0.1, size=offsets.shape) for _ in range(6)])
    centres = rng.normal(size=(6, 3))
    values = rng.normal(size=(6, 8))
    batch = gradient_batch(offsets, values, method=method)
    single = np.array([gradient(centres[k] + offsets[k], values[k], centres[k], method=method)
                       for k in range(6)])
    np.testing.assert_allclose(batch, single, rtol=1e-10, atol=1e-12)
    weights = estimator_weights(offsets, method)
    np.testing.assert_allclose(gradient_batch(None, values, method, weights=weights), batch)


def test_symmetric_uses_the_actual_mean_radius():
    """Eq. (3) on actual positions: D is the mean distance of where readings were taken."""
    offsets = formation.symmetric_cylinder(6, 1.0) * 3.0
    est = gradient(offsets, offsets @ np.array([1.0, 2.0, 3.0]), np.zeros(3), method="symmetric")
    np.testing.assert_allclose(est, [1.0, 2.0, 3.0])


def test_geometry_error_is_a_value_error():
    assert issubclass(GeometryError, ValueError)


_PLANAR = np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.5, 0.5, 0]])


@pytest.mark.parametrize(
    ("positions", "values", "centre", "kwargs", "error", "match"),
    [
        (_PLANAR, np.ones(5), np.zeros(3), {}, GeometryError, r"cond\(M\) = inf"),
        (np.c_[_PLANAR[:, :2], 1e-3 * np.arange(5)], np.ones(5), np.zeros(3), {}, GeometryError,
         r"exceeds max_condition = 1e\+03"),
        (np.eye(3), np.ones(3), np.zeros(3), {}, ValueError, "at least 4 readings"),
        (np.ones((5, 2)), np.ones(5), np.zeros(3), {}, ValueError, r"shape \(N, 3\)"),
        (np.eye(4, 3), np.ones(5), np.zeros(3), {}, ValueError, r"values must have shape \(\.\.\., 4\)"),
        (np.eye(4, 3), np.ones(4), np.zeros(2), {}, ValueError, r"centre must have shape \(3,\)"),
        (np.eye(4, 3), np.array([1.0, np.nan, 1, 1]), np.zeros(3), {}, ValueError, "values contains NaN"),
        (np.r_[np.eye(3), [[np.inf, 0, 0]]], np.ones(4), np.zeros(3), {}, ValueError,
         "positions contains NaN"),
        (np.eye(4, 3), np.ones(4), np.zeros(3), {"method": "lsq"}, ValueError, "unknown method 'lsq'"),
        (np.eye(4, 3), np.ones(4), np.zeros(3), {"sigma_c": np.nan}, ValueError, "sigma_c contains NaN"),
        (np.eye(4, 3), np.ones(4), np.zeros(3), {"max_condition": 0.5}, ValueError, "max_condition"),
    ],
)
def test_bad_inputs_raise_documented_errors(positions, values, centre, kwargs, error, match):
    with pytest.raises(error, match=match):
        gradient(positions, values, centre, **kwargs)


def test_max_condition_is_respected():
    offsets = np.diag([1.0, 1.0, 0.1]) @ formation.symmetric_cylinder(6, 1.0).T
    offsets = offsets.T  # cond(M) = 100
    values = offsets @ np.array([1.0, 1.0, 1.0])
    np.testing.assert_allclose(gradient(offsets, values, np.zeros(3), max_condition=200), [1, 1, 1])
    with pytest.raises(GeometryError, match=r"cond\(M\) = 100"):
        gradient(offsets, values, np.zeros(3), max_condition=50)


def test_batch_rejects_one_bad_geometry_among_many():
    good = formation.symmetric_cylinder(6, 1.0)
    bad = np.c_[good[:, :2], np.zeros(6)]
    with pytest.raises(GeometryError, match="degenerate"):
        gradient_batch(np.stack([good, bad, good]), np.ones((3, 6)))
