"""The paper's discretised constrained Lloyd algorithm (Section III), for comparison.

The sphere is replaced by a near-uniform mesh of points (here the Fibonacci lattice, which exists
for every number of points, unlike the subdivision mesh cited by the paper); each mesh point is
assigned to its nearest generator, a cell's centroid is the mean of its mesh points, projected
radially on the sphere. The result is a CVT of the *mesh*, so it differs from the exact CVT
(:func:`formation.cvt_sphere`) by the discretisation error: measure it with
:func:`formation.cvt_energy` (see ``tests/formation/test_formation_distributed.py`` and
``benchmarks/bench_cvt.py``).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .cvt import _check_n, _check_radius, random_sphere_points

__all__ = ["MeshLloydResult", "fibonacci_sphere", "lloyd_mesh", "lloyd_mesh_result"]


@dataclass(frozen=True)
class MeshLloydResult:
    """Outcome of the mesh-based Lloyd algorithm.

    Attributes
    ----------
    points : numpy.ndarray
        ``(n, 3)`` unit generators.
    iterations : int
        Lloyd iterations performed.
    max_move : float
        Largest generator displacement of the last iteration.
    converged : bool
        ``max_move < tol``.
    mesh_energy : float
        Discretised CVT energy ``(4 pi / m) sum_u |u - p(u)|^2`` over the ``m`` mesh points.
    """

    points: np.ndarray
    iterations: int
    max_move: float
    converged: bool
    mesh_energy: float


def fibonacci_sphere(m):
    """Fibonacci lattice: ``m`` near-uniform points on the unit sphere (equal-area bands).

    Parameters
    ----------
    m : int
        Number of points, ``m >= 1``.

    Returns
    -------
    numpy.ndarray
        ``(m, 3)`` unit vectors.
    """
    if isinstance(m, bool) or not isinstance(m, numbers.Integral) or m < 1:
        raise ValueError(f"mesh_points must be a positive integer, got {m!r}")
    k = np.arange(m) + 0.5
    z = 1.0 - 2.0 * k / m
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def lloyd_mesh_result(n, seed=0, mesh_points=20_000, max_iter=2000, tol=1e-12):
    """Discretised constrained Lloyd on a Fibonacci mesh of the unit sphere.

    Parameters
    ----------
    n : int
        Number of generators, ``n >= 4``.
    seed : int, optional
        Seed of the random initial generators (same draw as :func:`formation.cvt_sphere`).
    mesh_points : int, optional
        Number of mesh points; at least ``10 n`` so that no cell is empty in practice.
    max_iter : int, optional
        Iteration cap.
    tol : float, optional
        Stop when no generator moves by ``tol`` or more (on a mesh Lloyd stops exactly once
        the assignment no longer changes).

    Returns
    -------
    MeshLloydResult

    Raises
    ------
    ValueError
        On bad arguments.
    """
    n = _check_n(n)
    mesh = fibonacci_sphere(mesh_points)
    if mesh_points < 10 * n:
        raise ValueError(f"mesh_points must be at least 10 n = {10 * n}, got {mesh_points}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    tol = float(tol)
    if not tol > 0.0:
        raise ValueError(f"tol must be positive, got {tol!r}")
    p = random_sphere_points(n, seed)
    move = math.inf
    it = 0
    while it < max_iter and move >= tol:
        idx = cKDTree(p).query(mesh)[1]
        sums = np.stack([np.bincount(idx, weights=mesh[:, k], minlength=n) for k in range(3)], 1)
        norms = np.linalg.norm(sums, axis=1)
        new = p.copy()
        ok = norms > 0.0  # an empty cell keeps its generator
        new[ok] = sums[ok] / norms[ok, None]
        move = float(np.max(np.linalg.norm(new - p, axis=1)))
        p = new
        it += 1
    idx = cKDTree(p).query(mesh)[1]
    energy = 4.0 * math.pi / len(mesh) * float(np.sum((mesh - p[idx]) ** 2))
    return MeshLloydResult(p, it, move, bool(move < tol), energy)


def lloyd_mesh(n, radius=1.0, seed=0, mesh_points=20_000, max_iter=2000, tol=1e-12):
    """Offsets of the CVT formation computed with the paper's mesh-based Lloyd algorithm.

    Parameters
    ----------
    n : int
        Number of robots, ``n >= 4``.
    radius : float, optional
        Formation radius ``D``.
    seed, mesh_points, max_iter, tol
        See :func:`lloyd_mesh_result`.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` offsets of norm ``radius``.
    """
    radius = _check_radius(radius)
    res = lloyd_mesh_result(n, seed=seed, mesh_points=mesh_points, max_iter=max_iter, tol=tol)
    return radius * res.points
