"""CVT-based Spherical formation (paper Section III, eq. 7): constrained CVT on the sphere.

The generators are the robots' unit offsets ``p_i^c``; robot ``i`` flies at ``c + D p_i^c``.
Voronoi cells are computed exactly (spherical polygons, see :mod:`formation.spherical_cells`);
the constrained centroid of a cell is the radial projection of its exact mass centroid.

``method="auto"`` (the default) keeps the established solver (``"lbfgs"`` from a random start)
below :data:`FAST_MIN_N` generators, so every formation a mission can fly (n <= 254) and every
paper figure stays bit-identical, and uses the fast path (``"fast"``: a seeded rotation of a
Fibonacci sphere, L-BFGS with the Delaunay triangulation kept by edge flips) from there on.
Below 500 a single Fibonacci start can end in a worse local minimum than a random start (seen
at n = 16: d_min -3.3 %; n = 256: d_min -1.2..-4.0 %, energy +0.03..+0.09 %); from n = 300 to
2000 (tested seeds) its d_min was 1.6-8.5 % larger and its energy within +-0.22 %
(``benchmarks/bench_cvt.py``, docs/science.md).
"""
from __future__ import annotations

import math
import numbers

import numpy as np
from scipy.spatial.transform import Rotation

from .fast_cvt import METHODS, solve_cvt
from .spherical_cells import normalise_points

__all__ = [
    "FAST_MIN_N",
    "cvt_sphere",
    "cvt_sphere_result",
    "cvt_from",
    "fibonacci_start",
    "random_sphere_points",
]

_DEFAULT_MAX_ITER = 200_000

#: Smallest ``n`` for which ``method="auto"`` uses ``"fast"`` (above every mission formation).
FAST_MIN_N = 500


def _check_n(n):
    if isinstance(n, bool) or not isinstance(n, numbers.Integral):
        raise ValueError(f"n must be an integer number of robots, got {n!r}")
    if n < 4:
        raise ValueError(
            f"a CVT formation needs n >= 4 robots (a non-degenerate 3D spread), got n={n}"
        )
    return int(n)


def _check_radius(radius):
    try:
        radius = float(radius)
    except (TypeError, ValueError):
        raise ValueError(f"radius must be a finite positive number, got {radius!r}") from None
    if not math.isfinite(radius) or radius <= 0.0:
        raise ValueError(f"radius must be a finite positive number, got {radius!r}")
    return radius


def _check_solver(method, tol, max_iter):
    if method != "auto" and method not in METHODS:
        raise ValueError(f"method must be 'auto' or one of {METHODS}, got {method!r}")
    tol = float(tol)
    if not tol > 0.0 or not math.isfinite(tol):
        raise ValueError(f"tol must be a finite positive number, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    return method, tol, int(max_iter)


def _resolve(method, n):
    if method == "auto":
        return "fast" if n >= FAST_MIN_N else "lbfgs"
    return method


def fibonacci_start(n, seed=0):
    """Fibonacci sphere of ``n`` points turned by a uniform random rotation drawn from ``seed``.

    The start of the ``"fast"`` solver: near-uniform already (a CVT is reached in ~3x fewer
    L-BFGS steps than from random points, and with a larger d_min), deterministic for a seed.

    Parameters
    ----------
    n : int
        Number of points.
    seed : int or numpy.random.Generator, optional
        Seed (or generator) of the rotation.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` unit vectors.
    """
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    points = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    rotation = Rotation.random(random_state=np.random.default_rng(seed)).as_matrix()
    return points @ rotation.T


def random_sphere_points(n, seed=0):
    """Uniform random unit vectors from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    n : int
        Number of points.
    seed : int or numpy.random.Generator, optional
        Seed (or generator) of the initial draw.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` unit vectors.
    """
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1)[:, None]


def cvt_from(points, method="auto", tol=1e-10, max_iter=_DEFAULT_MAX_ITER):
    """Constrained CVT on the unit sphere warm-started from ``points``.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Initial generators, ``n >= 4`` non-zero vectors (projected radially on the sphere).
    method : {"auto", "fast", "lbfgs", "lbfgs-scipy", "lloyd"}, optional
        ``"lloyd"`` is plain exact Lloyd; ``"lbfgs"`` a quasi-Newton solver on the CVT energy
        after 300 Lloyd steps; ``"lbfgs-scipy"`` the same with scipy's L-BFGS-B; ``"fast"``
        L-BFGS straight from ``points`` with the triangulation kept between steps (see
        :mod:`formation.fast_cvt`); ``"auto"`` (default): ``"fast"`` if
        ``n >= FAST_MIN_N``, else ``"lbfgs"``.
    tol : float, optional
        Stop when one more Lloyd step would move every generator less than ``tol``.
    max_iter : int, optional
        Iteration cap.

    Returns
    -------
    CVTResult
        Unit generators, energy, residual move, iteration and evaluation counts.

    Raises
    ------
    ValueError
        On bad arguments or degenerate generators.
    """
    method, tol, max_iter = _check_solver(method, tol, max_iter)
    p = normalise_points(points)
    return solve_cvt(p, method=_resolve(method, p.shape[0]), tol=tol, max_iter=max_iter)


def _check_starts(n_starts):
    if isinstance(n_starts, bool) or not isinstance(n_starts, numbers.Integral) or n_starts < 1:
        raise ValueError(f"n_starts must be a positive integer, got {n_starts!r}")
    return int(n_starts)


def cvt_sphere_result(
    n, seed=0, method="auto", tol=1e-10, max_iter=_DEFAULT_MAX_ITER, n_starts=1
):
    """Constrained CVT of ``n`` generators on the unit sphere, with solver diagnostics.

    Parameters
    ----------
    n : int
        Number of generators, ``n >= 4``.
    seed : int, optional
        Seed of the initial generators (``numpy.random.default_rng(seed)``): uniform random
        points, or for ``"fast"`` the rotation of a Fibonacci sphere (:func:`fibonacci_start`).
    method, tol, max_iter
        See :func:`cvt_from`.
    n_starts : int, optional
        Solve from seeds ``seed, seed + 1, ..., seed + n_starts - 1`` and keep the lowest
        energy (the CVT energy has several local minima for most ``n``: e.g. for ``n = 20``
        seed 0 gives ``d_min = 0.749`` while the best of 12 seeds gives ``0.763``). With
        ``"fast"`` every seed gives a rotated copy of the same CVT, so ``n_starts > 1`` only
        costs time.

    Returns
    -------
    CVTResult
    """
    n = _check_n(n)
    method, tol, max_iter = _check_solver(method, tol, max_iter)
    n_starts = _check_starts(n_starts)
    method = _resolve(method, n)
    start = fibonacci_start if method == "fast" else random_sphere_points
    best = None
    for s in range(int(seed), int(seed) + n_starts):
        res = solve_cvt(start(n, s), method=method, tol=tol, max_iter=max_iter)
        if best is None or res.energy < best.energy:
            best = res
    return best


def cvt_sphere(
    n, radius=1.0, seed=0, method="auto", tol=1e-10, max_iter=_DEFAULT_MAX_ITER, n_starts=1
):
    """Offsets of the CVT-based Spherical formation (paper eq. 7).

    A constrained centroidal Voronoi tessellation of the sphere: every generator is the radial
    projection of the exact mass centroid of its own spherical Voronoi cell (to ``tol``).

    Parameters
    ----------
    n : int
        Number of robots, ``n >= 4``.
    radius : float, optional
        Formation radius ``D`` (positive).
    seed : int, optional
        Seed of the random initial generators; the result is deterministic for a seed.
    method : {"auto", "fast", "lbfgs", "lbfgs-scipy", "lloyd"}, optional
        Solver: ``"lloyd"`` is plain exact Lloyd; ``"lbfgs"`` minimises the CVT energy with
        L-BFGS (``"lbfgs-scipy"``: scipy's L-BFGS-B); ``"fast"`` is L-BFGS from a rotated
        Fibonacci sphere with the triangulation kept between steps; ``"auto"`` (default):
        ``"fast"`` if ``n >= FAST_MIN_N`` (500), else ``"lbfgs"``. All stop on the same rule.
    tol : float, optional
        Lloyd move tolerance (on the unit sphere).
    max_iter : int, optional
        Iteration cap; if reached the best configuration found is returned.
    n_starts : int, optional
        Number of consecutive seeds tried; the lowest-energy CVT is returned (default 1).

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` offsets from the formation centre, each of norm ``radius``.

    Raises
    ------
    ValueError
        If ``n`` is not an integer ``>= 4``, ``radius <= 0`` or a solver argument is invalid.

    Examples
    --------
    >>> import numpy as np
    >>> from formation import cvt_sphere
    >>> p = cvt_sphere(6)           # the regular octahedron
    >>> bool(np.allclose(np.linalg.norm(p, axis=1), 1.0))
    True
    """
    radius = _check_radius(radius)
    res = cvt_sphere_result(
        n, seed=seed, method=method, tol=tol, max_iter=max_iter, n_starts=n_starts
    )
    return radius * res.points
