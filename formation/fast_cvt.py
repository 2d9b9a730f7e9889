"""CVT solvers on the unit sphere: exact Lloyd and L-BFGS on the CVT energy.

All solvers start from given unit generators and use the exact cells of
:mod:`formation.spherical_cells`. Their common stopping rule is Lloyd's: the largest distance
between a generator and its constrained centroid (the move one more Lloyd step would make) is
below ``tol``. So a result of any method is a Lloyd fixed point to ``tol``.

* ``"lloyd"``: ``p <- c / |c|``. Linear convergence; the rate tends to 1 as ``n`` grows.
* ``"lbfgs"`` (default): Riemannian L-BFGS on the product of unit spheres (retraction
  ``p <- unit(p + a d)``, memory 20, initial inverse Hessian = the Lloyd step
  ``diag(1 / (2 |c_i|))`` scaled by the last curvature pair, Armijo backtracking). It starts with
  300 plain Lloyd steps: the CVT energy has many local minima for large n and Lloyd's early path
  decides which one is reached; with this warm-up L-BFGS ends in the same minimum as plain
  Lloyd in most measured cases (see ``_warm_lloyd_steps`` and ``benchmarks/bench_cvt.py``).
  Its Armijo test allows for the rounding floor of the energy (~64 eps * 8 pi): near a CVT the
  energy decrease of a step (~1e-19 at a 1e-10 move) is far below the rounding error of the
  energy itself, so a strict energy line search stalls around a move of 1e-9..1e-8.
* ``"fast"``: the same L-BFGS without the Lloyd warm-up (the caller gives a near-uniform start,
  e.g. :func:`formation.cvt.fibonacci_start`), with the Delaunay triangulation kept between
  evaluations and repaired by Lawson flips (:class:`formation.spherical_cells._Triangulation`:
  ~11x cheaper per evaluation at n = 1000 than a ``ConvexHull`` each time) and with dot products
  that OpenBLAS keeps on one thread. Profile of ``"lbfgs"`` at n = 1000 (cProfile, 568
  evaluations): ``ConvexHull`` 75 % of the time, the rest of the cell arithmetic 15 %.
* ``"lbfgs-scipy"``: ``scipy.optimize.minimize(method="L-BFGS-B")`` on ``E(x / |x|)`` with
  unconstrained 3-vectors ``x``; its strict line search does stall as described, and an
  Anderson-accelerated Lloyd polish finishes the job. Kept for comparison: per iteration its
  ``setulb`` costs ~5 ms at n = 1000 (as much as one exact Voronoi evaluation).

Anderson acceleration (type II, depth 8, of the Lloyd map, restarted with a plain Lloyd step
whenever the residual does not decrease) is used as a polisher only (also by ``"lbfgs"`` if its
line search ever fails): started from random generators it is not energy-monotone and wanders
(it failed to converge for n = 200 in 5000 iterations), so it is not offered as a method.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from .spherical_cells import _cells_unit, _Triangulation

__all__ = ["CVTResult", "solve_cvt", "METHODS"]

#: Accepted values of ``method``.
METHODS = ("fast", "lbfgs", "lbfgs-scipy", "lloyd")


@dataclass(frozen=True)
class CVTResult:
    """Outcome of a CVT solve on the unit sphere.

    Attributes
    ----------
    points : numpy.ndarray
        ``(n, 3)`` unit generators.
    energy : float
        Exact CVT energy of ``points``.
    max_move : float
        Distance one more Lloyd step would move the farthest generator.
    iterations : int
        Solver iterations (Lloyd steps, L-BFGS iterations plus any polishing steps).
    evaluations : int
        Number of exact Voronoi evaluations (the cost driver).
    converged : bool
        ``max_move < tol``.
    method : str
        Solver used.
    """

    points: np.ndarray
    energy: float
    max_move: float
    iterations: int
    evaluations: int
    converged: bool
    method: str


class _Evaluator:
    """Caches exact cell evaluations of the current generators and counts them."""

    def __init__(self):
        self.count = 0

    def __call__(self, p, with_energy=True):
        self.count += 1
        _, _, cint, energy = _cells_unit(p, with_energy)
        cent = cint / np.linalg.norm(cint, axis=1)[:, None]
        move = float(np.max(np.linalg.norm(cent - p, axis=1)))
        return energy, cint, cent, move


class _CachedEvaluator(_Evaluator):
    """As :class:`_Evaluator`, but keeps the Delaunay triangulation between evaluations."""

    def __init__(self):
        super().__init__()
        self.triangulation = _Triangulation()

    def __call__(self, p, with_energy=True):
        self.count += 1
        if with_energy:
            cint, energy = self.triangulation.centroids_and_energy(p)
        else:
            _, cint, energy = self.triangulation.cells(p, with_energy=False)
        cent = cint / np.linalg.norm(cint, axis=1)[:, None]
        move = float(np.max(np.linalg.norm(cent - p, axis=1)))
        return energy, cint, cent, move


def _lloyd(p, tol, max_iter, ev, it0=0, final_energy=True):
    """Plain exact Lloyd: ``p <- c / |c|`` until the largest move is below ``tol``."""
    _, _, cent, move = ev(p, with_energy=False)
    it = it0
    while move >= tol and it < max_iter:
        p = cent
        _, _, cent, move = ev(p, with_energy=False)
        it += 1
    # a Lloyd step needs no energy: compute it once at the end
    energy = _cells_unit(p)[3] if final_energy else None
    return p, energy, move, it


def _anderson(p, tol, max_iter, ev, it0=0, depth=8):
    """Anderson-accelerated Lloyd (type II, restarted on any residual increase): a polisher."""
    energy, _, cent, move = ev(p)
    it = it0
    xs, fs = [], []  # history of iterates and residuals g(x) - x
    while move >= tol and it < max_iter:
        res = (cent - p).ravel()
        xs.append(p.ravel())
        fs.append(res)
        if len(xs) > depth + 1:
            xs.pop(0)
            fs.pop(0)
        if len(xs) > 1:
            d_f = np.diff(np.array(fs), axis=0).T
            d_x = np.diff(np.array(xs), axis=0).T
            gamma, *_ = np.linalg.lstsq(d_f, res, rcond=None)
            trial = p.ravel() + res - (d_x + d_f) @ gamma
            trial = trial.reshape(-1, 3)
            trial /= np.linalg.norm(trial, axis=1)[:, None]
        else:
            trial = cent
        try:
            t_energy, _, t_cent, t_move = ev(trial)
        except ValueError:
            t_move = np.inf
        if not t_move < move:
            # extrapolation went wrong: restart the history with a plain Lloyd step
            xs, fs = [], []
            trial = cent
            t_energy, _, t_cent, t_move = ev(trial)
        p, energy, cent, move = trial, t_energy, t_cent, t_move
        it += 1
    return p, energy, move, it


def _tangent_gradient(p, cint):
    """Riemannian gradient ``-2 (I - p p^T) c`` of the CVT energy, flattened."""
    return (-2.0 * (cint - np.einsum("ij,ij->i", p, cint)[:, None] * p)).ravel()


def _serial_dot(a, b, chunk=8192):
    """Dot product of 1-D arrays in chunks that OpenBLAS computes on one thread.

    OpenBLAS threads ``ddot`` above 10 000 entries; on a busy machine the threads' spinning
    cost ~10x the CPU time of the product (measured at 30 000 entries, i.e. n = 10 000).
    """
    if a.shape[0] <= chunk:
        return float(np.dot(a, b))
    return float(sum(np.dot(a[i : i + chunk], b[i : i + chunk]) for i in range(0, a.shape[0], chunk)))


def _two_loop(g, pairs, h0, dot=np.dot):
    """L-BFGS two-loop recursion: ``-H g`` with initial inverse Hessian ``diag(h0)``."""
    q = g.copy()
    alphas = []
    for s, y, rho in reversed(pairs):
        a = rho * dot(s, q)
        alphas.append(a)
        q -= a * y
    r = h0 * q
    for (s, y, rho), a in zip(pairs, reversed(alphas)):
        b = rho * dot(y, r)
        r += (a - b) * s
    return -r


def _warm_lloyd_steps(n):
    """Plain Lloyd steps before L-BFGS (300, whatever ``n``).

    The CVT energy has many local minima and Lloyd's early path decides which one it reaches.
    Measured at tol 1e-10 (relative energy vs plain Lloyd from the same seed): with 20 warm-up
    steps L-BFGS ended in another minimum in most cases (-3e-3..+1.5e-3, n = 100..1000); with 300
    steps it matched Lloyd to 1e-14 for 8 of 8 seeds at n = 100, 3 of 3 at n = 500, seed 0 at
    n = 1000. Different minima remain possible for large n (both are CVTs).
    """
    return 300


def _lbfgs(
    p, tol, max_iter, ev, warm_lloyd=None, memory=20, max_backtracks=12, scale_h0=True, dot=np.dot
):
    """Riemannian L-BFGS on the product of unit spheres, Lloyd-preconditioned.

    Retraction ``p <- unit(p + a d)``, identity vector transport, initial inverse Hessian
    ``diag(1 / (2 |c_i|))`` (one Lloyd step), Armijo backtracking with an allowance for the
    energy's rounding floor; Anderson polish when the line search stalls. ``dot`` computes
    the dot products of flattened vectors (``np.dot``, or :func:`_serial_dot` for large n).
    """
    if warm_lloyd is None:
        warm_lloyd = _warm_lloyd_steps(p.shape[0])
    p, _, _, it = _lloyd(p, tol, min(warm_lloyd, max_iter), ev, final_energy=False)
    energy, cint, _, move = ev(p)
    n = p.shape[0]
    noise = 64.0 * np.finfo(float).eps * 8.0 * np.pi  # |rounding error| of the energy sum
    g = _tangent_gradient(p, cint)
    pairs = []
    stalled = False
    while move >= tol and it < max_iter:
        h0 = np.repeat(0.5 / np.linalg.norm(cint, axis=1), 3)
        if pairs and scale_h0:
            s_last, y_last, rho_last = pairs[-1]
            h0 *= 1.0 / (rho_last * float(dot(y_last, h0 * y_last)))
        d = _two_loop(g, pairs, h0, dot)
        gd = float(dot(g, d))
        if not gd < 0.0:
            pairs.clear()
            d = -h0 * g
            gd = float(dot(g, d))
        alpha = 1.0
        for _ in range(max_backtracks):
            q = p + alpha * d.reshape(n, 3)
            q /= np.linalg.norm(q, axis=1)[:, None]
            try:
                e1, c1, _, m1 = ev(q)
            except ValueError:  # degenerate trial point: shorten the step
                alpha *= 0.25
                continue
            if e1 <= energy + 1e-4 * alpha * gd + noise:
                break
            # safeguarded quadratic interpolation of the energy along the step
            denom = 2.0 * (e1 - energy - gd * alpha)
            alpha = min(0.5 * alpha, max(0.1 * alpha, -gd * alpha * alpha / denom))
        else:
            stalled = True
            break
        g1 = _tangent_gradient(q, c1)
        s_vec = (q - p).ravel()
        y_vec = g1 - g
        sy = float(dot(s_vec, y_vec))
        if sy > 1e-12 * math.sqrt(float(dot(s_vec, s_vec))) * math.sqrt(float(dot(y_vec, y_vec))):
            pairs.append((s_vec, y_vec, 1.0 / sy))
            if len(pairs) > memory:
                pairs.pop(0)
        p, energy, cint, move, g = q, e1, c1, m1, g1
        it += 1
    if stalled and move >= tol and it < max_iter:
        p, energy, move, it = _anderson(p, tol, max_iter, ev, it0=it)
    return p, energy, move, it


def _lbfgs_scipy(p, tol, max_iter, ev, warm_lloyd=None):
    """scipy's L-BFGS-B on ``E(x / |x|)``, same warm-up, Anderson polish after its stall."""
    if warm_lloyd is None:
        warm_lloyd = _warm_lloyd_steps(p.shape[0])
    p, energy, move, it = _lloyd(p, tol, min(warm_lloyd, max_iter), ev)
    if move < tol or it >= max_iter:
        return p, energy, move, it
    n = p.shape[0]
    best = {"p": p, "energy": energy, "move": move}

    def fun(x):
        xs = x.reshape(n, 3)
        norms = np.linalg.norm(xs, axis=1)
        q = xs / norms[:, None]
        e, cint, _, mv = ev(q)
        if mv < best["move"]:
            best.update(p=q, energy=e, move=mv)
        tangent = cint - np.einsum("ij,ij->i", q, cint)[:, None] * q
        grad = -2.0 * tangent / norms[:, None]
        return e, grad.ravel()

    def stop(intermediate_result):
        if best["move"] < tol:
            raise StopIteration

    res = minimize(
        fun,
        p.ravel(),
        jac=True,
        method="L-BFGS-B",
        callback=stop,
        options={"maxiter": max(max_iter - it, 1), "maxcor": 20, "ftol": 0.0, "gtol": 0.0,
                 "maxls": 20},
    )
    it += int(res.nit)
    p, energy, move = best["p"], best["energy"], best["move"]
    if move >= tol and it < max_iter:
        p, energy, move, it = _anderson(p, tol, max_iter, ev, it0=it)
    return p, energy, move, it


def solve_cvt(points, method="lbfgs", tol=1e-10, max_iter=20000):
    """Run a CVT solver from unit generators ``points``.

    Parameters
    ----------
    points : numpy.ndarray
        ``(n, 3)`` unit vectors, ``n >= 4`` (not validated here; see :func:`formation.cvt_sphere`).
    method : {"lbfgs", "lbfgs-scipy", "lloyd"}
        Solver (see the module docstring).
    tol : float
        Stop when one more Lloyd step would move no generator farther than ``tol``.
    max_iter : int
        Iteration cap (the result then has ``converged=False``).

    Returns
    -------
    CVTResult
    """
    if method == "fast":
        ev = _CachedEvaluator()
        p, energy, move, it = _lbfgs(points, tol, max_iter, ev, warm_lloyd=0, dot=_serial_dot)
        return CVTResult(p, energy, move, it, ev.count, bool(move < tol), method)
    ev = _Evaluator()
    if method == "lloyd":
        out = _lloyd(points, tol, max_iter, ev)
    elif method == "lbfgs":
        out = _lbfgs(points, tol, max_iter, ev)
    elif method == "lbfgs-scipy":
        out = _lbfgs_scipy(points, tol, max_iter, ev)
    else:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    p, energy, move, it = out
    return CVTResult(p, energy, move, it, ev.count, bool(move < tol), method)
