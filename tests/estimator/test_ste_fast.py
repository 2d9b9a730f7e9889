"""The ``ste`` seeker's fast forward model and likelihoods (:mod:`estimator.ste_fast`) equal the plain
ones (:mod:`estimator.ste_model`) within a tight tolerance over random particles and readings."""
from __future__ import annotations

import numpy as np
import pytest

from estimator import ste_fast as fast
from estimator import ste_model as plain

_PATCHY = dict(threshold=0.03, pi0=0.6, beta=0.5, log_sd=1.0, eps=0.01)


def _inputs(seed: int, k: int = 2, p: int = 400, m: int = 30, below_ground: bool = False):
    rng = np.random.default_rng(seed)
    parts = np.empty((k, p, 5))
    parts[..., :2] = rng.uniform(-60.0, 60.0, (k, p, 2))
    parts[..., 2] = rng.uniform(0.1, 20.0, (k, p))
    parts[..., 3] = rng.uniform(-4.0, 4.0, (k, p))
    parts[..., 4] = rng.uniform(-np.pi, np.pi, (k, p))
    pts = rng.uniform(-15.0, 40.0, (k, m, 3))
    pts[..., 2] = rng.uniform(-3.0 if below_ground else 0.0, 20.0, (k, m))
    # a third of the readers on some particle's plume line: pairs where a hit is likely, not only far ones
    near = rng.random((k, m)) < 0.35
    j = rng.integers(0, p, (k, m))
    src = np.take_along_axis(parts, j[..., None], axis=1)
    d = rng.uniform(-3.0, 30.0, (k, m))
    on = src[..., :3] + np.stack([d * np.cos(src[..., 4]), d * np.sin(src[..., 4]),
                                  rng.normal(0.0, 1.0, (k, m))], axis=-1)
    pts = np.where(near[..., None], on, pts)
    v = np.where(rng.random((k, m)) < 0.4, rng.lognormal(-1.0, 1.5, (k, m)), rng.normal(0.0, 0.01, (k, m)))
    return parts, pts, v


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("stability", ["A", "C", "D", "F"])
@pytest.mark.parametrize("smooth", [False, True])
def test_fast_model_and_likelihoods_equal_the_plain_ones(seed, stability, smooth):
    parts, pts, v = _inputs(seed, below_ground=seed % 3 == 2)
    model = dict(stability=stability, s0_m=1.0 + 0.5 * (seed % 2), ground_alt_m=0.0, smooth=smooth)
    mu, g = plain.plume_mean(parts, pts, **model)
    mu_f, g_f = fast.plume_mean_fast(parts, pts, **model)
    np.testing.assert_allclose(mu_f, mu, rtol=1e-9, atol=1e-250)
    np.testing.assert_allclose(g_f, g, rtol=1e-9, atol=1e-250)
    ll = plain.loglik_patchy(mu, g, v[:, None, :], background=0.0, **_PATCHY)
    ll_f = fast.loglik_patchy_fast(parts, pts, v, model=model, background=0.0, **_PATCHY)
    np.testing.assert_allclose(ll_f, ll, rtol=1e-9, atol=1e-12)
    ph = plain.hit_probability(mu, g, **_PATCHY)
    np.testing.assert_allclose(fast.hit_probability_fast(parts, pts, model=model, **_PATCHY), ph, rtol=1e-9, atol=1e-15)
    assert np.ptp(ll) > 1.0 and np.any(ph > 0.1), "the inputs must include pairs where a hit is likely"
    steady = dict(background=0.0, noise_std=0.01, rel_error=0.3)
    np.testing.assert_allclose(fast.loglik_steady_fast(parts, pts, v, model=model, **steady),
                               plain.loglik_steady(mu, v[:, None, :], **steady), rtol=1e-9, atol=1e-12)


def test_fast_steady_hit_probability_equals_the_normal_cdf():
    from scipy.special import ndtr
    parts, pts, _ = _inputs(7)
    model = dict(stability="C", s0_m=1.0, ground_alt_m=0.0, smooth=False)
    mu, _ = plain.plume_mean(parts, pts, **model)
    want = ndtr((mu - 0.3) / np.sqrt(0.01 ** 2 + (0.3 * mu) ** 2))
    got = fast.steady_hit_probability_fast(parts, pts, model=model, threshold=0.3, noise_std=0.01, rel_error=0.3)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-300)
    assert np.any(want > 0.5) and np.any(want < 1e-6)


def test_far_pairs_are_skipped_but_score_the_plain_constant():
    """Readers far across every particle's plume: no pair needs the special functions, and every
    miss scores ``log(1 - eps)``, every hit ``log eps`` (the plain path's values)."""
    parts, _, _ = _inputs(3)
    parts[..., 4] = 0.0  # all winds east: readers 500 m north are off every plume
    pts = np.zeros((2, 4, 3))
    pts[..., 1], pts[..., 2] = 500.0, 5.0
    model = dict(stability="C", s0_m=1.0, ground_alt_m=0.0, smooth=True)
    _, sel, _, _ = fast.patchy_hit_terms(parts, pts, model=model, **{k: _PATCHY[k] for k in ("threshold", "pi0", "beta", "log_sd")})
    assert sel.size == 0
    v = np.array([[0.0, 1.0, 0.0, 2.0], [0.5, 0.0, 0.0, 0.0]])
    ll = fast.loglik_patchy_fast(parts, pts, v, model=model, background=0.0, **_PATCHY)
    want = plain.loglik_patchy(*plain.plume_mean(parts, pts, **model), v[:, None, :], background=0.0, **_PATCHY)
    np.testing.assert_array_equal(ll, want)
    assert np.isclose(ll[0, 0, 1], np.log(0.01)) and np.isclose(ll[0, 0, 0], np.log(0.99))
