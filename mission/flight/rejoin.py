"""Lost vehicles that still fly (obstacles) and returning vehicles (re-admission).

* **Obstacles**: a vehicle lost by its link while armed and airborne (PX4 falls back to hold,
  ArduPilot GUIDED holds its last target) stays where it was. For ``OBSTACLE_TTL_S`` of the
  mission clock after its last frame, its last known position and its last setpoint (where it
  may still have been flying to) are obstacles: re-formed slots are rotated about the centre so
  that none is within ``min_separation_m + OBSTACLE_MARGIN_M`` of them
  (:func:`clear_offsets`), transfers are planned with them as fixed participants
  (:func:`plan_clear_transfer`), and the seek's per-iteration goals are checked likewise
  (:func:`clear_goals`). A lost vehicle heard again is an obstacle at its live position.
* **Re-admission** (``[faults] readmit = true``): a vehicle lost by its link, heard again
  during the seek while armed, airborne and not in RTL/LAND, is re-admitted at the start of
  the next iteration (:func:`readmit`): held where it is under setpoints, re-engaged
  (OFFBOARD/GUIDED), then the formation re-forms for N+1 (CVT warm-started from the current
  slots plus its position projected on the sphere, minimum-travel assignment) and a
  separation-keeping transfer is flown.
"""
from __future__ import annotations

import asyncio
import functools

import numpy as np

__all__ = ["OBSTACLE_MARGIN_M", "OBSTACLE_TTL_S", "clear_goals", "clear_offsets", "fly_rotation", "obstacles",
           "pending_readmissions", "plan_clear_transfer", "readmit", "readmitted_offsets",
           "segment_clearance"]

#: extra clearance (tracking error of the survivors and of the hovering vehicle)
OBSTACLE_MARGIN_M = 0.5
#: how long after its last frame a silent airborne vehicle is still assumed to hover there
OBSTACLE_TTL_S = 600.0
_GUIDED_MODES = {"px4": "OFFBOARD", "ardupilot": "GUIDED"}


def obstacles(co) -> np.ndarray:
    """``(K, 3)`` positions (mission ENU m) to keep clear of: lost vehicles still flying.

    A vehicle lost by its link (``reason == "link"``) that was last seen armed and above 1 m,
    whose last frame is less than :data:`OBSTACLE_TTL_S` old (its live position once heard
    again), and not re-admitted. Vehicles that left (RTL/LAND) fly away and are not included.
    """
    from mission.flight.loss import LEFT_MODES

    now = co.clock.time()
    pts = []
    for sysid, loss in co.lost.items():
        if loss.reason != "link" or now - loss.since_s > OBSTACLE_TTL_S:
            continue
        v = co.vehicles.get(sysid)
        if v is None:
            continue
        st = v.state
        alt = getattr(st, "relative_alt_m", None)
        if not st.armed or (alt is not None and alt < 1.0) or st.mode in LEFT_MODES.get(v.flavour, ()):
            continue
        pos = co._telemetry_position(sysid)
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
    from mission.safety.envelope import TransferError, plan_transfer
    from mission.safety.transfer import TransferPlan

    obs = np.asarray(obstacle_points, dtype=float).reshape(-1, 3)
    if not len(obs):
        return plan_transfer(start, goal, min_separation_m, max_speed_m_s, fence=fence)
    clear_m = float(min_separation_m if clearance_m is None else max(clearance_m, min_separation_m))
    # fixed participants must be apart themselves (a lost vehicle's last position and last
    # setpoint are close): plan with a thinned set, then check every leg against all of them
    fixed = []
    for q in obs:
        if all(np.linalg.norm(q - f) >= min_separation_m for f in fixed):
            fixed.append(q)
    fixed = np.array(fixed)
    a = np.vstack([np.asarray(start, dtype=float), fixed])
    b = np.vstack([np.asarray(goal, dtype=float), fixed])
    n = len(a) - len(fixed)
    errors = []
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


def clear_goals(co, centre_enu, sysids: list[int]) -> bool:
    """Rotate ``co.slot_offsets`` (about the centre) if a goal of this iteration is near an obstacle.

    Called by the seek before each iteration's move; logs an event when it rotates. Returns
    False if no clear rotation was found (the goals are then the best found).
    """
    obs = obstacles(co)
    if not len(obs):
        return True
    sep = co.plan.min_separation_m + OBSTACLE_MARGIN_M
    offsets = {s: co.slot_offsets[s] for s in sysids}
    start = {s: co.ramp.setpoint(s) for s in sysids if s in co.ramp.sysids}
    if len(start) != len(sysids):
        start = None
    new, ok = clear_offsets(offsets, centre_enu, obs, sep, start_enu=start,
                            allow_tilt=co.formation_kind == "cvt")
    if any(not np.allclose(new[s], offsets[s]) for s in sysids):
        co.slot_offsets.update(new)
        co.event("formation rotated to keep clear of a lost vehicle still flying"
                 + ("" if ok else " (no rotation keeps the full clearance)"),
                 level="info" if ok else "warning", obstacles=obs, slots={s: new[s] for s in sysids})
    return ok


async def fly_rotation(co, centre_enu, sysids: list[int], before: dict[int, np.ndarray]) -> None:
    """Fly a rotation of the slots made by :func:`clear_goals` as a separation-keeping transfer.

    Flown straight, a large rotation takes the slots along chords that cross each other and
    pass near the centre (where a vehicle with a retired sensor is parked); as a transfer
    (:func:`mission.flight.loss.transfer_to`) every path is planned and checked. ``before``: the slot
    offsets before :func:`clear_goals`. Nothing is flown when nothing rotated.
    """
    from mission.flight.loss import transfer_to

    members = [s for s in sysids if s not in co.lost and co.ramp is not None and s in co.ramp.sysids]
    if all(np.allclose(before[s], co.slot_offsets[s]) for s in members if s in before):
        return
    await transfer_to(co, members, {s: co.slot_offsets[s] for s in members}, centre_enu,
                      f"rotating the formation of {len(members)} clear of a lost vehicle", [])


def pending_readmissions(co) -> list[int]:
    """Lost vehicles heard again and waiting to be re-admitted (``[faults] readmit = true``)."""
    if not co.plan.faults.readmit:
        return []
    return sorted(s for s, x in co.lost.items() if x.reason == "link" and x.came_back_s is not None
                  and x.readmit_pending)


def readmitted_offsets(kind: str, offsets: dict[int, np.ndarray], returning: dict[int, np.ndarray],
                       radius_m: float) -> tuple[dict[int, np.ndarray], str]:
    """Slot offsets of the formation grown by the returning vehicles.

    Parameters
    ----------
    kind : {"cvt", "symmetric"}
    offsets : dict
        Current members' offsets (by sysid).
    returning : dict
        Returning vehicles' current offsets from the centre (projected on the sphere).
    radius_m : float

    Returns
    -------
    (dict, str)
        Every vehicle's new offset and the formation type: symmetric if it was and the new
        number is even, else a CVT warm-started from the current slots and the returning
        positions; minimum-travel assignment (rotation allowed for CVT).
    """
    import formation

    sysids = sorted(offsets) + sorted(returning)
    x = np.array([offsets[s] for s in sorted(offsets)] + [returning[s] for s in sorted(returning)], dtype=float)
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norms <= 1e-9):
        x = x + 1e-3 * np.random.default_rng(0).standard_normal(x.shape)
        norms = np.linalg.norm(x, axis=1, keepdims=True)
    proj = radius_m * x / norms
    if kind == "symmetric" and len(sysids) % 2 == 0:
        slots = np.asarray(formation.symmetric_cylinder(len(sysids), radius_m), dtype=float)
        perm, slots = formation.assign_slots(proj, slots, allow_rotation=False)
        return {s: slots[perm[k]] for k, s in enumerate(sysids)}, "symmetric"
    unit = formation.cvt_from(proj / radius_m).points
    perm, slots = formation.assign_slots(proj, radius_m * unit, allow_rotation=True)
    return {s: np.asarray(slots[perm[k]], dtype=float) for k, s in enumerate(sysids)}, "cvt"


async def readmit(co, centre_enu, sysids: list[int], returning: list[int]) -> list[int]:
    """Re-admit ``returning`` into the formation of ``sysids`` about ``centre_enu``.

    Each returning vehicle still armed, airborne and heard is held at its position under
    setpoints and re-engaged (OFFBOARD/GUIDED); the formation re-forms for the larger number
    (:func:`readmitted_offsets`, rotated clear of obstacles) and a separation-keeping transfer
    is flown. A vehicle that cannot be re-engaged is kept out and landed. Returns the new
    formation's sysids.
    """
    from mission.flight.loss import LEFT_MODES, keep_out, transfer_to

    plan = co.plan
    joined = []
    for sysid in returning:
        loss = co.lost[sysid]
        loss.readmit_pending = False
        v = co.vehicles.get(sysid)
        pos = co._telemetry_position(sysid)
        alt = None if v is None else getattr(v.state, "relative_alt_m", None)
        if (v is None or pos is None or not v.state.armed or (alt is not None and alt < 1.0)
                or v.link_age_s() > plan.faults.link_timeout_s or v.state.mode in LEFT_MODES.get(v.flavour, ())):
            await keep_out(co, sysid, v, loss, "no longer fit to re-join (disarmed, landed, silent or returning)")
            continue
        want = _GUIDED_MODES[v.flavour]
        co._reengaging.add(sysid)  # the watchdog must not race us
        try:
            co.ramp.add(sysid, np.asarray(pos, dtype=float))
            co.released.discard(sysid)
            await co.clock.sleep(0.5)  # a few setpoints first: PX4 refuses OFFBOARD without them
            await asyncio.wait_for(v.set_mode(want), timeout=30.0)
            await co.wait_until(lambda v=v, want=want: v.state.mode == want, 10.0, f"vehicle {sysid} in {want}")
        except Exception as exc:  # noqa: BLE001 - CommandError, MissionError, timeout: kept out
            co.ramp.remove(sysid)
            co.released.add(sysid)
            await keep_out(co, sysid, v, loss, f"could not re-engage {want}: {exc}")
            continue
        finally:
            co._reengaging.discard(sysid)
        del co.lost[sysid]
        co.airborne.add(sysid)
        co.readmitted.append({"sysid": sysid, "lost_s": loss.detected_s, "came_back_s": loss.came_back_s,
                              "readmitted_s": co.clock.time()})
        co.status[sysid] = "re-admitted"
        co.event(f"vehicle {sysid} re-admitted: re-engaged {want} at its position", sysid=sysid)
        joined.append(sysid)
    if not joined:
        return sysids
    members = [s for s in sysids if s not in co.lost]
    centre = np.asarray(centre_enu, dtype=float)
    loop = asyncio.get_running_loop()
    new, kind = await loop.run_in_executor(None, functools.partial(
        readmitted_offsets, co.formation_kind, {s: co.slot_offsets[s] for s in members},
        {s: co.ramp.setpoint(s) - centre for s in joined}, plan.formation.radius_m))
    everyone = sorted(new)
    obs = obstacles(co)
    if len(obs):
        new, _ = clear_offsets(new, centre, obs, plan.min_separation_m + OBSTACLE_MARGIN_M,
                               allow_tilt=kind == "cvt")
    if kind != co.formation_kind:
        co.event(f"{len(everyone)} vehicles: the symmetric formation needs an even number; switching to "
                 "the CVT formation (and the Theorem 2 estimator)", level="warning")
    co.formation_kind = kind
    await transfer_to(co, everyone, new, centre, f"re-forming for {len(everyone)} vehicles ({kind}), "
                      f"re-admitting {joined}", lost_here=[])
    return everyone
