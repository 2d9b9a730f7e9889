"""Fault detection of the robust gradient estimator: spiking, stuck, biased and noisy sensors.

Pure numpy functions on the per-sensor statistics kept by
:class:`estimator.robust.RobustGradientEstimator` (all vectorised over a leading batch of
independent formations):

* :func:`worst_spike` -- the reading farthest beyond ``k_mad`` robust standard deviations
  from its sensor's median leave-one-out prediction error (dropped from that update);
* :func:`stuck_mask` -- readings that stop changing while the others' change;
* :func:`biased_mask` -- the one sensor whose bias explains the windowed median errors of all
  sensors through the known leave-one-out map, leaving only noise unexplained;
* :func:`suspect_codes` -- the per-sensor verdict, one of :data:`REASONS` in order of
  precedence (noisy sensors are only reported: the weights handle them).

:class:`Suspect` is how a distrusted sensor is reported.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.robust_wls import _argmax_mask

__all__ = ["REASONS", "MAD_TO_STD", "Suspect", "worst_spike", "stuck_mask", "biased_mask",
           "suspect_codes"]

#: suspect reasons, in order of precedence (a sensor is reported once, for the first that applies)
REASONS = ("stuck", "biased", "spiking", "noisy")
#: robust standard deviation per median absolute deviation (normal distribution)
MAD_TO_STD = 1.4826
#: a bias is also accepted when what it leaves unexplained is below this fraction of it
_BIAS_DOMINANCE = 0.15


@dataclass(frozen=True)
class Suspect:
    """A sensor the estimator distrusts: 0-based ``index`` in the order of the readings,
    ``reason`` (one of :data:`REASONS`), whether the last estimate ``excluded`` it, and its
    current ``noise_std`` estimate."""

    index: int
    reason: str
    excluded: bool
    noise_std: float


def worst_spike(d, p, active, abs_tol, var, med_d, k_mad: float, warm: bool):
    """Per formation, the active sensor farthest beyond ``k_mad`` robust deviations (if any).

    Parameters
    ----------
    d, p : numpy.ndarray, shape (*batch, N)
        Leave-one-out prediction errors (``nan`` if undetermined) and their prediction variances.
    active : numpy.ndarray of bool, shape (*batch, N)
        Sensors in the fit.
    abs_tol : numpy.ndarray, shape (*batch, 1)
        Deviations at or below this are never spikes (rounding).
    var, med_d : numpy.ndarray, shape (*batch, N)
        Each sensor's noise variance estimate and windowed median prediction error.
    k_mad : float
        Spike threshold in robust standard deviations.
    warm : bool
        Whether the history is long enough to compare each sensor with its own past; before,
        it is compared with the other sensors' prediction errors.

    Returns
    -------
    numpy.ndarray of bool, shape (*batch, N)
        At most one True per formation.
    """
    valid = active & np.isfinite(d)
    if not np.any(valid):
        # no determined prediction error (e.g. exactly 4 sensors in the fit: each reading is
        # needed by the fit, ``1 - h = 0``): nothing can be called a spike
        return np.zeros(np.shape(d), dtype=bool)
    if not warm:
        # too little history: compare with the other sensors' prediction errors; a formation
        # of the batch with none determined gets zeros (its ``valid`` is all False, so it scores 0)
        some = np.any(valid, axis=-1, keepdims=True)
        da = np.where(valid, d, np.where(some, np.nan, 0.0))
        med = np.nanmedian(da, axis=-1, keepdims=True)
        mad = np.nanmedian(np.abs(da - med), axis=-1, keepdims=True)
        scale = np.maximum(MAD_TO_STD * mad, np.sqrt(np.median(var, axis=-1, keepdims=True) + p))
    else:
        med = med_d
        scale = np.sqrt(var + p)
    dev = np.abs(np.where(valid, d, 0.0) - med)
    score = np.where(valid & (dev > abs_tol), dev / np.maximum(scale, np.finfo(float).tiny), 0.0)
    return _argmax_mask(score) & (score > k_mad)


def stuck_mask(diff2, stuck_ratio: float):
    """Sensors whose reading-change energy ``diff2`` is below ``stuck_ratio`` times the
    median of the others' (which must be changing), shape ``(*batch, N)``."""
    n = diff2.shape[-1]
    others = np.stack([np.median(np.delete(diff2, i, axis=-1), axis=-1) for i in range(n)], axis=-1)
    return (diff2 <= stuck_ratio * others) & (others > 0)


def biased_mask(var, p_mean, med_d, loo, code, k: int, k_bias: float, bias_min_std: float,
                bias_explained: float):
    """The sensor (at most one per formation) whose bias explains the median errors.

    A bias ``b_i`` on sensor i moves the median errors by ``b_i c_i`` (``c_i``: column i of
    the leave-one-out map). Best candidate: the largest explained fraction of their weighted
    energy (>= ``bias_explained``) with ``|b_i|`` significant; a sensor already excluded as
    biased stays so while its own median error stays significant.

    Parameters
    ----------
    var, p_mean, med_d : numpy.ndarray, shape (*batch, N)
        Noise variance estimates, windowed mean prediction variances and windowed median
        leave-one-out errors.
    loo : numpy.ndarray, shape (*batch, N, N)
        Leave-one-out map: ``loo[..., j, i]`` is the effect on ``d_j`` of reading i.
    code : numpy.ndarray of int, shape (*batch, N)
        Current suspect codes (0 = trusted, ``k + 1`` = ``REASONS[k]``).
    k : int
        Number of updates in the window.
    k_bias, bias_min_std, bias_explained : float
        Thresholds (see :class:`estimator.robust.RobustGradientEstimator`).

    Returns
    -------
    numpy.ndarray of bool, shape (*batch, N)
    """
    std_d = np.sqrt(var + p_mean)
    se = 1.2533 * std_d / np.sqrt(k)
    med = med_d
    # a sensor whose prediction errors were never determined (zero variance: every reading needed
    # by the fit, as with exactly 4 sensors in it) carries no information: weight 0, not 1 / 0
    known = std_d**2 > 0
    inv_var = np.where(known, 1.0 / np.where(known, std_d**2, 1.0), 0.0)
    cols = loo  # loo[..., j, i]: effect on d_j of reading i
    num = np.einsum("...j,...j,...ji->...i", inv_var, med, cols)
    den = np.einsum("...j,...ji,...ji->...i", inv_var, cols, cols)
    # a sensor with (almost) no leverage on the errors (``den`` ~ 0: e.g. excluded with exactly
    # 4 sensors left in the fit) explains nothing: its bias is undetermined, taken as 0
    scale = np.max(den, axis=-1, keepdims=True)
    lever = den > 1e-12 * np.maximum(scale, np.finfo(float).tiny)
    b = np.where(lever, num / np.where(lever, den, 1.0), 0.0)
    energy = np.einsum("...j,...j->...", inv_var, med**2)[..., None]
    explained = np.where(lever, num * b, 0.0) / np.maximum(energy, np.finfo(float).tiny)
    significant = (np.abs(b) > k_bias * se) & (np.abs(b) > bias_min_std * std_d)
    # what one bias leaves unexplained must be noise, or small next to the bias: not
    # structure of its own size (strong curvature across the formation looks like that)
    remainder = np.abs(med[..., :, None] - cols * b[..., None, :])  # [..., j, i]: without bias i
    clean = (np.max(remainder / np.maximum(se, 1e-300)[..., :, None], axis=-2) <= k_bias) \
        | (np.max(remainder, axis=-2) <= _BIAS_DOMINANCE * np.abs(b))
    score = np.where(significant & clean, explained, 0.0)
    new = _argmax_mask(score) & (score >= bias_explained)
    stay = (code == REASONS.index("biased") + 1) & (np.abs(med) > k_bias * se) \
        & (np.abs(med) > bias_min_std * std_d)
    # one biased sensor at a time: the one already excluded, else the new best candidate
    return np.where(np.any(stay, axis=-1, keepdims=True), stay & _argmax_mask(np.where(stay, np.abs(med), -1.0)),
                    new)


def suspect_codes(stuck, biased, spiking, noisy):
    """Per-sensor code, 0 = trusted or ``k + 1`` for the first of :data:`REASONS` that applies.

    Parameters
    ----------
    stuck, biased, spiking, noisy : numpy.ndarray of bool, shape (*batch, N)
        The verdicts, in the order of :data:`REASONS`.

    Returns
    -------
    numpy.ndarray of numpy.int8, shape (*batch, N)
    """
    code = np.zeros(np.shape(stuck), dtype=np.int8)
    for j, mask in reversed(list(enumerate((stuck, biased, spiking, noisy)))):
        code = np.where(mask, np.int8(j + 1), code)
    return code
