"""Weighted least-squares gradient fit: Theorem 2 with per-sensor weights (pure numpy).

``g = (sum w_i r~_i r~_i^T)^-1 sum w_i (y_i - s_c) r~_i``; see :mod:`estimator.robust` for the
two ways of choosing ``s_c`` (``centre="fit"`` / ``"weighted_mean"``) and how the online
estimator picks the weights.
"""
from __future__ import annotations

import numpy as np

from estimator.gradient import DEFAULT_MAX_CONDITION, GeometryError

__all__ = ["CENTRE_MODES", "weighted_gradient"]

#: ways of choosing the centre value ``s_c`` (see estimator.robust)
CENTRE_MODES = ("fit", "weighted_mean")


def _moments(r, w, centre):
    """Weighted geometry: ``M`` (...,3,3), weighted mean offset ``rbar`` (...,3), ``r~`` (...,N,3)."""
    wsum = w.sum(axis=-1)
    if centre == "fit":
        rbar = np.einsum("...n,...ni->...i", w, r) / wsum[..., None]
    else:
        rbar = np.zeros(r.shape[:-2] + (3,))
    rt = r - rbar[..., None, :]
    return np.einsum("...n,...ni,...nj->...ij", w, rt, rt), rbar, rt


def _solve_weighted(r, y, w, centre):
    """Weighted fit; returns g (...,3), s_c (...), M (...,3,3), rbar (...,3)."""
    m, rbar, rt = _moments(r, w, centre)
    ybar = np.einsum("...n,...n->...", w, y) / w.sum(axis=-1)
    b = np.einsum("...n,...n,...ni->...i", w, y - ybar[..., None], rt)
    g = np.linalg.solve(m, b[..., None])[..., 0]
    s_c = ybar - np.einsum("...i,...i->...", g, rbar)  # value of the fitted plane at the centre
    return g, s_c, m, rbar


def _argmax_mask(score):
    mask = np.zeros(score.shape, dtype=bool)
    np.put_along_axis(mask, np.argmax(score, axis=-1)[..., None], True, axis=-1)
    return mask


def _condition(m):
    ev = np.linalg.eigvalsh(m)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ev[..., 0] > 0, ev[..., -1] / np.where(ev[..., 0] > 0, ev[..., 0], 1.0), np.inf)


def weighted_gradient(offsets, values, weights=None, centre: str = "fit",
                      max_condition: float = DEFAULT_MAX_CONDITION) -> np.ndarray:
    """Weighted Theorem-2 gradient estimate (no online state).

    Parameters
    ----------
    offsets : array_like, shape (..., N, 3)
        Reading positions relative to the formation centre (metres).
    values : array_like, shape (..., N)
        Readings.
    weights : array_like, shape (..., N), optional
        Non-negative weights (0 excludes a sensor); default all ones.
    centre : {"fit", "weighted_mean"}
        How ``s_c`` is obtained (module docstring). ``"weighted_mean"`` with equal weights is
        exactly :func:`estimator.gradient` ``(method="cvt")``.
    max_condition : float
        Largest accepted condition number of the weighted ``M``.

    Returns
    -------
    numpy.ndarray, shape (..., 3)

    Raises
    ------
    GeometryError
        Fewer than 4 sensors with positive weight, or ``cond(M) > max_condition``.
    ValueError
        Bad shapes, NaN/inf, negative weights, unknown ``centre``.
    """
    r, y, w = _check_inputs(offsets, values, weights, centre)
    if np.any(np.count_nonzero(w > 0, axis=-1) < 4):
        raise GeometryError("need at least 4 sensors with a positive weight to estimate a 3D gradient")
    cond = _condition(_moments(r, w, centre)[0])
    if np.any(~(cond <= max_condition)):
        raise GeometryError(f"weighted formation geometry is degenerate: cond(M) = {float(np.max(cond)):.3g} "
                            f"exceeds max_condition = {max_condition:.3g}")
    return _solve_weighted(r, y, w, centre)[0]


def _check_inputs(offsets, values, weights, centre):
    if centre not in CENTRE_MODES:
        raise ValueError(f"unknown centre mode {centre!r}; expected one of {', '.join(CENTRE_MODES)}")
    r = np.asarray(offsets, dtype=float)
    y = np.asarray(values, dtype=float)
    if r.ndim < 2 or r.shape[-1] != 3:
        raise ValueError(f"offsets must have shape (..., N, 3), got {r.shape}")
    if y.shape != r.shape[:-1]:
        raise ValueError(f"values must have shape {r.shape[:-1]} to match offsets {r.shape}, got {y.shape}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(y))):
        raise ValueError("offsets and values must be finite (no NaN or inf)")
    w = np.ones_like(y) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), y.shape)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    return r, y, w
