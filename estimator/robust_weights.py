"""Weight selection of the robust gradient estimator.

Pure numpy functions used by :class:`estimator.robust.RobustGradientEstimator` (vectorised
over a leading batch of independent formations):

* :func:`base_weights` -- relative inverse-variance weights, floored;
* :func:`admissible_weights` -- weights with some sensors dropped, where that keeps enough
  sensors and a well-conditioned geometry;
* :func:`choose_weights` -- the ``"auto"`` and ``"equal"`` weightings: unequal weights break
  the formation's symmetry, and the field's curvature across the formation then biases the
  estimate; the weights ``var^-a`` (``a`` in 0, 0.5, 1) with the smallest predicted error
  (noise plus ``bias_gain`` times the significant part of that bias) are chosen;
* :func:`fit_operator` -- the linear map from the readings to the weighted fit's gradient.
"""
from __future__ import annotations

import numpy as np

from estimator.gradient import GeometryError
from estimator.robust_wls import _condition, _moments, _solve_weighted

__all__ = ["WEIGHTINGS", "fit_operator", "base_weights", "admissible_weights", "choose_weights"]

#: how the weights are chosen (see RobustGradientEstimator)
WEIGHTINGS = ("auto", "inverse_variance", "equal")
#: exponents ``a`` of the weights ``var^-a`` that ``weighting="auto"`` chooses from
_AUTO_EXPONENTS = (0.0, 0.5, 1.0)
#: the curvature residual kappa is averaged over this many windows
_KAPPA_WINDOWS = 4
#: |b|^2 must exceed this many times its noise-only expectation to count as a curvature bias
_BIAS_SIGNIFICANCE = 9.0


def fit_operator(r, w, centre: str):
    """Gradient rows of the weighted fit: ``g = G y``, shape (..., 3, N).

    Parameters
    ----------
    r : numpy.ndarray, shape (..., N, 3)
        Offsets of the readings from the formation centre (metres).
    w : numpy.ndarray, shape (..., N)
        Weights (0 = left out).
    centre : {"fit", "weighted_mean"}
        How ``s_c`` is obtained (see :mod:`estimator.robust`).
    """
    m, rbar, _ = _moments(r, w, centre)
    rbar_w = np.einsum("...n,...ni->...i", w, r) / w.sum(axis=-1)[..., None]
    return np.einsum("...ij,...nj->...in", np.linalg.inv(m), w[..., None] * (r - rbar_w[..., None, :]))


def base_weights(var, var_floor_rel: float, warm: bool):
    """Relative inverse-variance weights (typical sensor = 1), equal before warm-up.

    ``var`` (shape ``(*batch, N)``) is floored at ``var_floor_rel`` times the median variance
    (and capped at 1e6 times it); a formation whose median variance is 0 gets equal weights.
    """
    if not warm:
        return np.ones(np.shape(var))
    ref = np.median(var, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = ref / np.clip(var, var_floor_rel * ref, 1e6 * ref)
    return np.where(ref > 0, w, 1.0)


def admissible_weights(r, base_w, drop, min_active: int, centre: str, max_condition: float,
                       fallback=None):
    """Weights ``base_w`` with the ``drop`` sensors removed, where that is admissible.

    Per formation: the drop is kept where at least ``min_active`` sensors remain with a
    geometry of condition number <= ``max_condition``; otherwise ``fallback`` (default:
    ``base_w``, nobody dropped). If the weights themselves starve the geometry, equal weights
    are used.

    Raises
    ------
    GeometryError
        Even equal weights on the remaining sensors give a degenerate geometry.
    """
    fallback = base_w if fallback is None else fallback
    w = np.where(drop, 0.0, base_w)
    ok = np.count_nonzero(w > 0, axis=-1) >= min_active
    if np.any(ok):
        m = _moments(r, np.where(ok[..., None], w, fallback), centre)[0]
        ok &= _condition(m) <= max_condition
    w = np.where(ok[..., None], w, fallback)
    if not np.all(ok):
        bad = ~(_condition(_moments(r, w, centre)[0]) <= max_condition)
        if np.any(bad):
            w = np.where(bad[..., None], 1.0, w)
            cond = _condition(_moments(r, w, centre)[0])
            if np.any(~(cond <= max_condition)):
                raise GeometryError(
                    f"formation geometry is degenerate: cond(M) = {float(np.max(cond)):.3g} exceeds "
                    f"max_condition = {max_condition:.3g}")
    return w


def choose_weights(r, y, w, kappa, var, centre: str, weighting: str, window: int, bias_gain: float):
    """Equal weights on the sensors in the fit, or ``var^-a``: the smallest predicted error.

    ``kappa`` is the persistent residual of the equal-weight fit (the part of the field the
    linear model misses: curvature). Weights ``w`` move the estimate by ``b = G_w kappa``
    (a bias) and change its noise variance ``v_w = sum_i |G_w[:, i]|^2 var_i``. Predicted
    error: ``v_w + bias_gain * max(0, |b|^2 - 9 var(b))`` where ``var(b)`` is the part of
    ``|b|^2`` due to the noise in ``kappa`` itself (an exponential mean over
    ``4 * window`` updates).

    Parameters
    ----------
    r, y : numpy.ndarray, shapes (*batch, N, 3) and (*batch, N)
        Offsets and readings of this update.
    w : numpy.ndarray, shape (*batch, N)
        Inverse-variance weights of this update (0 = left out).
    kappa, var : numpy.ndarray, shape (*batch, N)
        Persistent residual so far and noise variance estimates.
    centre, weighting : str
        As for :class:`estimator.robust.RobustGradientEstimator` (``weighting`` is ``"auto"``
        or ``"equal"``).
    window : int
        Length of the estimator's sliding window (updates).
    bias_gain : float
        Cost of a persistent gradient bias relative to white noise of the same variance.

    Returns
    -------
    w : numpy.ndarray, shape (*batch, N)
        The chosen weights.
    g : numpy.ndarray, shape (*batch, 3)
        The gradient estimate with them.
    kappa : numpy.ndarray, shape (*batch, N)
        The updated persistent residual.
    exponent : numpy.ndarray, shape (*batch,)
        The exponent ``a`` chosen (0 = equal weights).
    """
    batch_shape = np.shape(w)[:-1]
    active = w > 0
    w_eq = active.astype(float)
    g_eq_op = fit_operator(r, w_eq, centre)
    # residual of the equal-weight fit (intercept included)
    g_eq, s_eq, _, _ = _solve_weighted(r, y, w_eq, centre)
    e_eq = y - s_eq[..., None] - np.einsum("...ni,...i->...n", r, g_eq)
    alpha_k = 1.0 / (_KAPPA_WINDOWS * window)
    kappa = np.where(active, kappa + alpha_k * (e_eq - kappa), kappa)
    if weighting == "equal":
        return w_eq, g_eq, kappa, np.zeros(batch_shape)
    n_eff = (2.0 - alpha_k) / alpha_k
    best_w, best_g = w_eq, g_eq
    best_cost = np.einsum("...in,...n->...", g_eq_op**2, var)
    best_a = np.zeros(batch_shape)
    for a in _AUTO_EXPONENTS[1:]:
        w_a = np.where(active, w ** a, 0.0)
        op = fit_operator(r, w_a, centre)
        b = np.einsum("...in,...n->...i", op, np.where(active, kappa, 0.0))
        var_b = np.einsum("...in,...n->...", (op - g_eq_op) ** 2, var) / n_eff
        cost = np.einsum("...in,...n->...", op**2, var) + bias_gain * np.maximum(
            0.0, np.einsum("...i,...i->...", b, b) - _BIAS_SIGNIFICANCE * var_b)
        better = cost < best_cost
        if np.any(better):
            g_a = np.einsum("...in,...n->...i", op, y)
            best_w = np.where(better[..., None], w_a, best_w)
            best_g = np.where(better[..., None], g_a, best_g)
            best_cost = np.where(better, cost, best_cost)
            best_a = np.where(better, a, best_a)
    return best_w, best_g, kappa, best_a
