"""Vehicle-to-slot assignment with minimum total squared travel, and reconfiguration after a loss.

:func:`assign_slots` solves the linear assignment problem on squared distances
(``scipy.optimize.linear_sum_assignment``); with ``allow_rotation`` it alternates it with the
optimal proper rotation of the slots about the centre (Kabsch / orthogonal Procrustes). Each half
step minimises the same cost over one variable, so the cost never increases; the alternation is
started from the identity and, for small formations, from the 23 other rotations of the cube
group, and the best local optimum is kept.

:func:`reconfigure` builds the CVT for the survivors, warm-started from their current directions,
and assigns them to its (rotated) slots.
"""
from __future__ import annotations

import itertools
import numbers
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .cvt import _check_radius, cvt_from
from .fast_cvt import CVTResult
from .metrics import as_offsets

__all__ = ["Reconfiguration", "assign_slots", "reconfigure", "kabsch_rotation"]

#: Formations up to this size also try the 24 rotations of the cube group as starting points.
_MULTI_START_MAX = 64


def kabsch_rotation(source, target):
    """Proper rotation ``R`` minimising ``sum_i |target_i - R source_i|^2``.

    Parameters
    ----------
    source, target : numpy.ndarray
        ``(m, 3)`` paired vectors (about a common origin).

    Returns
    -------
    numpy.ndarray
        ``(3, 3)`` rotation matrix (``det = +1``; reflections are excluded).
    """
    h = source.T @ target
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def _cube_rotations():
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[np.arange(3), perm] = signs
            if np.linalg.det(m) > 0:
                mats.append(m)
    mats.sort(key=lambda m: -np.trace(m))  # identity first
    return mats


def _assign(x, s):
    cost = np.sum((x[:, None, :] - s[None, :, :]) ** 2, axis=2)
    rows, cols = linear_sum_assignment(cost)
    perm = np.empty(x.shape[0], dtype=int)
    perm[rows] = cols
    return perm, float(cost[rows, cols].sum())


def _alternate(x, s, rot, max_alternations):
    perm, cost = _assign(x, s @ rot.T)
    for _ in range(max_alternations):
        new_rot = kabsch_rotation(s[perm], x)
        new_perm, new_cost = _assign(x, s @ new_rot.T)
        if new_cost >= cost * (1.0 - 1e-12):
            if new_cost < cost:
                perm, cost, rot = new_perm, new_cost, new_rot
            break
        perm, cost, rot = new_perm, new_cost, new_rot
    return perm, cost, rot


def assign_slots(current_positions, slots, allow_rotation=False, centre=None, max_alternations=50):
    """Assign vehicles to slots minimising the total squared travel.

    Parameters
    ----------
    current_positions : array_like, shape (m, 3)
        Where the vehicles are now.
    slots : array_like, shape (k, 3)
        Target positions, ``k >= m`` (extra slots stay empty), same frame and units.
    allow_rotation : bool, optional
        Also rotate the slot set about ``centre`` (proper rotations only) to reduce the travel
        further, alternating assignment and Kabsch rotation (see the module docstring).
    centre : array_like, shape (3,), optional
        Centre of the rotation (the formation centre); default the origin.
    max_alternations : int, optional
        Cap on assignment/rotation alternations per start.

    Returns
    -------
    perm : numpy.ndarray
        ``(m,)`` ints: vehicle ``i`` goes to ``rotated_slots[perm[i]]``.
    rotated_slots : numpy.ndarray
        ``(k, 3)`` slots after the chosen rotation (the input slots if ``allow_rotation`` is
        false).

    Raises
    ------
    ValueError
        On bad shapes, non-finite values or more vehicles than slots.
    """
    x = as_offsets(current_positions, min_count=1, name="current_positions")
    s = as_offsets(slots, min_count=1, name="slots")
    if x.shape[0] > s.shape[0]:
        raise ValueError(f"more vehicles ({x.shape[0]}) than slots ({s.shape[0]})")
    c = np.zeros(3) if centre is None else as_offsets(np.reshape(centre, (1, 3)), name="centre")[0]
    if (
        isinstance(max_alternations, bool)
        or not isinstance(max_alternations, numbers.Integral)
        or max_alternations < 0
    ):
        raise ValueError(
            f"max_alternations must be a non-negative integer, got {max_alternations!r}"
        )
    if not allow_rotation:
        perm, _ = _assign(x, s)
        return perm, s
    xc, sc = x - c, s - c
    starts = _cube_rotations() if x.shape[0] <= _MULTI_START_MAX else [np.eye(3)]
    best = None
    for rot in starts:
        perm, cost, rot = _alternate(xc, sc, rot, int(max_alternations))
        if best is None or cost < best[1] * (1.0 - 1e-12):
            best = (perm, cost, rot)
    perm, _, rot = best
    return perm, sc @ rot.T + c


@dataclass(frozen=True)
class Reconfiguration:
    """New formation after a loss and the survivors' assignment to it.

    Attributes
    ----------
    slots : numpy.ndarray
        ``(m, 3)`` new offsets from the centre (norm ``radius``), ``m`` survivors.
    assignment : numpy.ndarray
        ``(m,)``: survivor ``k`` (``survivors[k]`` in the old numbering) flies to
        ``slots[assignment[k]]``.
    survivors : numpy.ndarray
        ``(m,)`` indices of the surviving vehicles in the input.
    travel_m : numpy.ndarray
        ``(m,)`` straight-line distance each survivor travels.
    total_sq_travel_m2 : float
        ``sum(travel_m ** 2)``, the minimised cost.
    rotation : numpy.ndarray
        ``(3, 3)`` rotation applied to the CVT to reduce the travel.
    cvt : CVTResult
        The unit-sphere CVT solve (energy, iterations, convergence).
    """

    slots: np.ndarray
    assignment: np.ndarray
    survivors: np.ndarray
    travel_m: np.ndarray
    total_sq_travel_m2: float
    rotation: np.ndarray
    cvt: CVTResult


def _survivor_mask(lost, n):
    if isinstance(lost, (bool, np.bool_)):
        raise ValueError("lost must be an index, a sequence of indices or a boolean mask")
    if isinstance(lost, numbers.Integral):
        lost = [int(lost)]
    arr = np.asarray(lost)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"a boolean lost mask must have shape ({n},), got {arr.shape}")
        return ~arr
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"lost indices must be integers, got {arr.dtype}")
    idx = arr.astype(int).ravel()
    if np.any(idx < -n) or np.any(idx >= n):
        raise ValueError(f"lost index out of range for {n} vehicles: {idx.tolist()}")
    mask = np.ones(n, dtype=bool)
    mask[idx] = False
    return mask


def reconfigure(current_offsets, lost, radius, method="auto", tol=1e-10):
    """CVT formation for the survivors of a loss, warm-started, with minimum-travel assignment.

    Parameters
    ----------
    current_offsets : array_like, shape (n, 3)
        Current positions of all vehicles relative to the formation centre (metres).
    lost : int, sequence of int or array_like of bool
        Index (or indices, or a length-``n`` mask) of the lost vehicle(s).
    radius : float
        Radius ``D`` of the new formation (metres).
    method : {"auto", "fast", "lbfgs", "lbfgs-scipy", "lloyd"}, optional
        CVT solver (see :func:`formation.cvt_sphere`).
    tol : float, optional
        Lloyd move tolerance of the CVT solve.

    Returns
    -------
    Reconfiguration
        New slots, the survivor-to-slot assignment and the travel it implies.

    Raises
    ------
    ValueError
        If fewer than 4 vehicles survive, a survivor sits at the centre, or an argument is bad.
    """
    x = as_offsets(current_offsets, min_count=1, name="current_offsets")
    radius = _check_radius(radius)
    mask = _survivor_mask(lost, x.shape[0])
    survivors = np.flatnonzero(mask)
    if survivors.size < 4:
        raise ValueError(f"a CVT formation needs at least 4 survivors, got {survivors.size}")
    xs = x[survivors]
    if np.any(np.linalg.norm(xs, axis=1) <= 1e-9 * radius):
        raise ValueError("a survivor sits at the formation centre: no direction to warm-start from")
    cvt = cvt_from(xs, method=method, tol=tol)
    unit_slots = cvt.points
    perm, rotated = assign_slots(xs, radius * unit_slots, allow_rotation=True)
    rotation = kabsch_rotation(unit_slots, rotated / radius)
    travel = np.linalg.norm(rotated[perm] - xs, axis=1)
    return Reconfiguration(
        slots=rotated,
        assignment=perm,
        survivors=survivors,
        travel_m=travel,
        total_sq_travel_m2=float(np.sum(travel**2)),
        rotation=rotation,
        cvt=cvt,
    )

