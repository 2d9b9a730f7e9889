"""The ``ste`` seeker's forward model and intermittent-plume likelihood, evaluated fast (numpy only).

The same numbers as :func:`estimator.ste_model.plume_mean`, :func:`~estimator.ste_model.
loglik_patchy`, :func:`~estimator.ste_model.hit_probability` and :func:`~estimator.ste_model.
loglik_steady` (the plain path, kept as the reference; ``tests/estimator/test_ste_fast.py`` holds
them equal within 1e-9 over random inputs), computed with far fewer passes over the
``(K, P, M)`` particle-by-reading arrays:

* the geometry from per-particle terms (``cos``/``sin`` of the wind and the release's along/across
  offsets computed once per particle, not per pair), in place where numpy allows;
* no ``pow``: ``g^beta`` is ``exp(beta log g)``, the Briggs exponents ``-1/2`` and ``-1`` are a
  division;
* the special functions (``erfc``, ``log_ndtr``, ``log``: 20-40 times an ``exp``'s cost here) only
  where they can change the result. A pair's plume mean is bounded above without them,
  ``log mu <= log A - min(x, 0)^2 / 2 s0^2 + log g + log 2`` (the spreads are at least ``s0``;
  ``log Phi(u) <= -u^2 / 2`` for ``u <= 0``; the ground image at most doubles the direct term);
  where that bound puts ``P(c > h)`` below ``erfc(27) / 2 ~ 3e-319``, the plain path's hit
  probability is ``eps`` to the last bit, and so is this one's. Everywhere else the plain formulas
  run, on the gathered pairs only (``log Phi(x / s0)`` of the puff plume's mean taken as 0 above
  ``x = 9 s0``, where it is above ``-1.2e-19``).

The gain grows with how many particle-reading pairs lie off each particle's plume (early in a
seek, most): see ``docs/seekers.md`` (round 7) for the measured CPU per ``propose``.

scipy.special is imported inside the functions that call it, not with the module: importing it costs
a third of a CPU second, which every ground station and mock fleet would pay at start even when no
``ste`` seeker flies.
"""
from __future__ import annotations

import numpy as np

from estimator.ste_model import BRIGGS_RURAL

__all__ = ["plume_geometry", "plume_mean_fast", "patchy_hit_terms", "loglik_patchy_fast",
           "hit_probability_fast", "loglik_steady_fast", "steady_hit_probability_fast"]

_LOG_TINY = float(np.log(1e-300))  # the plain path's clamp of mu and pi, in logs
_ERFC_ZERO = 27.0  # erfc(w) < 6e-319 beyond: P(c > h) is 0 to double precision
_LOG2 = float(np.log(2.0))


def plume_geometry(params: np.ndarray, points: np.ndarray, *, stability: str = "C", s0_m: float = 1.0,
                   ground_alt_m: float = 0.0) -> dict:
    """Per-pair geometry of the plume: ``x`` (downwind of the release, m), ``log_g`` (the normalised
    cross-section's log), ``sy2``/``sz2`` (spreads squared, m^2), ``zh`` (``-2 z H / s_z^2``, the
    ground image's log relative to the direct term), all ``(K, P, M)``; ``image_le0``: ``zh <= 0``
    everywhere (sensors and releases above the ground)."""
    ay, by, az, bz, pz = BRIGGS_RURAL[stability]
    th = params[..., 4:5]
    cs, sn = np.cos(th), np.sin(th)  # (K, P, 1)
    e0, n0 = params[..., 0:1], params[..., 1:2]
    pe, pn = points[:, None, :, 0], points[:, None, :, 1]  # (K, 1, M)
    x = pe * cs
    x += pn * sn
    x -= e0 * cs + n0 * sn
    y = pn * cs
    y -= pe * sn
    y -= n0 * cs - e0 * sn
    s2 = s0_m * s0_m
    xp = np.maximum(x, 0.0)
    sq = xp * xp
    sy2 = by * xp
    sy2 += 1.0
    np.divide(sq, sy2, out=sy2)
    sy2 *= ay * ay
    sy2 += s2
    sz2 = sq
    sz2 *= az * az
    if bz != 0.0:
        base = bz * xp
        base += 1.0
        if pz == -0.5:
            sz2 /= base
        elif pz == -1.0:
            sz2 /= base * base
        else:
            sz2 *= base ** (2.0 * pz)
    sz2 += s2
    z = points[:, None, :, 2] - ground_alt_m
    h = params[..., 2:3] - ground_alt_m
    log_g = y * y
    log_g /= sy2
    dz = z - h
    dz *= dz
    dz /= sz2
    log_g += dz
    log_g *= -0.5
    zh = z * h
    zh /= sz2
    zh *= -2.0
    image_le0 = bool(np.all(z >= 0.0)) and bool(np.all(h >= 0.0))
    return dict(x=x, log_g=log_g, sy2=sy2, sz2=sz2, zh=zh, image_le0=image_le0, s2=s2, log_amp=params[..., 3:4])


def _log1p_exp(a: np.ndarray) -> np.ndarray:
    """``log(1 + exp(a))`` without overflow."""
    return np.log1p(np.exp(-np.abs(a))) + np.maximum(a, 0.0)


def _log_phi(u: np.ndarray) -> np.ndarray:
    """``log Phi(u)``; 0 for ``u > 9`` (where it is above ``-1.2e-19``: ``log_ndtr`` only where it counts)."""
    out = np.zeros(u.shape)
    low = np.flatnonzero(u <= 9.0)
    from scipy.special import log_ndtr  # imported here: see the module's note
    out[low] = log_ndtr(u[low])
    return out


def _exact_log_mu_all(geo: dict, upwind: str, s0_m: float) -> np.ndarray:
    """The plume mean's log at every pair, flat (when most pairs count: no gathers)."""
    x = geo["x"].ravel()
    along = _log_phi(x / s0_m) if upwind == "edge" else -0.5 * np.minimum(x, 0.0) ** 2 / geo["s2"]
    along = along.reshape(geo["x"].shape)
    along += geo["log_amp"]
    spread = geo["sy2"] * geo["sz2"]
    along -= 0.5 * np.log(spread, out=spread)
    along += np.log(geo["s2"])
    along += geo["log_g"]
    along += _log1p_exp(geo["zh"])
    return along.ravel()


def _exact_log_mu(geo: dict, sel: np.ndarray, upwind: str, s0_m: float) -> np.ndarray:
    """The plume mean's log (:func:`estimator.ste_model.steady_plume`) at the flat pair indices ``sel``."""
    k, p, m = geo["x"].shape
    if sel.size > 0.5 * geo["x"].size:
        return _exact_log_mu_all(geo, upwind, s0_m)[sel]
    x = geo["x"].ravel()[sel]
    if upwind == "edge":
        along = _log_phi(x / s0_m)
    else:
        along = -0.5 * np.minimum(x, 0.0) ** 2 / geo["s2"]
    along += geo["log_amp"][sel // (p * m), (sel // m) % p, 0]
    along += np.log(geo["s2"]) - 0.5 * np.log(geo["sy2"].ravel()[sel] * geo["sz2"].ravel()[sel])
    along += geo["log_g"].ravel()[sel]
    along += _log1p_exp(geo["zh"].ravel()[sel])
    return along


def plume_mean_fast(params: np.ndarray, points: np.ndarray, *, stability: str = "C", s0_m: float = 1.0,
                    ground_alt_m: float = 0.0, smooth: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimator.ste_model.plume_mean`'s ``(mu, g)``, shape ``(K, P, M)``."""
    geo = plume_geometry(params, points, stability=stability, s0_m=s0_m, ground_alt_m=ground_alt_m)
    x = geo["x"]
    if smooth:
        along = _log_phi(x.ravel() / s0_m).reshape(x.shape)
    else:
        along = np.minimum(x, 0.0)
        along *= along
        along *= -0.5 / geo["s2"]
    g = np.exp(geo["log_g"])
    along += geo["log_amp"]
    mu = np.exp(along, out=along)
    spread = geo["sy2"] * geo["sz2"]
    np.sqrt(spread, out=spread)
    mu *= geo["s2"]
    mu /= spread
    if geo["image_le0"]:  # sensors and releases above the ground: zh <= 0, exp(zh) <= 1
        image = np.exp(geo["zh"])
        image += 1.0
        mu *= g
        mu *= image
    else:  # one below the ground: g (1 + e^zh) = exp(-(y^2/sy2 + (z + H)^2/sz2) / 2) (1 + e^-zh) <= 2,
        mu *= np.exp(geo["log_g"] + _log1p_exp(geo["zh"]))  # while e^zh alone can overflow
    return mu, g


def patchy_hit_terms(params: np.ndarray, points: np.ndarray, *, model: dict, threshold: float, pi0: float,
                     beta: float, log_sd: float) -> tuple:
    """The pairs where a hit is possible and their ``pi P(c > h)`` and log-normal ``log m``.

    Returns
    -------
    shape : tuple
        ``(K, P, M)``.
    sel : ndarray of int
        Flat indices of the pairs whose ``P(c > h)`` the cheap bound (module docstring) does not
        put at 0; every other pair's ``pi P(c > h)`` is 0 to double precision.
    pia, log_m : ndarray, shape (len(sel),)
        ``pi P(c > h)`` and ``log m`` there (:func:`estimator.ste_model.loglik_patchy`).
    """
    s0_m = model.get("s0_m", 1.0)
    geo = plume_geometry(params, points, stability=model.get("stability", "C"), s0_m=s0_m,
                         ground_alt_m=model.get("ground_alt_m", 0.0))
    upwind = "edge" if model.get("smooth", False) else "gauss"
    log_g = np.maximum(geo["log_g"], _LOG_TINY)
    xm = np.minimum(geo["x"], 0.0)
    bound = xm * xm
    bound *= -0.5 / geo["s2"]
    bound += geo["log_amp"]
    bound += geo["log_g"]
    bound += _LOG2
    if not geo["image_le0"]:
        bound += np.maximum(geo["zh"], 0.0)
    np.maximum(bound, _LOG_TINY, out=bound)
    log_pi = beta * log_g
    log_pi += np.log(pi0)
    np.maximum(log_pi, _LOG_TINY, out=log_pi)
    bound -= log_pi  # log m + s^2 / 2, bounded above
    w_max = (np.log(threshold) + 0.5 * log_sd * log_sd - bound.ravel()) / (log_sd * np.sqrt(2.0))
    sel = np.flatnonzero(w_max < _ERFC_ZERO)
    log_mu = np.maximum(_exact_log_mu(geo, sel, upwind, s0_m), _LOG_TINY)
    lp = log_pi.ravel()[sel]
    log_m = log_mu - lp - 0.5 * log_sd * log_sd
    from scipy.special import erfc  # imported here: see the module's note
    above = 0.5 * erfc((np.log(threshold) - log_m) / (log_sd * np.sqrt(2.0)))
    return geo["x"].shape, sel, np.exp(lp) * above, log_m


def hit_probability_fast(params: np.ndarray, points: np.ndarray, *, model: dict, threshold: float, pi0: float,
                         beta: float, log_sd: float, eps: float) -> np.ndarray:
    """:func:`estimator.ste_model.hit_probability` of :func:`~estimator.ste_model.plume_mean`'s
    ``(mu, g)`` at ``(params, points)``, shape ``(K, P, M)``."""
    shape, sel, pia, _ = patchy_hit_terms(params, points, model=model, threshold=threshold, pi0=pi0, beta=beta,
                                          log_sd=log_sd)
    out = np.full(shape, eps)
    out.ravel()[sel] = eps + (1.0 - eps) * pia
    return out


def loglik_patchy_fast(params: np.ndarray, points: np.ndarray, v: np.ndarray, *, model: dict, background: float,
                       threshold: float, pi0: float, beta: float, log_sd: float, eps: float) -> np.ndarray:
    """:func:`estimator.ste_model.loglik_patchy` of the readings ``v`` ``(K, M)`` at ``points``
    ``(K, M, 3)`` for particles ``params`` ``(K, P, 5)``: ``(K, P, M)``."""
    shape, sel, pia, log_m = patchy_hit_terms(params, points, model=model, threshold=threshold, pi0=pi0,
                                              beta=beta, log_sd=log_sd)
    excess = v - background
    hit = excess > threshold  # (K, M)
    out = np.where(hit[:, None, :], np.log(eps), np.log(np.maximum(1.0 - eps, 1e-300)))
    out = np.ascontiguousarray(np.broadcast_to(out, shape))
    k_of, m_of = sel // (shape[1] * shape[2]), sel % shape[2]
    is_hit = hit[k_of, m_of]
    val = np.empty(sel.size)
    miss = ~is_hit
    val[miss] = np.log(np.maximum(1.0 - (eps + (1.0 - eps) * pia[miss]), 1e-300))
    on = np.flatnonzero(is_hit)
    log_c = np.log(np.maximum(excess, threshold))  # per reading, not per pair
    shape_f = np.exp(-0.5 * ((log_c[k_of[on], m_of[on]] - log_m[on]) / log_sd) ** 2)
    val[on] = np.log(eps + (1.0 - eps) * pia[on] * shape_f)
    out.ravel()[sel] = val
    return out


def loglik_steady_fast(params: np.ndarray, points: np.ndarray, v: np.ndarray, *, model: dict, background: float,
                       noise_std: float, rel_error: float) -> np.ndarray:
    """:func:`estimator.ste_model.loglik_steady` of :func:`plume_mean_fast`'s mean: ``(K, P, M)``."""
    mu, _ = plume_mean_fast(params, points, **model)
    excess = (v - background)[:, None, :]
    var = np.maximum(mu, np.maximum(excess, 0.0))
    var *= rel_error
    var *= var
    var += noise_std ** 2
    mu -= excess
    mu *= mu
    mu /= var
    mu *= -0.5
    return mu


def steady_hit_probability_fast(params: np.ndarray, points: np.ndarray, *, model: dict, threshold: float,
                                noise_std: float, rel_error: float) -> np.ndarray:
    """``Phi((mu - h) / sd)``, ``sd^2 = noise^2 + (rel mu)^2``: the steady model's chance of a hit ``(K, P, M)``."""
    mu, _ = plume_mean_fast(params, points, **model)
    sd = np.sqrt(noise_std ** 2 + (rel_error * mu) ** 2)
    z = (mu - threshold) / sd
    out = np.zeros(z.shape)
    sel = np.flatnonzero(z.ravel() > -38.5)  # ndtr(-38.5) < 1e-300: 0 below, as the plain path's
    from scipy.special import ndtr  # imported here: see the module's note
    out.ravel()[sel] = ndtr(z.ravel()[sel])
    return out
