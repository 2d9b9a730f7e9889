"""Robust gradient estimator: weighted Theorem 2, noise estimation, fault identification."""
from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from estimator import GeometryError, estimator_weights, gradient, gradient_batch
from estimator.robust_faults import REASONS
from estimator.robust import RobustGradientEstimator
from estimator.robust_wls import weighted_gradient
from formation import cvt_sphere
from sitl_mock.fields_gaussian import sigma2

N = 8


@functools.lru_cache(maxsize=None)
def _unit_cvt(n):
    return cvt_sphere(n, 1.0, 0)


def _formation(n=N, radius=1.0, seed=0):
    return Rotation.random(random_state=seed).apply(radius * _unit_cvt(n))


# ---------------------------------------------------------------- the weighted estimator

@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(4, 12), radius=st.floats(0.5, 10.0))
def test_equal_weights_weighted_mean_is_theorem_2(seed, n, radius):
    rng = np.random.default_rng(seed)
    off = _formation(n, radius, seed) + rng.normal(0, 0.05 * radius, (n, 3))  # actual positions
    centre = rng.uniform(-30, 30, 3)
    values = rng.normal(0, 1, n)
    ours = weighted_gradient(off, values, centre="weighted_mean")
    # the paper's Remark (uncentred M, sigma_c = mean of the readings)
    theirs = gradient_batch(None, values, weights=estimator_weights(off, "cvt", centred=False))
    assert np.allclose(ours, theirs, rtol=1e-9, atol=1e-12)
    # the default Theorem 2 without sigma_c is least squares with an intercept: the "fit" mode
    fit = weighted_gradient(off, values, centre="fit")
    assert np.allclose(fit, gradient(centre + off, values, centre, method="cvt"), rtol=1e-9, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), drop=st.integers(0, 4))
def test_fit_is_exact_on_linear_fields_for_any_weights_and_subset(seed, drop):
    rng = np.random.default_rng(seed)
    off = _formation(N, 2.0, seed)
    grad = rng.normal(0, 1, 3)
    values = 3.0 + off @ grad
    w = rng.uniform(0.01, 10, N)
    w[rng.choice(N, drop, replace=False)] = 0.0
    rt = off - (w @ off) / w.sum()
    if np.linalg.cond((w[:, None] * rt).T @ rt) > 1e3:  # e.g. 4 coplanar sensors left: refused, not guessed
        with pytest.raises(GeometryError, match="degenerate"):
            weighted_gradient(off, values, w)
        return
    assert np.allclose(weighted_gradient(off, values, w), grad, atol=1e-9)


def test_weighted_mean_is_biased_after_dropping_a_sensor_but_fit_is_not():
    off = _formation()
    grad = np.array([0.3, -0.2, 0.5])
    values = 1.0 + off @ grad
    w = np.ones(N)
    w[0] = 0.0
    assert np.allclose(weighted_gradient(off, values, w, centre="fit"), grad)
    assert not np.allclose(weighted_gradient(off, values, w, centre="weighted_mean"), grad, atol=1e-3)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        ({"offsets": np.zeros((8, 2))}, ValueError, r"shape \(\.\.\., N, 3\)"),
        ({"values": np.zeros(7)}, ValueError, "values must have shape"),
        ({"values": np.r_[np.zeros(7), np.nan]}, ValueError, "finite"),
        ({"weights": -np.ones(8)}, ValueError, "weights must be"),
        ({"weights": np.r_[np.ones(3), np.zeros(5)]}, GeometryError, "at least 4 sensors"),
        ({"offsets": np.c_[np.random.default_rng(0).normal(size=(8, 2)), np.zeros(8)]}, GeometryError, "cond"),
        ({"centre": "median"}, ValueError, "unknown centre mode"),
    ],
)
def test_weighted_gradient_rejects_bad_input(kwargs, exc, match):
    args = {"offsets": _formation(), "values": np.zeros(8)}
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        weighted_gradient(**args)


# ---------------------------------------------------------------- the online estimator

def _run(fault=None, faulty=3, updates=300, seed=0, radius=1.0, std=0.1, window=100, n=N):
    """A slow seek on sigma_2 with noisy readings; returns the estimator and gradient errors."""
    rng = np.random.default_rng(seed)
    field = sigma2()
    off = _formation(n, radius, seed)
    est = RobustGradientEstimator(n, window=window)
    stds = np.full(n, std)
    if fault == "noisy":
        stds[faulty] = 5 * std
    centre = np.array([8.0, -6.0, 3.0])
    errors = []
    for _ in range(updates):
        y = field.value(centre + off) + rng.normal(0, 1, n) * stds
        if fault == "stuck":
            y[faulty] = 0.61
        elif fault == "biased":
            y[faulty] += 5 * std
        elif fault == "spiking" and rng.random() < 0.1:
            y[faulty] += 50 * std
        g = est.update(off, y)
        errors.append(np.linalg.norm(g - field.gradient(centre)))
        step = g * min(1.0, 0.1 / max(np.linalg.norm(g), 1e-12))
        centre = centre + step
    return est, np.asarray(errors)


@pytest.mark.parametrize("fault", ["stuck", "biased", "spiking", "noisy"])
@pytest.mark.parametrize("faulty", [0, 5])
def test_the_faulty_sensor_is_named_with_its_reason(fault, faulty):
    est, _ = _run(fault, faulty, seed=faulty + 1)
    reasons = {s.index: s.reason for s in est.suspects}
    assert reasons.get(faulty) == fault
    # nobody else is excluded or called stuck/biased
    assert not any(r in ("stuck", "biased") for i, r in reasons.items() if i != faulty)
    if fault in ("stuck", "biased"):
        assert est.excluded.tolist() == [i == faulty for i in range(N)]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_no_suspect_when_every_sensor_is_healthy(seed):
    est, _ = _run(None, seed=seed)
    assert est.suspects == []
    assert not est.excluded.any()


def test_noise_estimates_find_the_noisier_sensor():
    est, _ = _run("noisy", faulty=2, updates=400, seed=4)
    std = est.noise_std_estimates
    assert std[2] == pytest.approx(0.5, rel=0.3)
    assert np.all(np.abs(np.delete(std, 2) - 0.1) < 0.06)
    assert est.weights[2] < 0.1 * np.median(est.weights)


@functools.lru_cache(maxsize=None)
def _clean_errors(seed: int) -> np.ndarray:
    """The gradient errors of the healthy run of ``seed``, flown once for every fault compared with it
    (read-only)."""
    _, errors = _run(None, seed=seed)
    errors.flags.writeable = False
    return errors


@pytest.mark.parametrize("fault", ["stuck", "spiking", "biased"])
def test_a_faulty_sensor_does_not_spoil_the_estimate(fault):
    clean = _clean_errors(7)
    _, faulty = _run(fault, seed=7)
    assert np.mean(faulty[100:]) < 1.3 * np.mean(clean[100:])


def test_never_excludes_below_min_sensors():
    rng = np.random.default_rng(0)
    off = _formation(5, 1.0, 0)
    est = RobustGradientEstimator(5, window=20)
    for _ in range(100):
        y = 0.5 + off @ [0.1, 0.2, 0.3] + rng.normal(0, 0.01, 5)
        y[0] = y[1] = 0.7  # two stuck sensors: only one may go
        g = est.update(off, y)
        assert np.count_nonzero(est.excluded) <= 1
        assert np.all(np.isfinite(g))
    assert {s.index for s in est.suspects if s.reason == "stuck"} == {0, 1}


def test_noise_free_linear_field_is_exact_from_the_first_update():
    off = _formation()
    est = RobustGradientEstimator(N)
    for k in range(30):
        grad = np.array([0.1, -0.2, 0.05 * k])
        assert np.allclose(est.update(off, 2.0 + off @ grad), grad, atol=1e-9)
    assert est.suspects == []


def test_batch_matches_independent_estimators():
    rng = np.random.default_rng(5)
    offs = np.stack([_formation(N, 1.0, s) for s in range(3)])
    batch = RobustGradientEstimator(N, window=20, batch_shape=(3,))
    singles = [RobustGradientEstimator(N, window=20) for _ in range(3)]
    for _ in range(60):
        y = rng.normal(0, 0.1, (3, N)) + offs @ [0.2, 0.1, -0.1]
        y[1, 4] += 3.0 * (rng.random() < 0.2)
        gb = batch.update(offs, y)
        for k in range(3):
            assert np.allclose(gb[k], singles[k].update(offs[k], y[k]), atol=1e-12)
    assert [s.index for s in batch.suspects_of(1)] == [s.index for s in singles[1].suspects]
    with pytest.raises(ValueError, match="suspects_of"):
        batch.suspects  # noqa: B018


@pytest.mark.parametrize(
    "kwargs, match",
    [({"n": 3}, "n must be an integer >= 4"), ({"window": 2}, "window"), ({"centre": "x"}, "unknown centre mode"), ({"weighting": "x"}, "unknown weighting mode"),
     ({"bias_gain": -1.0}, "bias_gain"),
     ({"min_sensors": 3}, "min_sensors"), ({"k_mad": 0.0}, "k_mad")],
)
def test_estimator_rejects_bad_parameters(kwargs, match):
    args = {"n": N}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        RobustGradientEstimator(**args)


def test_update_rejects_bad_readings():
    est = RobustGradientEstimator(N)
    off = _formation()
    with pytest.raises(ValueError, match=r"offsets must have shape \(8, 3\)"):
        est.update(off[:7], np.zeros(7))
    with pytest.raises(ValueError, match="finite"):
        est.update(off, np.r_[np.zeros(7), np.inf])
    with pytest.raises(GeometryError, match="degenerate"):
        est.update(np.c_[off[:, :2], np.zeros(N)], np.zeros(N))
    assert est.updates == 0


def test_reasons_are_documented():
    assert REASONS == ("stuck", "biased", "spiking", "noisy")


@pytest.mark.parametrize("weighting", ["inverse_variance", "equal", "auto"])
def test_weighting_modes_on_a_nearly_linear_field(weighting):
    rng = np.random.default_rng(11)
    off = _formation()
    est = RobustGradientEstimator(N, weighting=weighting)
    std = np.full(N, 0.1)
    std[6] = 0.5
    for _ in range(200):
        est.update(off, 0.3 + off @ [0.02, -0.01, 0.03] + rng.normal(0, 1, N) * std)
    w = est.weights
    assert [(s.index, s.reason) for s in est.suspects] == [(6, "noisy")]
    if weighting == "equal":
        assert np.allclose(w, 1 / N) and est.weighting_exponent == 0.0
    else:  # no curvature: nothing to lose by down-weighting the noisy sensor
        assert w[6] < 0.1 / N and est.weighting_exponent == 1.0


def test_auto_weighting_keeps_equal_weights_when_curvature_would_bias():
    """Strong curvature across the formation: down-weighting one sensor would bias the
    estimate by far more than the noise it saves, so auto keeps equal weights (bias flags are
    switched off here: curvature this strong can also look like a bias)."""
    rng = np.random.default_rng(12)
    off = _formation()
    hess = np.diag([0.4, 0.1, -0.3])
    clean = 0.3 + off @ [0.02, -0.01, 0.03] + 0.5 * np.einsum("ni,ij,nj->n", off, hess, off)
    std = np.full(N, 0.01)
    std[6] = 0.05
    auto = RobustGradientEstimator(N, bias_min_std=1e9)
    inv = RobustGradientEstimator(N, bias_min_std=1e9, weighting="inverse_variance")
    g_eq = weighted_gradient(off, clean)
    for _ in range(200):
        y = clean + rng.normal(0, 1, N) * std
        ga, gi = auto.update(off, y), inv.update(off, y)
    assert auto.weighting_exponent == 0.0
    # the persistent error of the down-weighted estimate is the curvature bias auto avoided
    assert np.linalg.norm(gi - g_eq) > 3 * np.linalg.norm(ga - g_eq)


@pytest.mark.parametrize("bias, named", [(0.0, []), (0.5, [(3, "biased")])])
def test_curvature_across_a_large_formation_is_not_a_bias(bias, named):
    """D = 4 m on sigma_2 with quiet sensors (0.01): the field's curvature leaves a persistent
    residual pattern 16x the noise. It must not be taken for a bias; a real bias much larger
    than that pattern still is found."""
    rng = np.random.default_rng(2)
    field = sigma2()
    off = _formation(N, 4.0, 2)
    est = RobustGradientEstimator(N)
    centre = np.array([8.0, -6.0, 3.0])
    for _ in range(400):
        y = field.value(centre + off) + rng.normal(0, 0.01, N)
        y[3] += bias
        g = est.update(off, y)
        centre = centre + g * min(1.0, 0.1 / max(np.linalg.norm(g), 1e-12))
    assert [(s.index, s.reason) for s in est.suspects if s.reason != "noisy"] == named
