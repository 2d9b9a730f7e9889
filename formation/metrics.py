"""Geometric figures of merit of a formation (paper Sections II-III and Table I).

For offsets ``r_i = p_i - c`` from the formation centre: ``r_bar = sum_i r_i``,
``M = sum_i r_i r_i^T``, ``M_alpha = M - n D^2/3 I`` and ``||(n D^2/3) M^-1||``, which scales
the error bound of Theorem 2, plus the minimum inter-robot distance ``d_min`` of Table I.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import pdist

__all__ = ["FormationMetrics", "metrics", "as_offsets"]


def as_offsets(offsets, *, min_count=1, name="offsets"):
    """Validate and convert an ``(n, 3)`` array of finite offsets.

    Parameters
    ----------
    offsets : array_like
        Candidate ``(n, 3)`` array.
    min_count : int, optional
        Smallest accepted ``n``.
    name : str, optional
        Name used in error messages.

    Returns
    -------
    numpy.ndarray
        A float64 copy of shape ``(n, 3)``.

    Raises
    ------
    ValueError
        If the shape is not ``(n, 3)``, ``n < min_count`` or any entry is not finite.
    """
    try:
        arr = np.array(offsets, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric (n, 3) array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {arr.shape}")
    if arr.shape[0] < min_count:
        raise ValueError(f"{name} needs at least {min_count} rows, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (found NaN or inf)")
    return arr


@dataclass(frozen=True)
class FormationMetrics:
    """Geometric properties of a formation given as offsets from its centre.

    Attributes
    ----------
    n : int
        Number of robots.
    radius : float
        ``D``: mean distance of the robots from the centre.
    d_min : float
        Minimum distance between two robots.
    r_bar : numpy.ndarray
        ``sum_i r_i``, shape ``(3,)``.
    r_bar_norm : float
        Euclidean norm of ``r_bar``.
    M : numpy.ndarray
        ``sum_i r_i r_i^T``, shape ``(3, 3)``.
    M_alpha : numpy.ndarray
        ``M - n D^2/3 I``.
    norm_M_alpha : float
        Spectral norm of ``M_alpha``.
    norm_scaled_Minv : float
        Spectral norm of ``(n D^2/3) M^-1`` (``inf`` if ``M`` is singular).
    cond_M : float
        2-norm condition number of ``M`` (``inf`` if singular).
    """

    n: int
    radius: float
    d_min: float
    r_bar: np.ndarray
    r_bar_norm: float
    M: np.ndarray
    M_alpha: np.ndarray
    norm_M_alpha: float
    norm_scaled_Minv: float
    cond_M: float


def metrics(offsets):
    """Compute the paper's formation properties for ``offsets``.

    Parameters
    ----------
    offsets : array_like, shape (n, 3)
        Robot positions relative to the formation centre, ``n >= 2``.

    Returns
    -------
    FormationMetrics
        ``d_min``, ``r_bar``, ``M``, ``M_alpha``, their norms and the conditioning of ``M``.

    Raises
    ------
    ValueError
        If ``offsets`` is not a finite ``(n, 3)`` array with ``n >= 2``.

    Examples
    --------
    >>> from formation import metrics, symmetric_cylinder
    >>> m = metrics(symmetric_cylinder(8))
    >>> round(m.norm_scaled_Minv, 12)
    1.0
    """
    r = as_offsets(offsets, min_count=2)
    n = r.shape[0]
    radius = float(np.mean(np.linalg.norm(r, axis=1)))
    r_bar = r.sum(axis=0)
    m_mat = r.T @ r
    scale = n * radius**2 / 3.0
    m_alpha = m_mat - scale * np.eye(3)
    eig = np.linalg.eigvalsh(m_mat)  # ascending, M is symmetric positive semi-definite
    tiny = 1e-14 * max(float(eig[-1]), 1e-300)
    if eig[0] <= tiny:
        norm_scaled = float("inf")
        cond = float("inf")
    else:
        norm_scaled = float(scale / eig[0])
        cond = float(eig[-1] / eig[0])
    return FormationMetrics(
        n=n,
        radius=radius,
        d_min=float(pdist(r).min()),
        r_bar=r_bar,
        r_bar_norm=float(np.linalg.norm(r_bar)),
        M=m_mat,
        M_alpha=m_alpha,
        norm_M_alpha=float(np.max(np.abs(np.linalg.eigvalsh(m_alpha)))),
        norm_scaled_Minv=norm_scaled,
        cond_M=cond,
    )
