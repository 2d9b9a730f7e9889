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

Holding alone is safe but not *live*: two vehicles that want to cross (a swap, slots rotated
about the centre after a re-formation) are held at their previous setpoints tick after tick, and
the gate asks for the same straight steps again: frozen for good (docs/faults.md, "separation-hold
deadlock"). So, from that safe all-held batch, each held vehicle in turn (lowest index first: a
fixed priority) is **moved aside** (:func:`_move_aside`): it takes the best of a few candidate
steps, its straight step, that step with every component closing in on a neighbour removed
(relative to the neighbour's own step: the pair then never comes closer than it starts), a step
to its right of the nearest neighbour ("keep right": two vehicles head-on pass each other), and
halves of those, no longer than its own step and no steeper, inside the fence (``allowed``). A
candidate is taken only if every pair it is part of, against the batch as it now stands, needs no
more than it gets: each move keeps the batch safe, so the result is as safe as holding everyone.
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
    moved_aside : numpy.ndarray of bool, shape (N,), optional
        Vehicles first held, then moved aside: neither at their previous setpoint nor at the one
        asked for (:func:`_move_aside`). None: nobody.
    """

    positions_enu: np.ndarray
    held: np.ndarray
    conflicts: tuple = ()
    unresolved: bool = False
    rounds: int = 0
    moved_aside: np.ndarray | None = None

    @property
    def interventions(self) -> int:
        """How many vehicles were held or moved aside."""
        aside = 0 if self.moved_aside is None else int(np.count_nonzero(self.moved_aside))
        return int(np.count_nonzero(self.held)) + aside

    def describe(self, min_separation_m: float, names=None, max_listed: int = 3) -> str:
        """One line for the operator ("" when no pair was in conflict).

        ``names[k]`` is how vehicle ``k`` is called (default: its index).
        """
        return describe_conflicts(self.conflicts, self.held, min_separation_m, names, max_listed,
                                  self.unresolved, self.moved_aside)


def describe_conflicts(conflicts, held, min_separation_m: float, names=None, max_listed: int = 3,
                       unresolved: bool = False, aside=None) -> str:
    """``"pairs 3-7 0.50 m would come closer than 1.5 m: vehicle(s) [3, 7] held ..."`` ("" if none);
    ``aside``: the vehicles moved aside instead (bool mask, optional)."""
    if not conflicts:
        return ""
    name = (lambda k: k) if names is None else (lambda k: names[k])
    pairs = ", ".join("{}-{} {:.2f} m".format(*sorted((name(i), name(j))), d) for i, j, d in conflicts[:max_listed])
    more = f" and {len(conflicts) - max_listed} more" if len(conflicts) > max_listed else ""
    who = [name(k) for k in np.flatnonzero(held)]
    left = "; UNRESOLVED: a vehicle outside the fence could not be held" if unresolved else ""
    moved = [] if aside is None else [name(k) for k in np.flatnonzero(aside)]
    done = ([f"vehicle(s) {who} held at their previous setpoints"] if who or not moved else []) \
        + ([f"vehicle(s) {moved} moved aside"] if moved else [])
    return f"pairs {pairs}{more} would come closer than {min_separation_m:g} m: {', '.join(done)}{left}"


def hold_for_separation(p0, p1, sep_m: float, holdable, pairs=None, allowed=None) -> SeparationHold:
    """Hold vehicles at their previous setpoints until no pair is in conflict, then move the held
    ones aside where that keeps the batch safe (module docstring).

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
    allowed : callable, optional
        ``allowed(start, end)`` for ``(K, 3)`` arrays: bool ``(K,)``, whether each straight move
        ``start -> end`` stays inside the fence and altitude band. Without it a held vehicle is
        only moved along its own step (``p0 -> p1`` was already allowed), never sideways.

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
            unresolved = bool((cand & ~fixed).any())
            if unresolved:
                return SeparationHold(out, held, conflicts, unresolved=True, rounds=rounds)
            return _with_moves_aside(p0, p1, out, held, sep_m, allowed, conflicts, rounds)
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
            return _with_moves_aside(p0, p1, out, held, sep_m, allowed, conflicts, rounds)


def _with_moves_aside(p0, p1, out, held, sep_m, allowed, conflicts, rounds) -> SeparationHold:
    """The all-held safe batch ``out`` with each held vehicle moved aside where it can be."""
    out, moved = _move_aside(p0, p1, out, held, sep_m, allowed)
    still = held & np.all(out == p0, axis=1)
    aside = moved & ~still & ~np.all(out == p1, axis=1)   # a full straight step after all: no intervention
    return SeparationHold(out, still, conflicts, unresolved=False, rounds=rounds, moved_aside=aside)


def _move_aside(p0, p1, out, held, sep_m, allowed):
    """Give each held vehicle (lowest index first) its best safe candidate step.

    ``out`` is a safe batch (every pair gets what it needs). Vehicle ``k``'s candidates
    (:func:`_candidate_steps`) are checked against every other vehicle's path as the batch now
    stands; the one with the most progress along its own step is taken (a sidestep, no progress,
    rather than holding), so the batch stays safe after each move. Returns ``(out, moved)``.
    """
    out = out.copy()
    moved = np.zeros(len(p0), dtype=bool)
    for k in np.flatnonzero(held):
        step = p1[k] - p0[k]
        cands = _candidate_steps(k, p0, out, step, sep_m)
        if not len(cands):
            continue
        ends = p0[k] + cands
        ok = _safe_for(k, p0, out, ends, sep_m)
        side = np.any(np.abs(np.cross(cands, step)) > 1e-12 * max(float(step @ step), 1e-300), axis=1)
        if allowed is not None and ok.any():
            ok[ok & side] = np.asarray(allowed(np.repeat(p0[k:k + 1], int(np.count_nonzero(ok & side)), 0),
                                               ends[ok & side]), dtype=bool)
        elif allowed is None:
            ok &= ~side
        if not ok.any():
            continue
        gain = cands[ok] @ step
        best = int(np.argmax(gain + 1e-9 * np.linalg.norm(cands[ok], axis=1)))  # a sidestep over holding
        out[k] = ends[ok][best]
        moved[k] = True
    return out, moved


def _safe_for(k, p0, out, ends, sep_m) -> np.ndarray:
    """Whether each candidate end of vehicle ``k`` gives every pair ``(k, j)`` what it needs."""
    others = np.flatnonzero(np.arange(len(p0)) != k)
    d = synchronous_distance(p0[k][None, None], ends[:, None], p0[others][None], out[others][None])
    need = np.minimum(sep_m, np.linalg.norm(p0[others] - p0[k], axis=1)) * (1.0 - _REL_TOL)
    return np.all(d >= need[None, :], axis=1)


def _candidate_steps(k, p0, out, step, sep_m) -> np.ndarray:
    """Vehicle ``k``'s candidate steps ``(C, 3)``: no longer than ``step`` nor steeper (vertical part
    at most ``step``'s), so the speed limits the gate applied still hold.

    The straight step; the step with every component closing in on a near neighbour removed,
    relative to that neighbour's own step (projections; then the pair's distance never shrinks);
    a step of the same length to the right of the nearest neighbour, seen from ``k`` (two
    vehicles head-on pass each other), forward-right, both projected the same way; halves of all.
    """
    length = float(np.linalg.norm(step))
    if length <= 0.0:
        return np.zeros((0, 3))
    steps_o = out - p0
    gap = np.linalg.norm(p0 - p0[k], axis=1)
    near = np.flatnonzero((gap < sep_m + length + np.linalg.norm(steps_o, axis=1) + 1e-9) & (gap > 1e-9))
    near = near[near != k]
    if not len(near):
        return step[None]
    u = (p0[k] - p0[near]) / gap[near, None]          # from each neighbour to k
    nearest = u[int(np.argmin(gap[near]))]
    right = np.array([-nearest[1], nearest[0], 0.0])   # right of the direction towards the neighbour
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right *= length / np.linalg.norm(right)
    forward_right = 0.5 ** 0.5 * (right + step)

    def parted(c):
        for _ in range(3):
            for uj, sj in zip(u, steps_o[near]):
                closing = float((c - sj) @ uj)
                if closing < 0.0:
                    c = c - closing * uj
        return c

    base = [step, parted(step.copy()), parted(forward_right), parted(right.copy())]
    cands = np.array(base + [0.5 * c for c in base])
    return np.array([_within(c, step, length) for c in cands])


def _within(c, step, length):
    """``c`` scaled down to at most ``length`` long and no steeper than ``step``."""
    n = float(np.linalg.norm(c))
    if n > length:
        c = c * (length / n)
    vmax = abs(float(step[2]))
    if abs(c[2]) > vmax * (1.0 + 1e-12):
        c = c.copy()
        c[2] = np.sign(c[2]) * vmax
    return c
