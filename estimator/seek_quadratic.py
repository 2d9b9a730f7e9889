"""Quadratic models of the field fitted to a window of readings (pure numpy, batched).

A seeker that looks at more than the current formation fits

    y(x) = a + g . (x - c) + 1/2 (x - c)^T H (x - c)

to the readings of the last ``window`` iterations from all vehicles, by weighted least squares,
with ``y = s`` (the readings themselves: a second-order Taylor model) or ``y = log s`` (exact
for a Gaussian source ``A exp(-(x - r*)^T S (x - r*))``: ``H = -2 S`` everywhere, so readings
from far back along the path fit the same model). The fitted maximum is the Newton point
``c + p``, ``p = -H^-1 g`` when ``H`` is negative definite; its uncertainty comes from the
parameters' covariance (delta method, ``dp = -H^-1 (dg + dH p)``).

Weights: raw readings, 1 each; log readings, ``s_i^2`` (``var(log s) ~ sigma_n^2 / s^2`` for an
additive noise ``sigma_n``), readings ``<= 0`` dropped (weight 0). The six quadratic
coefficients carry a tiny ridge (relative ``1e-10``) so that a window with fewer than 10
readings, or all on one sphere (``|x - c|^2`` constant: the trace of ``H`` is not observable),
gives ``H ~ 0`` along the unobservable directions instead of noise; the residual variance is
estimated from the weighted residuals (``inf`` with fewer than 11 usable readings). A window
with fewer than 4 usable readings (no signal: every reading ``<= 0`` for the log fit) gives a
zero model: no gradient, no Newton step, so the seekers hold the centre.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QuadraticFit", "fit_quadratic"]

_RIDGE = 1e-10
_NPAR = 10
# the quadratic features' index pairs: squares then cross products
_QI = np.array([0, 1, 2, 0, 0, 1])
_QJ = np.array([0, 1, 2, 1, 2, 2])


@dataclass(frozen=True)
class QuadraticFit:
    """A batch of fitted quadratic models about the centres ``c``.

    Attributes
    ----------
    value : ndarray, shape (K,)
        Fitted ``y`` at the centre (``a``).
    value_std : ndarray, shape (K,)
        Its standard deviation.
    grad : ndarray, shape (K, 3)
        Fitted gradient of ``y`` at the centre, per metre.
    hessian : ndarray, shape (K, 3, 3)
        Fitted Hessian of ``y``, per square metre.
    newton : ndarray, shape (K, 3)
        ``p = -H^-1 g`` (NaN where ``H`` is not negative definite).
    newton_std_m : ndarray, shape (K,)
        RMS uncertainty of ``p`` (``inf`` where not defined).
    concave : ndarray of bool, shape (K,)
        ``H`` negative definite.
    used : ndarray of int, shape (K,)
        Readings with a non-zero weight.
    newton_cov : ndarray, shape (K, 3, 3), or None
        Covariance of ``p`` (delta method; ``trace = newton_std_m^2``; ``inf`` where not defined).
    """

    value: np.ndarray
    value_std: np.ndarray
    grad: np.ndarray
    hessian: np.ndarray
    newton: np.ndarray
    newton_std_m: np.ndarray
    concave: np.ndarray
    used: np.ndarray
    newton_cov: np.ndarray | None = None

    def predicted_gain(self, step) -> np.ndarray:
        """Model increase of ``y`` for a move ``step`` (K, 3): ``g.s + 1/2 s^T H s``."""
        s = np.asarray(step, dtype=float)
        return np.einsum("ki,ki->k", self.grad, s) + 0.5 * np.einsum("ki,kij,kj->k", s, self.hessian, s)


def _features(u: np.ndarray) -> np.ndarray:
    """``[1, u, u_i u_j]`` (K, M, 10) with squares halved-free: ``u_x^2, u_y^2, u_z^2, u_x u_y, ...``."""
    ones = np.ones(u.shape[:-1] + (1,))
    quad = u[..., _QI] * u[..., _QJ]
    return np.concatenate([ones, u, quad], axis=-1)


def _hessian(theta: np.ndarray, scale: np.ndarray) -> np.ndarray:
    k = theta.shape[0]
    h = np.zeros((k, 3, 3))
    q = theta[:, 4:]
    for idx, (i, j) in enumerate(zip(_QI, _QJ)):
        if i == j:
            h[:, i, i] = 2.0 * q[:, idx]
        else:
            h[:, i, j] = h[:, j, i] = q[:, idx]
    return h / scale[:, None, None] ** 2


def _newton_jacobian(p: np.ndarray, hinv: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``dp / dtheta`` (K, 3, 10) of ``p = -H^-1 g``."""
    k = p.shape[0]
    b = np.zeros((k, 3, _NPAR))
    b[:, :, 1:4] = np.eye(3) / scale[:, None, None]
    for idx, (i, j) in enumerate(zip(_QI, _QJ)):
        col = np.zeros((k, 3))
        if i == j:
            col[:, i] = 2.0 * p[:, i]
        else:
            col[:, i] += p[:, j]
            col[:, j] += p[:, i]
        b[:, :, 4 + idx] = col / scale[:, None] ** 2
    return -np.einsum("kij,kjl->kil", hinv, b)


def _weights_and_targets(values: np.ndarray, mask: np.ndarray, log: bool):
    if not log:
        return mask.astype(float), np.where(mask, values, 0.0)
    ok = mask & (values > 0)
    safe = np.where(ok, values, 1.0)
    return np.where(ok, safe**2, 0.0), np.where(ok, np.log(safe), 0.0)


def fit_quadratic(positions, values, mask, centre, log: bool) -> QuadraticFit:
    """Fit the quadratic model to each trial's window (module docstring).

    Parameters
    ----------
    positions : array_like, shape (K, M, 3)
        Where the readings were taken (metres).
    values : array_like, shape (K, M)
        The readings.
    mask : array_like of bool, shape (K, M)
        Which entries are readings (False: padding).
    centre : array_like, shape (K, 3)
        Expansion point ``c`` (the current formation centre).
    log : bool
        Fit ``log s`` (Gaussian-exact) instead of ``s``.

    Returns
    -------
    QuadraticFit
    """
    pos = np.asarray(positions, dtype=float)
    c = np.asarray(centre, dtype=float)
    w, y = _weights_and_targets(np.asarray(values, dtype=float), np.asarray(mask, dtype=bool), log)
    d = pos - c[:, None, :]
    used = np.count_nonzero(w > 0, axis=1)
    wsum = np.maximum(w.sum(axis=1), 1e-300)
    scale = np.sqrt(np.einsum("km,km->k", w, np.sum(d * d, axis=-1)) / wsum)
    scale = np.where(scale > 0, scale, 1.0)
    f = _features(d / scale[:, None, None])
    a = np.einsum("km,kmi,kmj->kij", w, f, f)
    tr = np.trace(a, axis1=1, axis2=2)[:, None]
    ridge = np.zeros(_NPAR)
    ridge[4:] = 1.0
    a = a + _RIDGE * tr[:, :, None] * np.diag(ridge)[None]
    dead = used < 4  # no usable readings (all <= 0 in log): a zero model, no step
    a = np.where(dead[:, None, None], np.eye(_NPAR), a)
    try:
        ainv = np.linalg.inv(a)
    except np.linalg.LinAlgError:  # an exactly singular window (e.g. repeated points): least norm
        ainv = np.linalg.pinv(a)
    theta = np.einsum("kij,kmj,km,km->ki", ainv, f, w, y)
    theta = np.where(dead[:, None], 0.0, theta)
    resid = y - np.einsum("kmi,ki->km", f, theta)
    dof = np.where(dead, 0, used - _NPAR)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where(dof > 0, np.einsum("km,km->k", w, resid**2) / np.maximum(dof, 1), np.inf)
    cov = np.where(np.isfinite(var)[:, None, None], np.where(np.isfinite(var), var, 0.0)[:, None, None] * ainv, np.inf)
    grad = theta[:, 1:4] / scale[:, None]
    hess = _hessian(theta, scale)
    eig = np.linalg.eigvalsh(hess)
    concave = eig[:, -1] < 0
    safe_h = np.where(concave[:, None, None], hess, -np.eye(3))
    hinv = np.linalg.inv(safe_h)
    p = -np.einsum("kij,kj->ki", hinv, grad)
    jac = _newton_jacobian(p, hinv, scale)
    with np.errstate(invalid="ignore"):
        p_var = np.einsum("kil,klm,kim->k", jac, np.where(np.isfinite(cov), cov, 0.0), jac)
        p_cov = np.einsum("kil,klm,kjm->kij", jac, np.where(np.isfinite(cov), cov, 0.0), jac)
        defined = np.isfinite(var) & concave
        p_std = np.where(defined, np.sqrt(np.maximum(p_var, 0.0)), np.inf)
        p_cov = np.where(defined[:, None, None], p_cov, np.inf)
    p = np.where(concave[:, None], p, np.nan)
    value_std = np.where(np.isfinite(var), np.sqrt(np.maximum(var * ainv[:, 0, 0], 0.0)), np.inf)
    return QuadraticFit(theta[:, 0], value_std, grad, hess, p, p_std, concave, used, p_cov)
