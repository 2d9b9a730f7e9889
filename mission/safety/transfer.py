"""Separation-keeping transfers: assembly, reconfiguration and return (pure maths).

A transfer moves N vehicles from ``start`` to ``goal`` (mission ENU metres) as a sequence of
*legs*; during a leg every moving vehicle flies a straight line at constant speed and all arrive
together, the others hover. Every leg is verified with the closed-form minimum distance of two
simultaneously moving points (:func:`mission.safety.geometry.synchronous_distance`), so the
plan keeps ``min_separation_m`` along the paths, not only at the waypoints.

Strategies, tried in this order by ``strategy="auto"``:

``direct``
    One leg, everyone at once (when it is already safe).
``sequenced``
    The direct moves split into groups that can fly together; each group flies while the others
    hover (greedy grouping, every group verified).
``layered``
    Staggered altitude layers: vehicles whose horizontal paths, starts or goals conflict get
    different layers (greedy graph colouring, layers ``min_separation_m`` apart above
    everything); climb to the layer, fly horizontally, descend to the goal; each of the three
    legs sequenced if needed.
``relayered``
    For vehicles stacked at both ends in opposite vertical orders (which ``layered`` cannot
    untangle: the vertical order must flip somewhere): climb to layers in the start's order,
    fly to a grid where nobody is stacked, exchange layers there, fly to the goal in layers in
    the goal's order and descend.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from mission.safety.geometry import synchronous_distance
from mission.safety.report import SafetyError

if TYPE_CHECKING:  # pragma: no cover
    from mission.safety.fence import Geofence

__all__ = ["TransferError", "TransferPlan", "plan_transfer", "leg_separation"]

_STRATEGIES = ("auto", "direct", "sequenced", "layered", "relayered")


class TransferError(SafetyError):
    """No separation-keeping transfer was found (or the inputs make one impossible)."""


@dataclass(frozen=True)
class TransferPlan:
    """A time-parametrised transfer.

    Attributes
    ----------
    times_s : numpy.ndarray, shape (K,)
        Waypoint times from 0 (start) to the end of the last leg.
    waypoints_enu : numpy.ndarray, shape (K, N, 3)
        Positions of every vehicle at each waypoint; between waypoints each vehicle flies a
        straight line at constant speed.
    strategy : str
        ``direct``, ``sequenced``, ``layered`` or ``relayered``.
    min_separation_m : float
        Smallest distance between two vehicles over the whole plan (paths included).
    """

    times_s: np.ndarray
    waypoints_enu: np.ndarray
    strategy: str
    min_separation_m: float

    @property
    def duration_s(self) -> float:
        """Total time of the transfer."""
        return float(self.times_s[-1])

    def position_at(self, t_s: float) -> np.ndarray:
        """Positions ``(N, 3)`` of every vehicle at time ``t_s`` (clamped to the plan)."""
        t = float(np.clip(t_s, 0.0, self.times_s[-1]))
        k = int(np.searchsorted(self.times_s, t, side="right")) - 1
        k = min(max(k, 0), len(self.times_s) - 2) if len(self.times_s) > 1 else 0
        if len(self.times_s) == 1:
            return self.waypoints_enu[0].copy()
        t0, t1 = self.times_s[k], self.times_s[k + 1]
        u = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return self.waypoints_enu[k] + u * (self.waypoints_enu[k + 1] - self.waypoints_enu[k])


def leg_separation(a, b) -> float:
    """Smallest pairwise distance while every vehicle flies ``a[i] -> b[i]`` simultaneously."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if len(a) < 2:
        return float("inf")
    d = synchronous_distance(a[:, None], b[:, None], a[None, :], b[None, :])
    np.fill_diagonal(d, np.inf)
    return float(d.min())


def _leg_ok(a, b, sep, fence):
    if leg_separation(a, b) < sep:
        return False
    if fence is not None:
        moving = np.nonzero(np.any(a != b, axis=1))[0]
        return all(fence.segment_inside(a[i], b[i]) for i in moving)
    return True


def _sequence(a, b, sep, fence):
    """Split leg ``a -> b`` into groups flying together; list of configurations or None."""
    cur = a.copy()
    remaining = [int(i) for i in np.argsort(-np.linalg.norm(b - a, axis=1)) if np.any(a[i] != b[i])]
    configs = []
    while remaining:
        target = cur.copy()
        group = []
        for i in remaining:
            trial = target.copy()
            trial[i] = b[i]
            # only pairs involving i can change: i against everyone on the trial leg
            d = synchronous_distance(cur[i], trial[i], cur, trial)
            d[i] = np.inf
            if d.min() >= sep and (fence is None or fence.segment_inside(cur[i], b[i])):
                target = trial
                group.append(i)
        if not group:
            return None
        remaining = [i for i in remaining if i not in group]
        cur = target
        configs.append(cur.copy())
    return configs


def _legs_or_sequence(configs, sep, fence):
    out = [configs[0]]
    for a, b in zip(configs[:-1], configs[1:]):
        if _leg_ok(a, b, sep, fence):
            out.append(b)
            continue
        seq = _sequence(a, b, sep, fence)
        if seq is None:
            return None
        out.extend(seq)
    return out


def _colour(start, goal, sep):
    """Greedy colouring of the horizontal conflict graph.

    Vehicles stacked (horizontally closer than ``sep``) at the start or at the goal must keep
    their vertical order on the way up to and down from the layers, so such pairs get the
    higher layer for the higher vehicle: colours are assigned in a topological order of that
    "above" relation, each above all of its "below" neighbours.
    """
    n = len(start)
    hs, hg = start[:, :2], goal[:, :2]
    stacked_s = np.linalg.norm(hs[:, None] - hs[None, :], axis=-1) < sep
    stacked_g = np.linalg.norm(hg[:, None] - hg[None, :], axis=-1) < sep
    conflict = stacked_s | stacked_g
    conflict |= synchronous_distance(hs[:, None], hg[:, None], hs[None, :], hg[None, :]) < sep
    np.fill_diagonal(conflict, False)
    # below[i, j]: j must be on a lower layer than i
    below = (stacked_s & (start[:, 2][None, :] < start[:, 2][:, None]))
    below |= (stacked_g & (goal[:, 2][None, :] < goal[:, 2][:, None]))
    np.fill_diagonal(below, False)
    below &= ~below.T  # contradictory orders (a swap of stacked vehicles): no constraint
    indeg = below.sum(axis=1)
    order, ready = [], [i for i in range(n) if indeg[i] == 0]
    done = np.zeros(n, dtype=bool)
    while len(order) < n:
        if not ready:  # a cycle: release the lowest remaining vehicle
            ready = [int(np.flatnonzero(~done)[np.argmin(start[~done, 2])])]
        ready.sort(key=lambda k: (start[k, 2], -conflict[k].sum()))
        i = ready.pop(0)
        if done[i]:
            continue
        order.append(i)
        done[i] = True
        for k in np.flatnonzero(below[:, i] & ~done):
            indeg[k] -= 1
            if indeg[k] == 0:
                ready.append(int(k))
    colours = -np.ones(n, dtype=int)
    for i in order:
        used = set(colours[conflict[i]].tolist())
        floor = max((colours[j] + 1 for j in np.flatnonzero(below[i]) if colours[j] >= 0), default=0)
        c = floor
        while c in used:
            c += 1
        colours[i] = c
    return colours


def _layered(start, goal, sep, fence, layer_base_alt_m):
    colours = _colour(start, goal, sep)
    step = sep * (1 + 1e-6)
    for base in _layer_bases(start, goal, sep, fence, layer_base_alt_m, int(colours.max()) + 1):
        layer = base + colours * step
        if fence is not None and (layer.min() < fence.min_alt_m or layer.max() > fence.max_alt_m):
            continue
        p1 = start.copy()
        p1[:, 2] = layer
        p2 = goal.copy()
        p2[:, 2] = layer
        legs = _legs_or_sequence([start, p1, p2, goal], sep, fence)
        if legs is not None:
            return legs
    return None


def _layer_bases(start, goal, sep, fence, layer_base_alt_m, n_layers):
    step = sep * (1 + 1e-6)
    if layer_base_alt_m is not None:
        return [layer_base_alt_m]
    bases = [max(start[:, 2].max(), goal[:, 2].max()) + step]
    if fence is not None:
        bases.append(min(start[:, 2].min(), goal[:, 2].min()) - step * n_layers)
    return bases


def _mid_grid(goal, sep):
    """Horizontal positions 2 * sep apart on a grid about the goal's centre, one per vehicle
    (minimum-travel assignment): nobody is stacked there, so altitudes can be exchanged."""
    n = len(goal)
    k = int(np.ceil(np.sqrt(n)))
    ij = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), axis=-1).reshape(-1, 2)
    grid = (ij - (k - 1) / 2.0) * 2.0 * sep + goal[:, :2].mean(axis=0)
    rows, cols = linear_sum_assignment(np.linalg.norm(goal[:, None, :2] - grid[None], axis=-1))
    mid = np.empty((n, 2))
    mid[rows] = grid[cols]
    return mid


def _relayered(start, goal, sep, fence, layer_base_alt_m):
    """Layers in the start's vertical order to a grid where nobody is stacked, exchange
    layers there, then layers in the goal's order down to the goal (for vehicles stacked at
    both ends in opposite orders, which ``layered`` cannot untangle)."""
    mid_h = _mid_grid(goal, sep)
    a_end = start.copy()
    a_end[:, :2] = mid_h
    b_start = goal.copy()
    b_start[:, :2] = mid_h
    col_a = _colour(start, a_end, sep)
    col_b = _colour(b_start, goal, sep)
    step = sep * (1 + 1e-6)
    n_layers = int(max(col_a.max(), col_b.max())) + 1
    for base in _layer_bases(start, goal, sep, fence, layer_base_alt_m, n_layers):
        la, lb = base + col_a * step, base + col_b * step
        if fence is not None and (min(la.min(), lb.min()) < fence.min_alt_m
                                  or max(la.max(), lb.max()) > fence.max_alt_m):
            continue
        wps = [start]
        for h, z in ((start[:, :2], la), (mid_h, la), (mid_h, lb), (goal[:, :2], lb)):
            wps.append(np.c_[h, z])
        wps.append(goal)
        legs = _legs_or_sequence(wps, sep, fence)
        if legs is not None:
            return legs
    return None


def plan_transfer(start, goal, min_separation_m: float, max_speed_m_s: float = 2.0,
                  fence: "Geofence | None" = None, strategy: str = "auto",
                  layer_base_alt_m: float | None = None) -> TransferPlan:
    """Plan a separation-keeping transfer of N vehicles from ``start`` to ``goal``.

    Parameters
    ----------
    start, goal : array_like, shape (N, 3)
        Positions (mission ENU metres). Both must already respect the separation.
    min_separation_m : float
        Minimum distance between any two vehicles at every instant (>= 0).
    max_speed_m_s : float
        Speed of the fastest vehicle on each leg (sets the leg durations).
    fence : Geofence, optional
        If given, every straight path must stay inside it (and the layers inside its band).
    strategy : {"auto", "direct", "sequenced", "layered", "relayered"}
        ``auto`` tries them in that order and returns the first that works.
    layer_base_alt_m : float, optional
        Altitude of the lowest layer for ``layered`` (default: ``min_separation_m`` above the
        highest start or goal, or below everything if that leaves the fence's band).

    Returns
    -------
    TransferPlan

    Raises
    ------
    TransferError
        Start or goal closer than the separation, outside the fence, or no strategy works.
    ValueError
        Bad shapes, NaN, non-positive speed, unknown strategy.
    """
    a = np.asarray(start, dtype=float)
    b = np.asarray(goal, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape:
        raise ValueError(f"start and goal must both be (N, 3), got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("start and goal must be finite")
    if strategy not in _STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}; choose one of {', '.join(_STRATEGIES)}")
    if not (np.isfinite(max_speed_m_s) and max_speed_m_s > 0):
        raise ValueError(f"max_speed_m_s must be > 0, got {max_speed_m_s!r}")
    sep = float(min_separation_m)
    if not (np.isfinite(sep) and sep >= 0):
        raise ValueError(f"min_separation_m must be >= 0, got {min_separation_m!r}")
    for name, cfg in (("start", a), ("goal", b)):
        s = leg_separation(cfg, cfg)
        if s < sep:
            raise TransferError(f"{name} positions are only {s:.2f} m apart < min separation {sep:g} m")
        if fence is not None and not np.all(fence.contains(cfg)):
            raise TransferError(f"{name} positions are not all inside the geofence")
    tried = _STRATEGIES[1:] if strategy == "auto" else (strategy,)
    for strat in tried:
        if strat == "direct":
            legs = [a, b] if _leg_ok(a, b, sep, fence) else None
        elif strat == "sequenced":
            legs = _legs_or_sequence([a, b], sep, fence)
        elif strat == "layered":
            legs = _layered(a, b, sep, fence, layer_base_alt_m)
        else:
            legs = _relayered(a, b, sep, fence, layer_base_alt_m)
        if legs is not None:
            return _timed(legs, strat, max_speed_m_s)
    raise TransferError(f"no transfer keeping {sep:g} m separation found (tried {', '.join(tried)})")


def _timed(legs, strategy, speed):
    wps = np.stack(legs)
    steps = np.linalg.norm(np.diff(wps, axis=0), axis=-1).max(axis=1) if len(wps) > 1 else np.zeros(0)
    keep = np.r_[True, steps > 0]
    wps = wps[keep]
    times = np.r_[0.0, np.cumsum(steps[steps > 0] / speed)]
    sep = min((leg_separation(x, y) for x, y in zip(wps[:-1], wps[1:])), default=leg_separation(wps[0], wps[0]))
    return TransferPlan(times, wps, strategy, float(sep))
