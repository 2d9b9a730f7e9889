"""Altitude layers shared by vehicles whose paths are far apart (takeoff, assembly, return).

A layered move (:func:`mission.flight.targets.layered_transfer`) flies every vehicle in three
batches, each finished by every vehicle before the next starts: vertically over its start to its
layer, horizontally at its layer to above its goal, vertically to its goal. One layer per vehicle
needs ``N`` layers (``1.25 * min_separation_m`` apart: 50 vehicles need 92 m); here vehicles
*share* a layer when their whole paths stay apart horizontally, so the number of layers grows
with how many paths cross, not with ``N``.

**The rule** (:func:`shared_layers`). Each vehicle's path projects onto the plane as one segment,
from its start to its goal (both vertical legs are at its ends). Two vehicles *conflict* when
those segments come closer than ``min_separation_m + margin_m`` (closed-form segment distance,
the vehicles are not assumed to fly in step). Conflicting vehicles get different layers (greedy
colouring of the conflict graph, the best of a few vertex orders); two vehicles on one layer are then at least
``min_separation_m + margin_m`` apart horizontally at every point of their three legs, whatever
their timing. Vehicles on different layers are ``1.25 * min_separation_m`` apart vertically
during the horizontal batch. During a vertical batch, two vehicles whose columns are closer than
``min_separation_m + margin_m`` (stacked at the start, or at the goal) move at the same vertical
speed from the same instant, so their vertical gap is monotone between its value before and
after the batch; it keeps its sign (and so the separation) when their layers are in the order of
their altitudes at that end. The colours are therefore given in a topological order of that
"above" relation, each vehicle above all the stacked vehicles below it (a pair stacked in
opposite orders at the two ends cannot be layered and is refused).
"""
from __future__ import annotations

import numpy as np

from mission.safety.geometry import segment_distance

__all__ = ["LAYER_MARGIN_M", "LAYER_SPACING_FACTOR", "layer_conflicts", "layers_keep_apart", "shared_layers"]

#: extra horizontal distance, beyond ``min_separation_m``, between the paths of vehicles on one layer
LAYER_MARGIN_M = 0.5
#: vertical distance between two layers, in units of ``min_separation_m``
LAYER_SPACING_FACTOR = 1.25


def layer_conflicts(start_enu_m, goal_enu_m, clearance_m: float) -> np.ndarray:
    """``(N, N)`` bool: the horizontal paths ``start -> goal`` of two vehicles come within ``clearance_m``.

    Parameters
    ----------
    start_enu_m, goal_enu_m : array_like, shape (N, 3) or (N, 2)
        Starts and goals (only east and north are used).
    clearance_m : float
        Horizontal distance two vehicles on one layer keep.

    Returns
    -------
    numpy.ndarray of bool, shape (N, N)
        Symmetric, False on the diagonal.
    """
    s = np.asarray(start_enu_m, dtype=float)[:, :2]
    g = np.asarray(goal_enu_m, dtype=float)[:, :2]
    n = len(s)
    conflict = np.zeros((n, n), dtype=bool)
    # row blocks keep the (n, n, 2) temporaries small for large fleets
    block = 64
    for lo in range(0, n, block):
        hi = min(n, lo + block)
        d = segment_distance(s[lo:hi, None], g[lo:hi, None], s[None, :], g[None, :])
        conflict[lo:hi] = d < clearance_m
    np.fill_diagonal(conflict, False)
    return conflict


def _below(start, goal, clearance_m: float) -> np.ndarray:
    """``below[i, j]``: ``j`` must be on a lower layer than ``i`` (stacked lower at an end).

    Raises
    ------
    ValueError
        Two vehicles stacked in opposite vertical orders at the two ends.
    """
    below = np.zeros((len(start), len(start)), dtype=bool)
    for end in (start, goal):
        h = end[:, :2]
        stacked = np.linalg.norm(h[:, None] - h[None, :], axis=-1) < clearance_m
        below |= stacked & (end[:, 2][None, :] < end[:, 2][:, None])
    np.fill_diagonal(below, False)
    both = below & below.T
    if np.any(both):
        i, j = (int(k) for k in np.argwhere(both)[0])
        raise ValueError(f"vehicles {i} and {j} are stacked in opposite vertical orders at the start and at "
                         f"the goal: no layering keeps them apart")
    return below


def _colours(conflict: np.ndarray, below: np.ndarray, order_key: np.ndarray) -> np.ndarray:
    """Greedy colouring in a topological order of ``below`` (smallest ``order_key`` first among the ready)."""
    n = len(conflict)
    indeg = below.sum(axis=1)
    ready = sorted((i for i in range(n) if indeg[i] == 0), key=lambda k: (order_key[k], k))
    colours = -np.ones(n, dtype=int)
    while ready:
        i = ready.pop(0)
        used = set(colours[conflict[i]].tolist())
        c = max((int(colours[j]) + 1 for j in np.flatnonzero(below[i])), default=0)
        while c in used:
            c += 1
        colours[i] = c
        newly = []
        for k in np.flatnonzero(below[:, i]):
            indeg[k] -= 1
            if indeg[k] == 0:
                newly.append(int(k))
        ready = sorted(ready + newly, key=lambda k: (order_key[k], k))
    if np.any(colours < 0):  # pragma: no cover - _below refuses 2-cycles; longer ones cannot occur
        raise ValueError("the vertical order of stacked vehicles has a cycle: no layering keeps them apart")
    return colours


def shared_layers(start_enu_m, goal_enu_m, low_alt_m: float, high_alt_m: float, min_separation_m: float,
                  margin_m: float = LAYER_MARGIN_M) -> np.ndarray:
    """Each vehicle's altitude layer for a layered move ``start -> goal``, layers shared where safe.

    Parameters
    ----------
    start_enu_m, goal_enu_m : array_like, shape (N, 3)
        Where each vehicle starts and ends the move (mission ENU metres).
    low_alt_m, high_alt_m : float
        The lowest layer is at ``low_alt_m``; every layer must be at or below ``high_alt_m``.
    min_separation_m : float
        Separation to keep; layers are ``LAYER_SPACING_FACTOR * min_separation_m`` apart.
    margin_m : float
        Vehicles on one layer keep ``min_separation_m + margin_m`` horizontally along their paths.

    Returns
    -------
    numpy.ndarray, shape (N,)
        Layer altitude of each vehicle (see the module docstring for the rule).

    Raises
    ------
    ValueError
        The layers do not fit below ``high_alt_m``, or two vehicles are stacked in opposite orders
        at the two ends.
    """
    s = np.asarray(start_enu_m, dtype=float).reshape(-1, 3)
    g = np.asarray(goal_enu_m, dtype=float).reshape(-1, 3)
    if s.shape != g.shape:
        raise ValueError(f"start and goal must have the same shape, got {s.shape} and {g.shape}")
    if not len(s):
        return np.zeros(0)
    clearance = float(min_separation_m) + float(margin_m)
    conflict, below = layer_conflicts(s, g, clearance), _below(s, g, clearance)
    travel_m = np.linalg.norm(g[:, :2] - s[:, :2], axis=1)
    # greedy colouring is order-sensitive: a few orders, the fewest layers kept
    keys = (g[:, 2], s[:, 2], -conflict.sum(axis=1).astype(float), travel_m)
    colours = min((_colours(conflict, below, k) for k in keys), key=lambda c: (int(c.max()), int(c.sum())))
    spacing = LAYER_SPACING_FACTOR * float(min_separation_m)
    alts = float(low_alt_m) + spacing * colours
    if alts.max() > high_alt_m + 1e-9:
        raise ValueError(f"{len(s)} vehicles need {int(colours.max()) + 1} shared altitude layers {spacing:.2f} m "
                         f"apart from {low_alt_m:.1f} m, up to {alts.max():.1f} m, above the allowed "
                         f"{high_alt_m:.1f} m: widen the geofence altitude band, lower takeoff_alt_m or "
                         f"spread the homes")
    return alts


def layers_keep_apart(start_enu_m, goal_enu_m, layer_alt_m, min_separation_m: float,
                      margin_m: float = LAYER_MARGIN_M) -> bool:
    """Whether given layers obey the rule of :func:`shared_layers` for the move ``start -> goal``.

    Vehicles on one layer must not conflict; stacked vehicles (at either end) must have their
    layers in the order of their altitudes there, and distinct layers must be
    ``LAYER_SPACING_FACTOR * min_separation_m`` apart.

    Parameters
    ----------
    start_enu_m, goal_enu_m : array_like, shape (N, 3)
    layer_alt_m : array_like, shape (N,)
    min_separation_m, margin_m : float
        As for :func:`shared_layers`.

    Returns
    -------
    bool
    """
    s = np.asarray(start_enu_m, dtype=float).reshape(-1, 3)
    g = np.asarray(goal_enu_m, dtype=float).reshape(-1, 3)
    lay = np.asarray(layer_alt_m, dtype=float).reshape(-1)
    clearance = float(min_separation_m) + float(margin_m)
    dz = np.abs(lay[:, None] - lay[None, :])
    same = dz < 1e-6
    np.fill_diagonal(same, False)
    if np.any(same & layer_conflicts(s, g, clearance)):
        return False
    distinct = ~same
    np.fill_diagonal(distinct, False)
    if np.any(distinct & (dz < LAYER_SPACING_FACTOR * float(min_separation_m) - 1e-6)):
        return False
    try:
        below = _below(s, g, clearance)
    except ValueError:
        return False
    return not np.any(below & (lay[None, :] >= lay[:, None] - 1e-6))
