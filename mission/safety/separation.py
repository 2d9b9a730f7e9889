"""Separation on a batch of setpoints: the close pairs, and holding vehicles so that none is left.

Every vehicle flies a straight line from its previous setpoint ``p0`` to its new one ``p1``, all
at constant speed over the same tick (the audit's model, :mod:`mission.safety.audit`). A pair is
*in conflict* when its closest approach on those paths (end points included,
:func:`mission.safety.geometry.synchronous_distance`) is below what it needs:

* ``min_separation_m`` for a pair that starts at least that far apart;
* its start distance for a pair that already starts closer (e.g. a vehicle re-admitted where it
  was heard): it may move apart or keep its distance, never come closer.

:func:`hold_for_separation` resolves conflicts by **holding** vehicles at their previous
setpoints: both vehicles of every pair in conflict, then again for the pairs the holds create
(a held vehicle is a fixed point another one may still fly into), until no pair is in conflict.
Holding everyone is conflict-free by construction (every pair keeps its start distance, which is
what it needs at most), so the iteration ends, after at most ``N`` rounds, with a safe batch —
unless a vehicle that would have to be held may not be (its previous setpoint is outside the
fence: the fence wins), which is reported as ``unresolved``. Only batches with a conflict cost
more than the one pruned pair check (:func:`close_pairs`).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mission.safety.geometry import synchronous_distance

__all__ = ["SeparationHold", "close_pairs", "describe_conflicts", "hold_for_separation"]

#: relative slack on the separation needed (floating point), as in the envelope's check
_REL_TOL = 1e-9


def _pair_distances(p):
    sq = np.einsum("ni,ni->n", p, p)
    return np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * p @ p.T, 0.0))


def close_pairs(p0, p1, sep_m):
    """Pairs ``i < j`` that may come closer than ``sep_m`` or be the closest pair, with their
    path and end-point distances.

    Two vehicles flying ``p0 -> p1`` are never closer than their start distance minus both
    steps: only pairs whose lower bound is below ``sep_m`` or below the smallest end-point
    distance (an upper bound of the minimum) need the exact path distance. The overall minimum
    over all pairs is exact.

    Returns
    -------
    ii, jj : numpy.ndarray of int
        The pairs kept.
    d_path_m, d_end_m : numpy.ndarray
        Their closest approach on the paths (end points included) and their end-point distance.
    """
    step = np.linalg.norm(p1 - p0, axis=1)
    d_start = _pair_distances(p0)
    d_end = _pair_distances(p1)
    upper = _upper_mask(len(p0))
    # (N, N) arrays and one mask: cheaper than gathering the N (N - 1) / 2 pairs first;
    # np.nonzero lists them in np.triu_indices order
    lower = d_start - step[:, None] - step[None, :]
    ends_min = np.where(upper, d_end, np.inf).min() if len(p0) >= 2 else np.inf
    ii, jj = np.nonzero(upper & ((lower < sep_m) | (lower <= ends_min)))
    ends = d_end[ii, jj]
    d_path = synchronous_distance(p0[ii], p1[ii], p0[jj], p1[jj])
    return ii, jj, np.minimum(d_path, ends), ends


@functools.lru_cache(maxsize=8)
def _upper_mask(n: int) -> np.ndarray:
    """Read-only ``(n, n)`` mask of the pairs ``i < j``."""
    mask = np.triu(np.ones((n, n), dtype=bool), 1)
    mask.setflags(write=False)
    return mask


def _needed_m(p0, ii, jj, sep_m):
    """What each pair needs: ``sep_m``, or its start distance if it starts closer (the same
    formula as the path distance, so a pair held at both ends meets it exactly)."""
    return np.minimum(sep_m, synchronous_distance(p0[ii], p0[ii], p0[jj], p0[jj])) * (1.0 - _REL_TOL)


@dataclass(frozen=True)
class SeparationHold:
    """Result of :func:`hold_for_separation`.

    Attributes
    ----------
    positions_enu : numpy.ndarray, shape (N, 3)
        The setpoints with the held vehicles back at their previous ones.
    held : numpy.ndarray of bool, shape (N,)
        Vehicles held (their setpoint would have moved; it did not).
    conflicts : tuple of (int, int, float)
        The pairs in conflict in the batch asked for: ``(i, j, closest approach m)``, closest first.
    unresolved : bool
        A conflict is left (a vehicle that had to be held had its previous setpoint outside the
        fence, so it was not held).
    rounds : int
        Rounds of holding (0: no conflict).
    """

    positions_enu: np.ndarray
    held: np.ndarray
    conflicts: tuple = ()
    unresolved: bool = False
    rounds: int = 0

    @property
    def interventions(self) -> int:
        """How many vehicles were held."""
        return int(np.count_nonzero(self.held))

    def describe(self, min_separation_m: float, names=None, max_listed: int = 3) -> str:
        """One line for the operator ("" when no pair was in conflict).

        ``names[k]`` is how vehicle ``k`` is called (default: its index).
        """
        return describe_conflicts(self.conflicts, self.held, min_separation_m, names, max_listed,
                                  self.unresolved)


def describe_conflicts(conflicts, held, min_separation_m: float, names=None, max_listed: int = 3,
                       unresolved: bool = False) -> str:
    """``"pairs 3-7 0.50 m would come closer than 1.5 m: vehicle(s) [3, 7] held ..."`` ("" if none)."""
    if not conflicts:
        return ""
    name = (lambda k: k) if names is None else (lambda k: names[k])
    pairs = ", ".join("{}-{} {:.2f} m".format(*sorted((name(i), name(j))), d) for i, j, d in conflicts[:max_listed])
    more = f" and {len(conflicts) - max_listed} more" if len(conflicts) > max_listed else ""
    who = [name(k) for k in np.flatnonzero(held)]
    left = "; UNRESOLVED: a vehicle outside the fence could not be held" if unresolved else ""
    return (f"pairs {pairs}{more} would come closer than {min_separation_m:g} m: vehicle(s) {who} "
            f"held at their previous setpoints{left}")


def hold_for_separation(p0, p1, sep_m: float, holdable, pairs=None) -> SeparationHold:
    """Hold vehicles at their previous setpoints until no pair is in conflict (module docstring).

    Parameters
    ----------
    p0, p1 : numpy.ndarray, shape (N, 3)
        Previous (sent) and new setpoints.
    sep_m : float
        Minimum separation.
    holdable : numpy.ndarray of bool, shape (N,)
        Vehicles that may be held (their previous setpoint is inside the fence).
    pairs : tuple, optional
        ``close_pairs(p0, p1, sep_m)`` if the caller has it already.

    Returns
    -------
    SeparationHold
        ``positions_enu`` is ``p1`` itself (not a copy) when nothing is in conflict.
    """
    n = len(p0)
    held = np.zeros(n, dtype=bool)
    if n < 2 or sep_m <= 0:
        return SeparationHold(p1, held)
    ii, jj, d_path, _ = close_pairs(p0, p1, sep_m) if pairs is None else pairs
    bad = d_path < _needed_m(p0, ii, jj, sep_m)
    if not bad.any():
        return SeparationHold(p1, held)
    order = np.argsort(d_path[bad], kind="stable")
    conflicts = tuple((int(i), int(j), float(d)) for i, j, d in
                      zip(ii[bad][order], jj[bad][order], d_path[bad][order]))
    out = p1.copy()
    moved = np.any(p1 != p0, axis=1)
    fixed = ~moved                      # held, or not moving anyway: already at p0
    cand = np.zeros(n, dtype=bool)
    cand[ii[bad]] = cand[jj[bad]] = True
    rounds = 0
    while True:
        rounds += 1
        new = cand & ~fixed & holdable
        if not new.any():               # every pair in conflict has a vehicle that cannot move back
            return SeparationHold(out, held, conflicts, unresolved=bool((cand & ~fixed).any()), rounds=rounds)
        out[new] = p0[new]
        held |= new
        fixed |= new
        # only pairs with a newly held vehicle changed; the others were checked already
        idx = np.flatnonzero(new)
        d = synchronous_distance(p0[idx, None], out[idx, None], p0[None], out[None])
        need = np.minimum(sep_m, synchronous_distance(p0[idx, None], p0[idx, None], p0[None], p0[None]))
        conflict = d < need * (1.0 - _REL_TOL)
        conflict[np.arange(len(idx)), idx] = False
        cand = np.zeros(n, dtype=bool)
        cand[np.flatnonzero(conflict.any(axis=0))] = True
        if not (cand & ~fixed).any():
            return SeparationHold(out, held, conflicts, unresolved=False, rounds=rounds)
