"""Lost vehicles that still fly, as obstacles, and the geometry that keeps clear of them.

A vehicle lost by its link while armed and airborne (PX4 falls back to hold, ArduPilot GUIDED
holds its last target) stays where it was. For ``OBSTACLE_TTL_S`` of the mission clock after its
last frame, its last known position and its last setpoint (where it may still have been flying
to) are obstacles (:func:`obstacles`): re-formed slots are rotated about the centre so that none is
within ``min_separation_m + OBSTACLE_MARGIN_M`` of them (:func:`clear_offsets`), transfers are
planned with them as fixed participants (:func:`plan_clear_transfer`). A lost vehicle heard again
is an obstacle at its live position.
"""
from __future__ import annotations

import numpy as np

from mission.flight.modes import LEFT_MODES
from mission.flight.services import Fleet

__all__ = ["OBSTACLE_MARGIN_M", "OBSTACLE_TTL_S", "clear_offsets", "obstacles", "plan_clear_transfer",
           "plan_survivor_transfer", "segment_clearance"]

#: extra clearance (tracking error of the survivors and of the hovering vehicle)
OBSTACLE_MARGIN_M = 0.5
#: how long after its last frame a silent airborne vehicle is still assumed to hover there
OBSTACLE_TTL_S = 600.0


def obstacles(lost: dict, fleet: Fleet, now_s: float) -> np.ndarray:
    """``(K, 3)`` positions (mission ENU m) to keep clear of: lost vehicles still flying.

    A vehicle lost by its link (``reason == "link"``) that was last seen armed and above 1 m,
    whose last frame is less than :data:`OBSTACLE_TTL_S` old (its live position once heard
    again), and not re-admitted. Vehicles that left (RTL/LAND) fly away and are not included.
    ``lost``: the mission state's losses by system id; ``now_s``: the mission clock's time.
    """
    now = now_s
    pts = []
    for sysid, loss in lost.items():
        if loss.reason != "link" or now - loss.since_s > OBSTACLE_TTL_S:
            continue
        v = fleet.vehicles.get(sysid)
        if v is None:
            continue
        st = v.state
        alt = st.relative_alt_m
        if not st.armed or (alt is not None and alt < 1.0) or st.mode in LEFT_MODES.get(v.flavour, ()):
            continue
        pos = fleet.telemetry_position(sysid)
        for p in (pos, loss.last_setpoint_enu):
            if p is not None and np.all(np.isfinite(np.asarray(p, dtype=float))):
                pts.append(np.asarray(p, dtype=float))
    return np.array(pts, dtype=float).reshape(-1, 3)


def segment_clearance(a, b, points) -> float:
    """Smallest distance from the straight paths ``a[i] -> b[i]`` to any of ``points``.

    Parameters
    ----------
    a, b : array_like, shape (N, 3)
    points : array_like, shape (K, 3)

    Returns
    -------
    float
        ``inf`` when there are no points.
    """
    a = np.asarray(a, dtype=float).reshape(-1, 3)
    b = np.asarray(b, dtype=float).reshape(-1, 3)
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if not len(p) or not len(a):
        return float("inf")
    d = b - a                                            # (N, 3)
    rel = p[None, :, :] - a[:, None, :]                  # (N, K, 3)
    den = np.maximum(np.sum(d * d, axis=1), 1e-12)[:, None]
    t = np.clip(np.einsum("nkj,nj->nk", rel, d) / den, 0.0, 1.0)
    closest = a[:, None, :] + t[..., None] * d[:, None, :]
    return float(np.min(np.linalg.norm(p[None] - closest, axis=-1)))


def _yaw(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _candidate_rotations(allow_tilt: bool, seed: int = 0):
    yield np.eye(3)
    for deg in range(5, 181, 5):
        yield _yaw(np.radians(deg))
        yield _yaw(-np.radians(deg))
    if allow_tilt:
        from scipy.spatial.transform import Rotation

        for r in Rotation.random(200, random_state=seed).as_matrix():
            yield r


def clear_offsets(offsets: dict[int, np.ndarray], centre_enu, obstacle_points, clearance_m: float,
                  start_enu: dict[int, np.ndarray] | None = None,
                  allow_tilt: bool = True) -> tuple[dict[int, np.ndarray], bool]:
    """Rotate a formation about its centre so that no slot (nor path to it) is near an obstacle.

    Parameters
    ----------
    offsets : dict
        Sysid -> slot offset from the centre (m).
    centre_enu : array_like, shape (3,)
    obstacle_points : array_like, shape (K, 3)
    clearance_m : float
        Smallest distance allowed between a slot and an obstacle.
    start_enu : dict, optional
        Sysid -> where the vehicle is now; then the straight path to the slot must keep the
        clearance too.
    allow_tilt : bool
        Also try arbitrary rotations (CVT); otherwise only rotations about the vertical axis
        (which keep a symmetric cylinder symmetric and the slot altitudes unchanged).

    Returns
    -------
    (dict, bool)
        The offsets (the input ones if they are clear: identity first, then yaw by 5 deg steps
        either way, then random rotations) and whether a clear rotation was found (if not,
        the rotation with the largest clearance).
    """
    sysids = sorted(offsets)
    x = np.array([offsets[s] for s in sysids], dtype=float)
    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    if not len(obs) or not sysids:
        return dict(offsets), True
    c = np.asarray(centre_enu, dtype=float)
    a = None if start_enu is None else np.array([start_enu[s] for s in sysids], dtype=float)
    best, best_d = None, -np.inf
    for rot in _candidate_rotations(allow_tilt):
        slots = c + x @ rot.T
        d = float(np.min(np.linalg.norm(slots[:, None] - obs[None], axis=-1)))
        if a is not None:
            d = min(d, segment_clearance(a, slots, obs))
        if d >= clearance_m:
            return {s: x[i] @ rot.T for i, s in enumerate(sysids)}, True
        if d > best_d:
            best, best_d = rot, d
    return {s: x[i] @ best.T for i, s in enumerate(sysids)}, False


def plan_clear_transfer(start, goal, obstacle_points, min_separation_m: float, max_speed_m_s: float,
                        fence=None, clearance_m: float | None = None):
    """:func:`mission.safety.envelope.plan_transfer` with the obstacles as participants that do not move.

    The obstacles are appended to ``start`` and ``goal`` (same position in both), so the
    planner keeps ``min_separation_m`` from them along every path; a plan in which an obstacle's
    row moves (a layered strategy lifts every row) is rejected and the next strategy tried;
    last, the layered strategies for the movers alone, kept if every leg passes the obstacles at
    ``clearance_m`` or more.

    ``clearance_m`` (default ``min_separation_m``) is the distance every path must keep from
    the obstacles (e.g. ``min_separation_m + OBSTACLE_MARGIN_M``); the vehicles keep
    ``min_separation_m`` between themselves.

    Returns
    -------
    TransferPlan
        With the obstacle rows removed.

    Raises
    ------
    TransferError
        No strategy keeps the separation with the obstacles fixed.
    """
    from mission.safety.transfer import TransferError, plan_transfer

    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    if not len(obs):
        return plan_transfer(start, goal, min_separation_m, max_speed_m_s, fence=fence)
    clear_m = float(min_separation_m if clearance_m is None else max(clearance_m, min_separation_m))
    # fixed participants must be apart themselves (a lost vehicle's last position and last
    # setpoint are close): plan with a thinned set, then check every leg against all of them
    errors: list[str] = []
    tp = _plan_with_fixed(start, goal, obs, min_separation_m, max_speed_m_s, fence, clear_m, errors)
    if tp is not None:
        return tp
    # the layered strategies move every row: plan the movers alone, keep a plan whose every leg
    # stays clear of the obstacles
    for strategy in ("layered", "relayered"):
        try:
            tp = plan_transfer(start, goal, min_separation_m, max_speed_m_s, fence=fence, strategy=strategy)
        except TransferError:
            continue
        wps = np.asarray(tp.waypoints_enu, dtype=float)
        if min(segment_clearance(x, y, obs) for x, y in zip(wps[:-1], wps[1:])) >= clear_m:
            return tp
        errors.append(f"{strategy} (movers only): passes too close to an obstacle")
    raise TransferError("no transfer keeping clear of the lost vehicles still flying (" + "; ".join(errors) + ")")


def plan_survivor_transfer(start, goal, obstacle_points, min_separation_m: float, max_speed_m_s: float,
                           fence=None):
    """:func:`plan_clear_transfer`; when no plan keeps clear of the obstacles, a plan that keeps
    the movers' separation between themselves only (:func:`mission.safety.transfer.plan_transfer`).

    Found on ArduCopter SITL: 5 vehicles in a CVT of radius 2 m, one lost by a link cut and
    assumed hovering in the formation; no transfer of the 4 others kept clear of it, they flew
    straight under the safety envelope, two of them met (1.26 m), the envelope held both at their
    previous setpoints, and the mission aborted 32 s later: the formation never settled. Flying
    straight keeps no clearance from the obstacles either; this plan at least keeps the movers
    apart, so the envelope never has to hold two of them against each other.

    Returns
    -------
    tuple of (TransferPlan, str or None)
        The plan, and why it does not keep clear of the obstacles (None: it does).

    Raises
    ------
    TransferError
        Not even the movers alone can keep their separation.
    """
    from mission.safety.transfer import TransferError, plan_transfer

    try:
        return plan_clear_transfer(start, goal, obstacle_points, min_separation_m, max_speed_m_s, fence=fence), None
    except TransferError as exc:
        if not len(np.asarray(obstacle_points, dtype=float).reshape(-1, 3)):
            raise
        why = str(exc)
    return plan_transfer(start, goal, min_separation_m, max_speed_m_s, fence=fence), why


def _plan_with_fixed(start, goal, obs, min_separation_m: float, max_speed_m_s: float, fence, clear_m: float,
                     errors: list[str]):
    """:func:`plan_clear_transfer`'s first try: the obstacles (thinned) as participants that do not move.

    Returns the plan with the obstacle rows removed, or None (each strategy's failure appended to
    ``errors``).
    """
    from mission.safety.transfer import TransferError, plan_transfer
    from mission.safety.transfer import TransferPlan

    fixed = []
    for q in obs:
        if all(np.linalg.norm(q - f) >= min_separation_m for f in fixed):
            fixed.append(q)
    fixed = np.array(fixed)
    a = np.vstack([np.asarray(start, dtype=float), fixed])
    b = np.vstack([np.asarray(goal, dtype=float), fixed])
    n = len(a) - len(fixed)
    for strategy in ("direct", "sequenced", "layered", "relayered"):
        try:
            tp = plan_transfer(a, b, min_separation_m, max_speed_m_s, fence=fence, strategy=strategy)
        except TransferError as exc:
            errors.append(f"{strategy}: {exc}")
            continue
        wps = np.asarray(tp.waypoints_enu, dtype=float)
        if not np.allclose(wps[:, n:], fixed[None], atol=1e-6):
            errors.append(f"{strategy}: moves the obstacle")
            continue
        movers = wps[:, :n]
        if min(segment_clearance(x, y, obs) for x, y in zip(movers[:-1], movers[1:])) >= clear_m:
            return TransferPlan(tp.times_s, movers, tp.strategy, tp.min_separation_m)
        errors.append(f"{strategy}: passes too close to an obstacle")
    return None
