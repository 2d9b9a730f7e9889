"""A source estimate with its 95 % region, as every seeker reports it (pure numpy).

The project's rule: an estimate of the source is never given without its uncertainty, or an
explicit statement that it has none. :class:`SourceEstimate` carries the point, the radius of
the sphere about it that holds 95 % of the probability (``region95_m``; None: no region) and
``basis``, one sentence that says honestly what the region is. Each seeker's
``source_estimate(k)`` gives trial ``k``'s (or None: the seeker has no estimate of its own);
:func:`reported_estimate` is what a mission reports: the seeker's own when it has one, else the
convergence monitor's (the mean of the recent centres, labelled as such).

Regions are spheres for every seeker, so the numbers compare: for a Gaussian ``N(x, C)`` the
radius ``r`` with ``P(|X - x| <= r) = 0.95`` (:func:`sphere_radius95_m`): ``sqrt(chi2_3(0.95))
sigma = 2.80 sigma`` when ``C = sigma^2 I``; for an anisotropic ``C`` the 95 % quantile of
``sum_i lambda_i z_i^2`` (``lambda`` the eigenvalues of ``C``, ``z`` standard normal), which lies
between ``1.96 sqrt(lambda_max)`` and ``2.80 sqrt(lambda_max)``: the sphere holds 95 %, it is not
the (smaller-volume) 95 % ellipsoid. The definitions per seeker are in ``docs/seekers.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SourceEstimate", "PlanPosterior", "sphere_radius95_m", "centres_estimate", "reported_estimate",
           "NO_ESTIMATE"]

#: What a seeker without a model of the source says (its ``source_estimate`` returns None).
NO_ESTIMATE = "none: this seeker has no estimate of its own"
_DIRECTIONS = 4000  # points of the sphere quadrature in sphere_radius95_m


@dataclass(frozen=True)
class PlanPosterior:
    """A compact plan-view (east, north) posterior: probabilities on a square grid.

    Attributes
    ----------
    east0_m, north0_m : float
        The grid's south-west corner (ENU metres).
    cell_m : float
        Cell side, metres.
    prob_e4 : ndarray of int, shape (n, n)
        Probability of each cell in units of ``1e-4`` (rows: north, columns: east), rounded.
    outside : float
        Probability outside the grid.
    """

    east0_m: float
    north0_m: float
    cell_m: float
    prob_e4: np.ndarray
    outside: float

    def __post_init__(self):
        p = np.asarray(self.prob_e4)
        if p.ndim != 2 or p.shape[0] != p.shape[1] or p.size == 0:
            raise ValueError(f"prob_e4 must be a square 2D grid, got shape {p.shape}")
        if not (np.isfinite(self.cell_m) and self.cell_m > 0):
            raise ValueError(f"cell_m must be a positive finite number, got {self.cell_m!r}")
        if np.any(p < 0):
            raise ValueError("prob_e4 must be >= 0")

    def to_json(self) -> dict:
        """The log's form: ``east0_m``, ``north0_m``, ``cell_m``, ``prob_e4`` (list of rows), ``outside``."""
        return {"east0_m": round(float(self.east0_m), 3), "north0_m": round(float(self.north0_m), 3),
                "cell_m": round(float(self.cell_m), 4), "prob_e4": np.asarray(self.prob_e4, dtype=int).tolist(),
                "outside": round(float(self.outside), 4)}

    @classmethod
    def weighted(cls, east, north, w, centre_en, half_m: float, cells: int = 24) -> "PlanPosterior":
        """The weighted 2D histogram of points ``(east, north)`` with weights ``w`` (summing to 1)
        on ``cells x cells`` cells of side ``2 half_m / cells`` centred on ``centre_en``."""
        e0, n0 = float(centre_en[0]) - half_m, float(centre_en[1]) - half_m
        edges_e = np.linspace(e0, e0 + 2.0 * half_m, cells + 1)
        edges_n = np.linspace(n0, n0 + 2.0 * half_m, cells + 1)
        h, _, _ = np.histogram2d(north, east, bins=(edges_n, edges_e), weights=w)
        return cls(e0, n0, 2.0 * half_m / cells, np.rint(h * 1e4).astype(int),
                   max(0.0, 1.0 - float(h.sum())))


@dataclass(frozen=True)
class SourceEstimate:
    """One estimate of the source and what is known of its error.

    Attributes
    ----------
    enu : ndarray, shape (3,)
        The estimated source, ENU metres.
    region95_m : float or None
        Radius of the sphere about ``enu`` holding 95 % of the probability (as ``basis`` defines
        it); None: no region (``basis`` says why).
    basis : str
        What the region is (e.g. "posterior 95 % region"), in one sentence.
    plan_map : PlanPosterior or None
        A plan-view posterior, for seekers that have one.

    Raises
    ------
    ValueError
        ``enu`` not a finite 3-vector, ``region95_m`` NaN, infinite or negative, empty ``basis``.
    """

    enu: np.ndarray
    region95_m: float | None
    basis: str
    plan_map: PlanPosterior | None = None

    def __post_init__(self):
        enu = np.asarray(self.enu, dtype=float)
        if enu.shape != (3,) or not np.all(np.isfinite(enu)):
            raise ValueError(f"enu must be a finite 3-vector, got {self.enu!r}")
        object.__setattr__(self, "enu", enu)
        if self.region95_m is not None:
            r = float(self.region95_m)
            if not np.isfinite(r):
                raise ValueError(f"region95_m must be finite or None, got {self.region95_m!r}")
            if r < 0:
                raise ValueError(f"region95_m must be >= 0, got {self.region95_m!r}")
            object.__setattr__(self, "region95_m", r)
        if not isinstance(self.basis, str) or not self.basis.strip():
            raise ValueError(f"basis must be a non-empty sentence, got {self.basis!r}")


def sphere_radius95_m(cov) -> float:
    """Radius of the sphere about the mean of ``N(mean, cov)`` that holds 95 % of it (metres).

    ``X = R u`` with ``R^2 ~ chi2_3`` and ``u`` uniform on the unit sphere, independent, so
    ``P(|X|^2 <= x) = E_u[F_chi2_3(x / (u^T L u))]`` (``L`` the eigenvalues of ``cov``); the mean
    over ``u`` is taken on a Fibonacci lattice of 4000 directions (the integrand is smooth: the
    isotropic and the degenerate cases agree with ``chi2_3`` and ``chi2_1`` to 1e-9) and the 95 %
    point found by bisection.

    Parameters
    ----------
    cov : array_like, shape (3, 3)
        Symmetric positive semi-definite covariance, square metres.

    Returns
    -------
    float
        ``2.795 sigma`` for ``sigma^2 I``; ``1.960 sigma`` for a covariance of rank one; 0 for 0.

    Raises
    ------
    ValueError
        Not a finite 3x3 matrix.
    """
    from scipy.optimize import brentq
    from scipy.special import gammainc

    c = np.asarray(cov, dtype=float)
    if c.shape != (3, 3) or not np.all(np.isfinite(c)):
        raise ValueError(f"cov must be a finite 3x3 matrix, got shape {c.shape}")
    lam = np.clip(np.linalg.eigvalsh(0.5 * (c + c.T)), 0.0, None)
    top = float(lam.max())
    if top == 0.0:
        return 0.0
    i = np.arange(_DIRECTIONS) + 0.5
    z = 1.0 - 2.0 * i / _DIRECTIONS
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    u2 = np.stack([(1.0 - z * z) * np.cos(phi) ** 2, (1.0 - z * z) * np.sin(phi) ** 2, z * z], axis=1)
    q = np.maximum(u2 @ (lam / top), 1e-300)
    x = brentq(lambda x: float(np.mean(gammainc(1.5, 0.5 * x / q))) - 0.95, 3.0, 8.5, xtol=1e-12)
    return float(np.sqrt(x * top))


def centres_estimate(centres, min_centres: int = 8) -> SourceEstimate:
    """The mean of recent formation centres, with the radius about it holding 95 % of them.

    That region is where the formation wandered, not a confidence region for the source: the
    seeker has no model of the source, and a formation stalled beside a plume wanders in a small
    region far from the release. ``basis`` says so.

    Parameters
    ----------
    centres : array_like, shape (M, 3)
        The centres, oldest first (M >= 1).
    min_centres : int
        Fewer centres than this: no region (None).
    """
    c = np.asarray(centres, dtype=float)
    if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0:
        raise ValueError(f"centres must have shape (M >= 1, 3), got {c.shape}")
    mean = c.mean(axis=0)
    if len(c) < min_centres:
        return SourceEstimate(mean, None, f"mean of the last {len(c)} formation centres; no region "
                                          f"(fewer than {min_centres} centres)")
    radius = float(np.quantile(np.linalg.norm(c - mean, axis=1), 0.95))
    return SourceEstimate(mean, radius, f"mean of the last {len(c)} formation centres; region: 95 % of them "
                                        "within it (no model of the source: not a confidence region)")


def reported_estimate(seeker, monitor, k: int = 0) -> SourceEstimate | None:
    """What a mission reports: ``seeker.source_estimate(k)`` (trial ``k``; the mission's is 0) when
    the seeker has one, else the convergence monitor's (of that trial's centres)
    :meth:`~estimator.seeking.ConvergenceMonitor.source_estimate` (None before any centre)."""
    own = getattr(seeker, "source_estimate", None)
    est = None if own is None else own(k)
    if est is not None:
        return est
    return monitor.source_estimate()
