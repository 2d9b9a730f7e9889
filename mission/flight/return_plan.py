"""Planning the return (and any layered move) clear of lost vehicles that still fly.

See :mod:`mission.flight.return_clear` for the rules; this module holds the geometry:
:func:`landing_spots` (a landing spot clear of the obstacles for each vehicle),
:func:`plan_clear_return` (layered legs, detours at the layers, or a synchronous transfer, the
first that keeps the clearance) and :func:`path_clearance`. No I/O, no coordinator.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mission.flight.obstacles import plan_clear_transfer, segment_clearance
from mission.safety.geometry import segment_distance

__all__ = ["ClearPlan", "landing_spots", "path_clearance", "plan_clear_return"]

#: the transfer flies at this fraction of the speed limits so that the ramp keeps up with it
_TRANSFER_SPEED_FRACTION = 0.8
#: detours through two via points try the pairs among this many candidates each side
_MAX_VIAS = 160
#: how many times a return may be re-planned after new losses (each re-plan starts where it is)


@dataclass(frozen=True)
class ClearPlan:
    """A return (or any layered move) planned clear of obstacles.

    Attributes
    ----------
    waypoints_enu : numpy.ndarray, shape (K, N, 3)
        Configurations from the start (row 0) to the goal (row ``K - 1``); each vehicle flies
        straight between consecutive rows.
    times_s : numpy.ndarray or None
        ``(K,)`` times of a synchronous plan (every vehicle starts and ends each leg together),
        or None: batch by batch (every vehicle reaches a row before any starts the next).
    strategy : str
        ``layered``, ``layered+detour``, ``transfer (<plan_transfer strategy>)``.
    clearance_m : float
        Smallest distance from any path to any obstacle (``inf`` without obstacles).
    clear : bool
        ``clearance_m`` is at least the clearance asked for.
    """

    waypoints_enu: np.ndarray
    times_s: np.ndarray | None
    strategy: str
    clearance_m: float
    clear: bool


def path_clearance(waypoints_enu, obstacle_points) -> float:
    """Smallest distance from the straight legs of ``waypoints_enu`` ``(K, N, 3)`` to the points.

    Returns ``inf`` without points; a single row is checked as points.
    """
    w = np.asarray(waypoints_enu, dtype=float)
    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    if not len(obs):
        return float("inf")
    if len(w) == 1:
        return segment_clearance(w[0], w[0], obs)
    return min(segment_clearance(a, b, obs) for a, b in zip(w[:-1], w[1:]))


def _point_clearance(a, b, obs) -> np.ndarray:
    """``(M,)`` distance from each segment ``a[m] -> b[m]`` to the nearest of ``obs``."""
    if not len(obs):
        return np.full(len(a), np.inf)
    return segment_distance(a[:, None, :], b[:, None, :], obs[None, :, :], obs[None, :, :]).min(axis=1)


def _horizontal_ok(fence, xy) -> np.ndarray:
    if fence is None:
        return np.ones(len(xy), dtype=bool)
    pts = np.c_[xy, np.full(len(xy), fence.min_alt_m + 0.01)]
    return np.atleast_1d(fence.contains(pts))


def landing_spots(homes_enu, layer_alt_m, obstacle_points, clearance_m: float, min_separation_m: float,
                  fence=None, rtl: bool = False, max_shift_m: float = 15.0):
    """Where each vehicle lands: its home, or the nearest clear spot beside it.

    Parameters
    ----------
    homes_enu : array_like, shape (N, 3)
        Homes (mission ENU, ground altitude).
    layer_alt_m : array_like, shape (N,)
        Altitude each vehicle descends from.
    obstacle_points : array_like, shape (K, 3)
    clearance_m : float
        Distance to keep from the obstacles.
    min_separation_m : float
        Horizontal distance kept between a moved spot and every other vehicle's spot.
    fence : mission.safety.envelope.Geofence, optional
        A moved spot must be inside its polygon.
    rtl : bool
        The vehicles RTL: a home is obstructed by an obstacle horizontally within the
        clearance at any altitude (the autopilot's own path over home), not only by one near
        the descent column.
    max_shift_m : float
        Farthest a spot is moved from its home.

    Returns
    -------
    spots : numpy.ndarray, shape (N, 3)
        Landing spots (at the home's altitude).
    moved : numpy.ndarray of bool, shape (N,)
        The spot is not the home (the vehicle must land there: no RTL).
    clear : numpy.ndarray of bool, shape (N,)
        The descent column over the spot keeps the clearance (False: no clear spot found, the
        home is kept).
    """
    homes = np.asarray(homes_enu, dtype=float).reshape(-1, 3)
    layers = np.asarray(layer_alt_m, dtype=float).reshape(-1)
    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    n = len(homes)
    spots = homes.copy()
    moved = np.zeros(n, dtype=bool)
    clear = np.ones(n, dtype=bool)
    if not len(obs):
        return spots, moved, clear
    c = float(clearance_m)

    def _column_clear(xy, i):
        return _column_clearance(xy, layers[i], homes[i, 2], obs) >= c

    for i in range(n):
        if rtl:
            blocked = bool(np.min(np.linalg.norm(obs[:, :2] - homes[i, :2], axis=1)) < c)
        else:
            blocked = not bool(_column_clear(homes[i:i + 1, :2], i)[0])
        if not blocked:
            continue
        others = np.delete(spots[:, :2], i, axis=0)
        found = _nearest_clear_spot(homes[i, :2], lambda xy, i=i: _column_clear(xy, i) & _horizontal_ok(fence, xy),
                                    others, obs, min_separation_m, max_shift_m)
        if found is None:
            clear[i] = False
            continue
        spots[i, :2] = found
        moved[i] = True
    return spots, moved, clear


def _column_clearance(xy, layer_alt_m: float, ground_alt_m: float, obs) -> np.ndarray:
    """``(M,)`` distance from the vertical descent columns over ``xy`` ``(M, 2)`` to the obstacles."""
    top = np.c_[xy, np.full(len(xy), max(layer_alt_m, ground_alt_m))]
    bottom = np.c_[xy, np.full(len(xy), ground_alt_m)]
    return _point_clearance(top, bottom, obs)


def _nearest_clear_spot(home_xy, ok_at, others, obs, min_separation_m: float, max_shift_m: float):
    """The nearest spot beside ``home_xy`` (rings every 0.5 m, 15 deg) where ``ok_at(xy)`` holds and that
    is ``min_separation_m`` from ``others``; among the clear ones of a ring, the farthest from the
    obstacles. None within ``max_shift_m``."""
    angles = np.radians(np.arange(0.0, 360.0, 15.0))
    ring = np.c_[np.cos(angles), np.sin(angles)]
    for d in np.arange(0.5, max_shift_m + 1e-9, 0.5):
        xy = home_xy + d * ring
        ok = ok_at(xy)
        if len(others):
            ok &= np.min(np.linalg.norm(xy[:, None] - others[None], axis=-1), axis=1) >= min_separation_m
        if np.any(ok):
            far = np.min(np.linalg.norm(xy[:, None] - obs[None, :, :2], axis=-1), axis=1)
            return xy[np.flatnonzero(ok)[np.argmax(far[ok])]]
    return None


def _via_candidates(obs, z_m, clearance_m):
    """Horizontal detour points about every obstacle near altitude ``z_m`` (``(M, 3)``)."""
    pts = []
    angles = np.radians(np.arange(0.0, 360.0, 15.0))
    ring = np.c_[np.cos(angles), np.sin(angles)]
    for q in obs:
        dz = abs(float(q[2]) - z_m)
        if dz >= clearance_m:
            continue
        r = float(np.sqrt(clearance_m ** 2 - dz ** 2))
        for k in (1.1, 1.4, 2.0, 3.0):
            xy = q[:2] + k * r / np.cos(np.pi / len(angles)) * ring
            pts.append(np.c_[xy, np.full(len(xy), z_m)])
    return np.vstack(pts) if pts else np.zeros((0, 3))


def _detour(u, a, obs, clearance_m, fence):
    """Horizontal polyline ``[via...]`` from ``u`` to ``a`` (same altitude) clear of ``obs``.

    Returns the via points (``(0..2, 3)``, shortest found) or None.
    """
    if _point_clearance(u[None], a[None], obs)[0] >= clearance_m:
        return np.zeros((0, 3))
    cand = _via_candidates(obs, float(u[2]), clearance_m)
    if not len(cand):
        return None
    inside = np.ones(len(cand), dtype=bool)
    if fence is not None:
        inside = np.atleast_1d(fence.contains(cand))
    cand = cand[inside]
    if not len(cand):
        return None
    m = len(cand)
    first = _point_clearance(np.repeat(u[None], m, axis=0), cand, obs) >= clearance_m
    last = _point_clearance(cand, np.repeat(a[None], m, axis=0), obs) >= clearance_m
    if fence is not None:
        first &= np.atleast_1d(fence.segment_inside(np.repeat(u[None], m, axis=0), cand))
        last &= np.atleast_1d(fence.segment_inside(cand, np.repeat(a[None], m, axis=0)))
    du = np.linalg.norm(cand - u, axis=1)
    da = np.linalg.norm(cand - a, axis=1)
    single = first & last
    if np.any(single):
        k = np.flatnonzero(single)[np.argmin((du + da)[single])]
        return cand[k:k + 1]
    # two via points: the pairs among the (at most _MAX_VIAS) reachable candidates most on the way
    on_way = du + da
    i_idx = np.flatnonzero(first)[np.argsort(on_way[first])][:_MAX_VIAS]
    j_idx = np.flatnonzero(last)[np.argsort(on_way[last])][:_MAX_VIAS]
    if not len(i_idx) or not len(j_idx):
        return None
    p, q = np.meshgrid(i_idx, j_idx, indexing="ij")
    p, q = p.ravel(), q.ravel()
    mid = _point_clearance(cand[p], cand[q], obs) >= clearance_m
    if fence is not None:
        mid &= np.atleast_1d(fence.segment_inside(cand[p], cand[q]))
    if not np.any(mid):
        return None
    length = du[p] + np.linalg.norm(cand[p] - cand[q], axis=1) + da[q]
    k = np.flatnonzero(mid)[np.argmin(length[mid])]
    return np.vstack([cand[p[k]], cand[q[k]]])


def _batch_separation(waypoints) -> float:
    """Smallest distance between two vehicles' paths within a batch (vehicles not in step)."""
    w = np.asarray(waypoints, dtype=float)
    if w.shape[1] < 2:
        return float("inf")
    best = float("inf")
    for a, b in zip(w[:-1], w[1:]):
        d = segment_distance(a[:, None], b[:, None], a[None], b[None])
        np.fill_diagonal(d, np.inf)
        best = min(best, float(d.min()))
    return best


def _retimed(wps, max_speed_m_s, max_vertical_speed_m_s):
    """Leg times at which the ramp keeps up with every vehicle (horizontal and vertical limits)."""
    d = np.diff(wps, axis=0)
    dt = np.maximum(np.linalg.norm(d, axis=-1) / max_speed_m_s,
                    np.abs(d[..., 2]) / max_vertical_speed_m_s).max(axis=1)
    return np.r_[0.0, np.cumsum(dt / _TRANSFER_SPEED_FRACTION)]


def plan_clear_return(start, goal, layer_alt_m, obstacle_points, min_separation_m: float, clearance_m: float,
                      max_speed_m_s: float, max_vertical_speed_m_s: float = 1.0, fence=None) -> ClearPlan:
    """Layered legs from ``start`` to ``goal`` keeping ``clearance_m`` from the obstacles.

    Parameters
    ----------
    start, goal : array_like, shape (N, 3)
        Mission ENU metres (for the return, the goal is above each landing spot at its layer).
    layer_alt_m : array_like, shape (N,)
        Each vehicle's altitude layer (``mission.flight.layers``: shared only by vehicles whose
        paths keep apart; distinct layers ``1.25 * min_separation_m`` apart).
    obstacle_points : array_like, shape (K, 3)
    min_separation_m : float
        Between vehicles.
    clearance_m : float
        From every obstacle, along every path.
    max_speed_m_s, max_vertical_speed_m_s : float
        Speed limits of the ramp (times of a synchronous transfer).
    fence : mission.safety.envelope.Geofence, optional

    Returns
    -------
    ClearPlan
        The first of ``layered``, ``layered+detour``, ``transfer`` that keeps the clearance
        (see the module docstring), else the candidate with the largest clearance
        (``clear=False``).

    Raises
    ------
    ValueError
        Shapes do not match or a coordinate is not finite.
    """
    s = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    lay = np.asarray(layer_alt_m, dtype=float).reshape(-1)
    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    if s.ndim != 2 or s.shape[1] != 3 or s.shape != g.shape or lay.shape != (len(s),):
        raise ValueError(f"start and goal must be (N, 3) and the layers (N,), got {s.shape}, {g.shape}, {lay.shape}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(g)) and np.all(np.isfinite(lay))
            and np.all(np.isfinite(obs))):
        raise ValueError("start, goal, layers and obstacles must be finite")
    c = float(clearance_m)
    up = s.copy()
    up[:, 2] = lay
    across = g.copy()
    across[:, 2] = lay
    layered = np.stack([s, up, across, g])
    cl = path_clearance(layered, obs)
    if cl >= c:
        return ClearPlan(layered, None, "layered", cl, True)
    candidates = [ClearPlan(layered, None, "layered", cl, False)]
    # the same legs with horizontal detours at each vehicle's own layer
    for plan in (_detoured(s, up, across, g, obs, c, min_separation_m, fence),
                 # synchronous transfer with the obstacles as fixed participants
                 _transfer(s, g, obs, c, min_separation_m, max_speed_m_s, max_vertical_speed_m_s, fence)):
        if plan is not None and plan.clear:
            return plan
        if plan is not None:
            candidates.append(plan)
    return max(candidates, key=lambda p: p.clearance_m)


def _detoured(s, up, across, g, obs, c: float, min_separation_m: float, fence) -> ClearPlan | None:
    """The layered legs with horizontal detours at each vehicle's own layer, or None (the vertical
    legs are not clear, no detour needed, or the detours of one batch come too close)."""
    if path_clearance(np.stack([s, up]), obs) < c or path_clearance(np.stack([across, g]), obs) < c:
        return None
    vias, complete = [], True
    for i in range(len(s)):
        v = _detour(up[i], across[i], obs, c, fence)
        if v is None:
            complete, v = False, np.zeros((0, 3))
        vias.append(v)
    k = max(len(v) for v in vias)
    rows = [np.array([v[j] if j < len(v) else across[i] for i, v in enumerate(vias)]) for j in range(k)]
    det = np.stack([s, up, *rows, across, g])
    det_cl = path_clearance(det, obs)
    if not k or _batch_separation(det[1:-1]) < min_separation_m:
        return None
    return ClearPlan(det, None, "layered+detour", det_cl, complete and det_cl >= c)


def _transfer(s, g, obs, c: float, min_separation_m: float, max_speed_m_s: float, max_vertical_speed_m_s: float,
              fence) -> ClearPlan | None:
    """A synchronous transfer with the obstacles as fixed participants (clearance ``c``, else the
    separation), retimed for the ramp; None when none can be planned."""
    from mission.safety.transfer import TransferError

    for need in (c, min_separation_m):
        try:
            tp = plan_clear_transfer(s, g, obs, min_separation_m, max_speed_m_s, fence=fence, clearance_m=need)
        except (TransferError, ValueError):
            continue
        wps = np.asarray(tp.waypoints_enu, dtype=float)
        tr_cl = path_clearance(wps, obs)
        return ClearPlan(wps, _retimed(wps, max_speed_m_s, max_vertical_speed_m_s), f"transfer ({tp.strategy})",
                         tr_cl, tr_cl >= c)
    return None
