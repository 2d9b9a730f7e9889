"""Asynchronous distributed constrained Lloyd on the sphere (paper Section III, after [cortes2004]).

At each step one robot, chosen at random, wakes up, learns the current positions of its Voronoi
(Delaunay) neighbours only, computes its own spherical Voronoi cell *locally* from itself and
those neighbours, and moves to the cell's constrained centroid. A robot's cell depends only on
its Delaunay neighbours (every Voronoi edge of a cell is a bisector with a Delaunay neighbour),
so the local cell is exactly its cell in the whole tessellation.

Neighbour discovery itself (which robots are my Voronoi neighbours now?) is simulated here from
the current tessellation of all positions; on real robots it is the communication layer's job
(e.g. the adjustable sensing radius of Cortes et al. 2004). The order is a fresh random
permutation per round, so every robot updates once per round, in a random asynchronous order.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from .spherical_cells import _cells_unit, _oriented_hull, normalise_points

__all__ = ["DistributedResult", "distributed_lloyd", "local_centroid"]


@dataclass(frozen=True)
class DistributedResult:
    """Outcome of the asynchronous distributed Lloyd algorithm.

    Attributes
    ----------
    points : numpy.ndarray
        ``(n, 3)`` unit generators.
    energy : float
        Exact CVT energy of ``points``.
    rounds : int
        Completed rounds (each robot updated once per round).
    updates : int
        Individual robot updates.
    max_move : float
        Largest single-robot move of the last round.
    converged : bool
        ``max_move < tol``.
    """

    points: np.ndarray
    energy: float
    rounds: int
    updates: int
    max_move: float
    converged: bool


def local_centroid(own, neighbours):
    """Constrained centroid of a robot's cell computed from its neighbours' positions only.

    Parameters
    ----------
    own : array_like, shape (3,)
        The robot's (non-zero) position relative to the formation centre.
    neighbours : array_like, shape (k, 3)
        Positions of its Voronoi neighbours, ``k >= 3``.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` unit vector: the radially projected mass centroid of the robot's cell.

    Raises
    ------
    ValueError
        If fewer than 3 neighbours are given or the local configuration is degenerate.
    """
    pts = normalise_points(np.vstack([np.reshape(own, (1, 3)), neighbours]))
    _, _, cint, _ = _cells_unit(pts)
    c = cint[0]
    return c / np.linalg.norm(c)


def _neighbours_of(p, i):
    tri = _oriented_hull(p)[0]
    nbrs = np.unique(tri[np.any(tri == i, axis=1)])
    return nbrs[nbrs != i]


def distributed_lloyd(points, seed=0, max_rounds=5000, tol=1e-10):
    """Run asynchronous distributed Lloyd from ``points`` until a round moves nobody by ``tol``.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Initial positions relative to the formation centre (projected on the unit sphere),
        ``n >= 4``.
    seed : int or numpy.random.Generator, optional
        Randomness of the update order (``numpy.random.default_rng(seed)``).
    max_rounds : int, optional
        Cap on the number of rounds.
    tol : float, optional
        Stop after a full round in which no robot moved by ``tol`` or more (unit sphere).

    Returns
    -------
    DistributedResult
        The final unit generators (a CVT to ``tol``) and convergence figures.

    Raises
    ------
    ValueError
        On bad arguments or degenerate positions.
    """
    p = normalise_points(points)
    if isinstance(max_rounds, bool) or not isinstance(max_rounds, numbers.Integral):
        raise ValueError(f"max_rounds must be a positive integer, got {max_rounds!r}")
    if max_rounds < 1:
        raise ValueError(f"max_rounds must be a positive integer, got {max_rounds!r}")
    tol = float(tol)
    if not tol > 0.0 or not math.isfinite(tol):
        raise ValueError(f"tol must be a finite positive number, got {tol!r}")
    rng = np.random.default_rng(seed)
    n = p.shape[0]
    rounds = updates = 0
    round_move = math.inf
    while rounds < max_rounds and round_move >= tol:
        round_move = 0.0
        for i in rng.permutation(n):
            nbrs = _neighbours_of(p, i)  # neighbour discovery (the communication layer's job)
            new = local_centroid(p[i], p[nbrs])
            round_move = max(round_move, float(np.linalg.norm(new - p[i])))
            p[i] = new
            updates += 1
        rounds += 1
    _, _, _, energy = _cells_unit(p)
    return DistributedResult(p, energy, rounds, updates, round_move, bool(round_move < tol))
