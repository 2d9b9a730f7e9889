"""Cooperative gradient estimation from the readings of a formation (paper eq. (3) and Thm. 2).

Both estimators are *linear in the readings*. For offsets ``d_i = r_i - c`` (where the readings
were actually taken, relative to the centre ``c``) and readings ``s_i``:

* ``"symmetric"`` (eq. (3), Theorem 1)::

      g = 3 / (N D^2) * sum_i s_i d_i,        D = mean_i ||d_i||

  It is exact on linear fields only when ``sum d_i = 0`` and ``M = N D^2 / 3 I`` (the symmetric
  cylindrical formation); otherwise it is biased by ``3 s_c rbar / (N D^2)`` and ``M_alpha``.

* ``"cvt"`` (Theorem 2)::

      g = M^-1 (sum_i s_i d_i - s_c sum_i d_i),   M = sum_i d_i d_i^T

  with ``s_c`` the field at the centre when it is known (``sigma_c`` given): exact on linear
  fields for *any* geometry with ``M`` invertible.

* ``"cvt"`` with ``s_c`` *not* known (the default, ``sigma_c=None``): least squares with an
  intercept, i.e. the centred moment matrix and centred readings::

      g = M_c^-1 sum_i (s_i - s_bar) (d_i - rbar / N),   M_c = sum_i (d_i - rbar/N)(d_i - rbar/N)^T
                                                             = M - rbar rbar^T / N

  exact on linear fields for any geometry with ``M_c`` invertible. The paper's Remark
  (``s_c`` := the mean of the readings, with the *uncentred* ``M``) has the same numerator but
  ``M^-1`` in place of ``M_c^-1``; it is exact only when ``rbar = sum d_i = 0`` and otherwise
  carries the bias ``-M^-1 rbar (rbar . grad) / N`` (relative error up to 3.2e-4 and 2.6e-4
  for the CVTs with ``||rbar|| ~ 0.1 D``, N = 11 and 13; ``tests/estimator/test_centred_moment.py``). It stays available
  as ``centred=False`` (the paper's formula, used to reproduce the paper).

So ``g = W^T s - s_c b`` with weights ``W`` (N, 3) and ``b`` (3,): ``W = M^-1 d_i``,
``b = M^-1 rbar`` for Theorem 2 with ``s_c``; ``W = M_c^-1 (d_i - rbar/N)``, ``b = 0`` centred;
``b = 0`` for eq. (3). :func:`estimator_weights` computes ``W`` and ``b`` once per geometry (the offline
simulation keeps a formation rigid, so it reuses them for every iteration);
:func:`gradient` and :func:`gradient_batch` use the same code.

Every geometry is checked: ``M`` must be invertible with ``cond(M) <= max_condition``, else
:class:`GeometryError`. (A planar or collinear formation cannot see the gradient component
normal to it; refusing it is better than returning noise amplified by ``||M^-1||``.)
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "METHODS",
    "DEFAULT_MAX_CONDITION",
    "GeometryError",
    "estimator_weights",
    "gradient",
    "gradient_batch",
]

#: Estimator names accepted by ``method``.
METHODS = ("cvt", "symmetric")
#: Largest accepted condition number of ``M`` unless told otherwise.
DEFAULT_MAX_CONDITION = 1e3
_MIN_READINGS = 4


class GeometryError(ValueError):
    """The formation geometry cannot support a gradient estimate (``M`` singular or
    badly conditioned, or a zero radius)."""


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")


def _check_finite(name: str, array: np.ndarray) -> None:
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")


def _as_offsets(offsets) -> np.ndarray:
    arr = np.asarray(offsets, dtype=float)
    if arr.ndim < 2 or arr.shape[-1] != 3:
        raise ValueError(f"offsets/positions must have shape (..., N, 3), got {arr.shape}")
    if arr.shape[-2] < _MIN_READINGS:
        raise ValueError(
            f"need at least {_MIN_READINGS} readings to estimate a 3D gradient, got {arr.shape[-2]}"
        )
    _check_finite("offsets/positions", arr)
    return arr


def estimator_weights(offsets, method: str = "cvt", max_condition: float = DEFAULT_MAX_CONDITION,
                      centred: bool = True):
    """Linear weights of the estimator for a geometry.

    Parameters
    ----------
    offsets : array_like, shape (..., N, 3)
        Where the readings are taken, relative to the centre ``c`` (metres). Leading
        dimensions are batch dimensions (e.g. trials).
    method : {"cvt", "symmetric"}
        Theorem 2 (``M^-1`` corrected) or eq. (3).
    max_condition : float
        Largest accepted 2-norm condition number of ``M = sum d_i d_i^T`` (of ``M_c`` when
        centred).
    centred : bool
        ``"cvt"`` only. True (default): least squares with an intercept (``M_c``, centred
        offsets, ``b = 0``), for when ``s_c`` is not measured. False: Theorem 2 as stated
        (``M``, ``b = M^-1 rbar``), exact with the true ``s_c``; with ``s_c`` = mean of the
        readings this is the paper's Remark.

    Returns
    -------
    weights : ndarray, shape (..., N, 3)
        ``W`` such that the estimate is ``W^T s - s_c b`` for readings ``s`` (N,).
    bias_vector : ndarray, shape (..., 3)
        ``b = M^-1 sum_i d_i`` for uncentred ``"cvt"``, zeros otherwise.

    Raises
    ------
    GeometryError
        If any ``M`` is singular or ``cond(M) > max_condition``, or the mean radius is zero.
    ValueError
        Bad shapes, fewer than 4 readings, NaN/inf, unknown method.
    """
    _check_method(method)
    d = _as_offsets(offsets)
    if not (np.isfinite(max_condition) and max_condition >= 1.0):
        raise ValueError(f"max_condition must be a finite number >= 1, got {max_condition!r}")
    n = d.shape[-2]
    rbar = d.sum(axis=-2)
    dc = d - rbar[..., None, :] / n if (centred and method == "cvt") else d
    m = np.einsum("...ni,...nj->...ij", dc, dc)
    sv = np.linalg.svd(m, compute_uv=False)
    smax, smin = sv[..., 0], sv[..., -1]
    bad = ~(smin > smax / max_condition) | ~(smax > 0)
    if np.any(bad):
        with np.errstate(divide="ignore", invalid="ignore"):
            cond = np.where(smin > 0, smax / np.where(smin > 0, smin, 1.0), np.inf)
        worst = float(np.max(np.where(bad, cond, 0.0)))
        raise GeometryError(
            f"formation geometry is degenerate: cond(M) = {worst:.3g} exceeds max_condition = "
            f"{max_condition:.3g} (the readings are (nearly) coplanar or collinear, so the "
            "gradient component normal to them is unobservable)"
        )
    if method == "symmetric":
        radius_m = np.linalg.norm(d, axis=-1).mean(axis=-1)
        scale = 3.0 / (n * radius_m**2)
        weights = d * scale[..., None, None]
        return weights, np.zeros_like(rbar)
    minv = np.linalg.inv(m)
    weights = np.einsum("...ij,...nj->...ni", minv, dc)
    if centred:
        return weights, np.zeros_like(rbar)
    bias_vector = np.einsum("...ij,...j->...i", minv, rbar)
    return weights, bias_vector


def _combine(weights, bias_vector, values, sigma_c):
    est = np.einsum("...n,...ni->...i", values, weights)
    if sigma_c is None:
        sigma_c = values.mean(axis=-1)
    return est - np.asarray(sigma_c, dtype=float)[..., None] * bias_vector


def _check_values(values: np.ndarray, n: int) -> None:
    if values.shape[-1:] != (n,):
        raise ValueError(f"values must have shape (..., {n}) to match {n} positions, got {values.shape}")
    _check_finite("values", values)


def _check_sigma_c(sigma_c):
    if sigma_c is None:
        return None
    arr = np.asarray(sigma_c, dtype=float)
    _check_finite("sigma_c", arr)
    return arr


def gradient(
    positions,
    values,
    centre,
    method: str = "cvt",
    sigma_c: float | None = None,
    max_condition: float = DEFAULT_MAX_CONDITION,
) -> np.ndarray:
    """Estimate the field gradient at ``centre`` from readings taken at ``positions``.

    Parameters
    ----------
    positions : array_like, shape (N, 3)
        Where each reading was actually taken (mission frame, metres). N >= 4.
    values : array_like, shape (N,)
        The readings.
    centre : array_like, shape (3,)
        Point at which the gradient is estimated (the formation centre).
    method : {"cvt", "symmetric"}
        ``"cvt"``: Theorem 2, ``M^-1 (sum s_i d_i - s_c sum d_i)``; ``"symmetric"``: eq. (3),
        ``3/(N D^2) sum s_i d_i`` with ``D`` the mean distance of the positions to the centre.
    sigma_c : float, optional
        Field value at the centre (``"cvt"`` only): Theorem 2 with ``M``. Default (None): not
        measured; least squares with an intercept (centred ``M_c``, exact on linear fields for
        any geometry). Ignored by ``"symmetric"``.
    max_condition : float
        Largest accepted condition number of ``M``.

    Returns
    -------
    ndarray, shape (3,)
        Estimated gradient (signal units per metre).

    Raises
    ------
    GeometryError
        ``M`` singular or ``cond(M) > max_condition``.
    ValueError
        Shape mismatch, fewer than 4 readings, NaN/inf, unknown method.
    """
    pos = np.asarray(positions, dtype=float)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {pos.shape}")
    c = np.asarray(centre, dtype=float)
    if c.shape != (3,):
        raise ValueError(f"centre must have shape (3,), got {c.shape}")
    _check_finite("centre", c)
    vals = np.asarray(values, dtype=float)
    if vals.ndim != 1:
        raise ValueError(f"values must have shape (N,), got {vals.shape}")
    _check_values(vals, pos.shape[0])
    sc = _check_sigma_c(sigma_c)
    if sc is not None and sc.shape != ():
        raise ValueError(f"sigma_c must be a scalar, got shape {sc.shape}")
    weights, bias_vector = estimator_weights(pos - c, method, max_condition, centred=sc is None)
    return _combine(weights, bias_vector, vals, sc)


def gradient_batch(
    offsets,
    values,
    method: str = "cvt",
    sigma_c=None,
    max_condition: float = DEFAULT_MAX_CONDITION,
    weights=None,
) -> np.ndarray:
    """Many gradient estimates at once (same maths as :func:`gradient`).

    Parameters
    ----------
    offsets : array_like, shape (..., N, 3)
        Reading positions relative to their centres. Ignored if ``weights`` is given.
    values : array_like, shape (..., N)
        Readings; leading dimensions broadcast against those of ``offsets``.
    method : {"cvt", "symmetric"}
        As in :func:`gradient`.
    sigma_c : array_like, shape (...), optional
        Field values at the centres (``"cvt"``, Theorem 2 with ``M``); default: not measured,
        centred least squares (with precomputed ``weights``: whatever they were made for; with
        uncentred weights and no ``sigma_c``, the mean of the readings, the paper's Remark).
    max_condition : float
        Largest accepted condition number of ``M``.
    weights : tuple, optional
        ``(W, b)`` from :func:`estimator_weights`, to skip recomputing them for a rigid
        formation.

    Returns
    -------
    ndarray, shape (..., 3)

    Raises
    ------
    GeometryError, ValueError
        As :func:`gradient`.
    """
    if weights is None:
        weights = estimator_weights(offsets, method, max_condition, centred=sigma_c is None)
    w, b = weights
    vals = np.asarray(values, dtype=float)
    _check_values(vals, w.shape[-2])
    return _combine(w, b, vals, _check_sigma_c(sigma_c))
