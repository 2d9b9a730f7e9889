"""The robust estimator's degenerate cases are handled, not left to numpy's warnings.

Exactly 4 sensors in the fit (a formation of 4, or of 5 with one excluded) leave every
leave-one-out prediction error undetermined (``1 - h = 0``) and every such sensor's variance at
0: the spike test then has no error to compare (numpy's "All-NaN slice encountered") and the
bias test divided by those zero variances (overflow). Both are explicit cases now; these runs
turn every numpy floating-point warning (a ``RuntimeWarning``) into an error; a ResourceWarning the
garbage collector raises for some earlier test's socket is not theirs to fail on.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from estimator.robust import RobustGradientEstimator
from estimator.robust_faults import biased_mask, worst_spike, REASONS
from formation import cvt_sphere

GRAD = np.array([1.0, 2.0, 3.0])


def _run(n, updates, batch=(), stuck=None, seed=0):
    rng = np.random.default_rng(seed)
    off = np.broadcast_to(cvt_sphere(n, 1.0, 0), batch + (n, 3)).copy()
    est = RobustGradientEstimator(n, batch_shape=batch)
    g = None
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for _ in range(updates):
            y = off @ GRAD + 0.01 * rng.standard_normal(batch + (n,))
            if stuck is not None:
                y[stuck] = 1.0
            g = est.update(off, y)
    return est, g


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_four_sensors_no_warning_and_exact_gradient():
    est, g = _run(4, 150)
    assert np.all(est.suspect_codes == 0)
    assert np.allclose(g, GRAD, atol=0.1)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_five_with_one_stuck_excluded_leaves_four_without_warning():
    est, g = _run(5, 150, stuck=(..., 0))
    assert est.suspect_codes[0] == REASONS.index("stuck") + 1
    assert est.excluded[0] and not est.excluded[1:].any()
    assert np.allclose(g, GRAD, atol=0.1)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_batch_mixing_a_degenerate_formation_with_a_healthy_one():
    est, g = _run(5, 150, batch=(2,), stuck=(0, 0))
    assert est.excluded[0, 0] and not est.excluded[1].any()
    assert np.allclose(g, GRAD, atol=0.1)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_worst_spike_with_no_determined_error():
    d = np.full((2, 4), np.nan)
    d[1] = [0.0, 0.01, -0.01, 9.0]
    active = np.ones((2, 4), dtype=bool)
    var = np.full((2, 4), 1e-4)
    out = worst_spike(d, np.zeros((2, 4)), active, np.zeros((2, 1)), var, np.zeros((2, 4)), 5.0, warm=False)
    assert not out[0].any()  # nothing determined: no spike, no warning
    assert out[1].tolist() == [False, False, False, True]
    assert not worst_spike(d[:1], np.zeros((1, 4)), active[:1], np.zeros((1, 1)), var[:1], np.zeros((1, 4)),
                           5.0, warm=True).any()


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_biased_mask_with_zero_variances():
    n = 5
    var = np.array([5e-4, 0.0, 0.0, 0.0, 0.0])
    loo = np.eye(n)
    med = np.array([0.3, 0.0, 0.0, 0.0, 0.0])
    out = biased_mask(var, np.zeros(n), med, loo, np.zeros(n, dtype=int), 50, 6.0, 1.5, 0.85)
    assert out.dtype == bool and out.shape == (n,)
    zero = biased_mask(np.zeros(n), np.zeros(n), np.zeros(n), loo, np.zeros(n, dtype=int), 50, 6.0, 1.5, 0.85)
    assert not zero.any()
