"""The source-term-estimation seeker's forward model and likelihoods (pure numpy/scipy).

A particle is ``(E, N, U, log A, theta)``: the release point (ENU m), the log of the release-point
amplitude ``A`` (the mean concentration there, without the ground image) and the direction the
wind blows TOWARD (radians, counter-clockwise from east). The mean field is the textbook steady
Gaussian plume (the family :mod:`sitl_mock.fields_plume` uses; Seinfeld & Pandis 2016, ch. 18)
with Briggs open-country spreads for a stability class and a source radius ``s0``:

``mu = A s0^2 / (s_y s_z) exp(-y^2 / 2 s_y^2) [exp(-(z - H)^2 / 2 s_z^2) + exp(-(z + H)^2 / 2 s_z^2)]``

(``x`` downwind of the release, upwind ``exp(-x^2 / 2 s0^2)``). The wind speed ``U`` enters the
mean field only through ``Q / U`` (the spreads are functions of the distance), so it is folded
into ``A``: it is not identifiable from the mean field and is not estimated.

Likelihoods (log, each term ``<= 0``, 0 for a perfect explanation, so that a sum is a deviance):

* ``steady``: ``v ~ N(mu + b, sigma^2 + (rho max(mu, v - b))^2)`` (``rho`` the model's relative
  error);
* ``patchy`` (intermittent plumes): a reading is a *hit* when it exceeds ``b + h`` (``h`` the
  detection threshold). The concentration is 0 with probability ``1 - pi`` and log-normal with
  mean ``mu / pi`` and log-deviation ``s`` otherwise, where ``pi = pi0 g^beta`` is the chance that
  the meandering plume covers the point (``g`` the plume's normalised cross-section there, 1 on the
  centreline). ``P(hit) = eps + (1 - eps) pi P(c > h)`` (``eps`` false alarms and dropouts); a
  miss scores ``log(1 - P(hit))`` (a zero reading is information), a hit
  ``log(eps + (1 - eps) pi P(c > h) exp(-(log c - log m)^2 / 2 s^2))`` (``m`` the log-normal's
  median): a hit where the plume is not, or much stronger or weaker than the particle predicts,
  costs up to ``-log eps``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["BRIGGS_RURAL", "plume_mean", "steady_plume", "loglik_steady", "loglik_patchy", "hit_probability",
           "deviance_steady", "deviance_patchy"]

#: Briggs (1973) open-country coefficients ``(ay, by, az, bz, pz)``:
#: ``sigma_y = ay x (1 + by x)^-1/2``, ``sigma_z = az x (1 + bz x)^pz`` (Seinfeld & Pandis table 18.3)
BRIGGS_RURAL = {
    "A": (0.22, 1e-4, 0.20, 0.0, 1.0),
    "B": (0.16, 1e-4, 0.12, 0.0, 1.0),
    "C": (0.11, 1e-4, 0.08, 2e-4, -0.5),
    "D": (0.08, 1e-4, 0.06, 1.5e-3, -0.5),
    "E": (0.06, 1e-4, 0.03, 3e-4, -1.0),
    "F": (0.04, 1e-4, 0.016, 3e-4, -1.0),
}
_TINY = 1e-300


def plume_mean(params: np.ndarray, points: np.ndarray, *, stability: str = "C", s0_m: float = 1.0,
               ground_alt_m: float = 0.0, smooth: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The steady plume (:func:`steady_plume`), or with ``smooth`` the mean of a puff plume.

    A puff plume's puffs exist only downwind of the release and keep the source's size ``s0``
    along the wind (``docs/fields.md``), so its mean is the downwind plume convolved along the
    wind with ``N(0, s0^2)``; the spreads change little over ``s0`` near the release, hence
    ``mean ~ plume(max(x, 0)) Phi(x / s0)`` (exact at the release: half the steady value)."""
    return steady_plume(params, points, stability=stability, s0_m=s0_m, ground_alt_m=ground_alt_m,
                        upwind="edge" if smooth else "gauss")


def steady_plume(params: np.ndarray, points: np.ndarray, *, stability: str = "C", s0_m: float = 1.0,
                 ground_alt_m: float = 0.0, upwind: str = "gauss") -> tuple[np.ndarray, np.ndarray]:
    """Mean plume (without background) and its normalised cross-section at ``points``.

    Parameters
    ----------
    params : ndarray, shape (K, P, 5)
        Particles ``(E, N, U, log A, theta)`` (module docstring).
    points : ndarray, shape (K, M, 3)
        Where the readings were taken, ENU m.
    upwind : {"gauss", "edge"}
        The factor in ``x``: ``exp(-min(x, 0)^2 / 2 s0^2)`` (the steady field's) or ``Phi(x / s0)``
        (a puff plume's mean, :func:`plume_mean`).

    Returns
    -------
    mu, g : ndarray, shape (K, P, M)
        The mean concentration, and ``g`` in [0, 1]: ``exp(-y^2/2 s_y^2 - (z - H)^2/2 s_z^2)``,
        the normalised cross-section (1 on the wind's line through the release).
    """
    ay, by, az, bz, pz = BRIGGS_RURAL[stability]
    src = params[:, :, None, :]
    pts = points[:, None, :, :]
    de, dn = pts[..., 0] - src[..., 0], pts[..., 1] - src[..., 1]
    ux, uy = np.cos(src[..., 4]), np.sin(src[..., 4])
    x = de * ux + dn * uy
    y = dn * ux - de * uy
    z, h = pts[..., 2] - ground_alt_m, src[..., 2] - ground_alt_m
    xp = np.maximum(x, 0.0)
    s2 = s0_m * s0_m
    sy2 = s2 + (ay * xp) ** 2 / (1.0 + by * xp)
    sz2 = s2 + (az * xp * (1.0 + bz * xp) ** pz) ** 2
    along = _log_ndtr(x / s0_m) if upwind == "edge" else -0.5 * np.minimum(x, 0.0) ** 2 / s2
    lat = -0.5 * y * y / sy2
    direct = -0.5 * (z - h) ** 2 / sz2
    g = np.exp(lat + direct)
    vert = g + np.exp(lat - 0.5 * (z + h) ** 2 / sz2)
    mu = np.exp(src[..., 3] + along) * s2 / np.sqrt(sy2 * sz2) * vert
    return mu, g


def loglik_steady(mu: np.ndarray, v: np.ndarray, *, background: float, noise_std: float,
                  rel_error: float) -> np.ndarray:
    """Per-reading log-likelihood ratio ``-z^2 / 2`` of a steady plume's readings, shape of ``mu``.

    ``v`` broadcasts against ``mu`` (readings on the last axis)."""
    excess = v - background
    var = noise_std ** 2 + (rel_error * np.maximum(mu, np.maximum(excess, 0.0))) ** 2
    return -0.5 * (excess - mu) ** 2 / var


def _p_above(mu, pi, h, s):
    """``P(c > h)`` for the log-normal of mean ``mu / pi`` and log-deviation ``s``; and ``log m``."""
    log_m = np.log(np.maximum(mu, _TINY)) - np.log(np.maximum(pi, _TINY)) - 0.5 * s * s
    from scipy.special import erfc  # here, not at the top: see :func:`_log_ndtr`
    return 0.5 * erfc((np.log(h) - log_m) / (s * np.sqrt(2.0))), log_m


def _log_ndtr(u):
    """``scipy.special.log_ndtr``, imported at the first call: the mock fleet's plume imports this
    module for :data:`BRIGGS_RURAL` alone, and scipy.special costs it a third of a CPU second at
    every start."""
    from scipy.special import log_ndtr
    return log_ndtr(u)


def hit_probability(mu, g, *, threshold: float, pi0: float, beta: float, log_sd: float,
                    eps: float) -> np.ndarray:
    """``P(hit)`` of the patchy model (module docstring) for means ``mu`` and cross-sections ``g``."""
    pi = pi0 * np.power(np.maximum(g, _TINY), beta)
    above, _ = _p_above(mu, pi, threshold, log_sd)
    return eps + (1.0 - eps) * pi * above


def loglik_patchy(mu, g, v, *, background: float, threshold: float, pi0: float, beta: float,
                  log_sd: float, eps: float) -> np.ndarray:
    """Per-reading log-likelihood (<= 0) of an intermittent plume's readings (module docstring)."""
    pi = pi0 * np.power(np.maximum(g, _TINY), beta)
    above, log_m = _p_above(mu, pi, threshold, log_sd)
    p_hit = eps + (1.0 - eps) * pi * above
    c = np.maximum(v - background, threshold)
    shape = np.exp(-0.5 * ((np.log(c) - log_m) / log_sd) ** 2)
    hit = np.log(eps + (1.0 - eps) * pi * above * shape)
    miss = np.log(np.maximum(1.0 - p_hit, _TINY))
    return np.where(v - background > threshold, hit, miss)


def deviance_steady(mu_pred, var_pred, v, *, background: float) -> tuple:
    """Per-reading deviance ``z^2`` of steady readings under a Gaussian predictive (mean ``mu_pred``,
    variance ``var_pred``), with its expectation (1) and variance (2) if the model holds."""
    d = (v - background - mu_pred) ** 2 / var_pred
    return d, np.ones_like(d), np.full_like(d, 2.0)


def deviance_patchy(p_hit, hit) -> tuple:
    """Per-reading deviance ``-2 log P(hit or miss)`` of an intermittent plume's readings under the
    predictive hit probability ``p_hit``, with its expectation ``2 H(p)`` and variance
    ``4 p (1 - p) logit(p)^2`` if the model holds (``hit`` boolean, same shape)."""
    p = np.clip(p_hit, 1e-9, 1.0 - 1e-9)
    d = -2.0 * np.where(hit, np.log(p), np.log1p(-p))
    e = -2.0 * (p * np.log(p) + (1.0 - p) * np.log1p(-p))
    var = 4.0 * p * (1.0 - p) * np.log(p / (1.0 - p)) ** 2
    return d, e, var
