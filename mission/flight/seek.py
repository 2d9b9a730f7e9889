"""The seek phase: move the formation centre up the estimated gradient until it converges.

One iteration (design choice: *move, settle, then estimate*):

1. every vehicle's goal is its slot about the current centre; the ramp moves the setpoints
   there at the speed limit and the loop waits until every vehicle is within ``arrival_tol_m``;
2. it waits (at most ``1 / rate_hz`` per iteration overall) for a reading from every vehicle taken
   after the arrival, then takes the estimation instant ``t = now`` and each vehicle's reading
   nearest ``t`` within ``reading_window_s``, with the position where it was taken;
3. gradient from those actual positions about their centroid (Theorem 2, ``method="cvt"``; or
   eq. 3, or the robust estimator), ``seek_step(eps, gamma)`` from the commanded centre, the
   safety envelope's ``clamp_centre``;
4. the convergence monitor sees the new centre; the iteration is logged.

Why not estimate on the fly at a fixed rate: the centre moves by at most ``gamma`` per
iteration, so arrival takes about ``gamma / max_speed`` plus the autopilot's settling, a second
or so; estimating while the vehicles are still flying would use readings whose positions are
right (Theorem 2 uses the actual positions) but a formation distorted by tracking lag, which
raises ``cond(M)`` and the noise of the estimate for no gain in mission time that matters.
"""
from __future__ import annotations

import numpy as np

from mission.flight.loss import reform
from mission.flight.motion import move_and_wait, parked
from mission.flight.rejoin import clear_goals, fly_rotation, pending_readmissions, readmit
from mission.flight.retire import formation_goals, keep_out_retired, make_watch, retire_sensor
from mission.flight.state import MissionError

__all__ = ["seek", "make_estimator"]


def make_estimator(kind: str, n: int):
    """``f(positions (N,3), values (N,), centre (3,)) -> gradient (3,)`` for the plan's estimator."""
    import estimator

    if kind == "robust":
        from estimator.robust import RobustGradientEstimator

        robust = RobustGradientEstimator(n)

        def _robust(positions, values, centre):
            return np.asarray(robust.update(np.asarray(positions) - centre, np.asarray(values)), dtype=float)

        _robust.suspects = lambda: list(robust.suspects)
        _robust.suspect_codes = lambda: robust.suspect_codes
        _robust.noise_std = lambda: robust.noise_std_estimates
        _robust.needs_all = True
        return _robust

    def _plain(positions, values, centre):
        return estimator.gradient(positions, values, centre, method=kind)

    return _plain


async def seek(co, start_iteration: int = 0, history=()) -> tuple[str, str]:
    """Run the seek loop; returns ``(outcome, message)``.

    ``start_iteration`` and ``history`` (the last centres, oldest first) resume a stopped seek
    (:mod:`mission.flight.resume`): iterations are numbered on, the convergence monitor is prefilled.

    Outcomes: ``converged``, ``max_iterations``, ``stopped_at_fence`` (the centre has been held
    at the geofence for a whole convergence window: the source is probably outside),
    ``too_few_vehicles`` (vehicles were lost and fewer than 4 are left: the caller brings the
    others home). After a loss the formation is re-formed for the survivors
    (:func:`mission.flight.loss.reform`) before the next iteration; a returning vehicle is re-admitted
    (``[faults] readmit = true``, :func:`mission.flight.rejoin.readmit`); every iteration's slots are
    rotated clear of lost vehicles still flying (:func:`mission.flight.rejoin.clear_goals`). With the
    robust estimator, a sensor it keeps naming is retired: its vehicle is parked at the centre,
    its readings ignored, the others re-formed (:mod:`mission.flight.retire`); only sensing vehicles
    count towards the 4.
    """
    from estimator import ConvergenceMonitor, GeometryError, seek_step

    co.set_phase("seek")
    plan = co.plan
    sk = plan.seeking
    # the formation's vehicles: those under setpoints, and those lost since their slot was given
    # (the loop re-forms without them first)
    sysids = sorted(s for s in co.slot_offsets if (s in co.ramp.sysids or s in co.lost) and s not in co.retired)
    flying = [s for s in sysids if s not in co.lost]
    if len(flying) < 4:
        raise MissionError(f"seek needs at least 4 vehicles in formation, have {len(flying)}")
    est_kind = sk.estimator
    estimate = make_estimator(est_kind, len(sysids))
    watch = make_watch(co, est_kind, sysids)
    monitor = ConvergenceMonitor(window=sk.convergence_window, tol_m=sk.convergence_tol_m)
    centre = np.asarray(co.centre_enu, dtype=float).copy()
    for c in history:
        monitor.update(np.asarray(c, dtype=float))
    if not len(history):
        monitor.update(centre)
    co._t_seek_start = co.clock.time()
    period_s = 1.0 / sk.rate_hz
    last_estimate_t = -np.inf
    failures = 0
    at_fence = 0
    for k in range(int(start_iteration), sk.max_iterations):
        if any(s in co.lost for s in sysids):
            sysids = await reform(co, centre, sysids)
            if len(sysids) < 4:
                co._t_seek_end = co.clock.time()
                return "too_few_vehicles", (f"vehicles {sorted(co.lost)} lost: {len(sysids)} left, a formation "
                                            "needs 4; ending the mission, the others come home")
            if co.formation_kind == "cvt" and est_kind == "symmetric":
                est_kind = "cvt"
            estimate, watch = make_estimator(est_kind, len(sysids)), make_watch(co, est_kind, sysids)
        returning = await keep_out_retired(co, pending_readmissions(co))
        if returning:
            sysids = await readmit(co, centre, sysids, returning)
            if co.formation_kind == "cvt" and est_kind == "symmetric":
                est_kind = "cvt"
            estimate, watch = make_estimator(est_kind, len(sysids)), make_watch(co, est_kind, sysids)
        before = {s: co.slot_offsets[s].copy() for s in sysids}
        clear_goals(co, centre, sysids)  # a few ms at most: slots clear of lost vehicles still flying
        await fly_rotation(co, centre, sysids, before)  # a rotation is flown as a planned transfer
        goals = formation_goals(co, centre, sysids)  # parked vehicles (retired sensors) at the centre
        try:
            await move_and_wait(co, goals, sk.arrival_tol_m,
                                timeout_s=20.0 + 3.0 * sk.gamma_m / plan.max_speed_m_s,
                                what=f"iteration {k + 1}: the formation to settle")
        except MissionError as exc:
            co.event(f"{exc}; estimating anyway", level="warning")
        t_arrive = co.clock.time()
        wait_s = period_s - (t_arrive - last_estimate_t)
        if wait_s > 0:
            await co.clock.sleep(wait_s)

        def _fresh():
            return all((r := co.store.latest(s)) is not None and r.time_s >= t_arrive
                       for s in sysids if s not in co.lost)

        try:
            await co.wait_until(_fresh, max(5.0, 10 * sk.reading_window_s), "fresh readings", poll_s=0.02)
        except MissionError:
            missing = [s for s in sysids if (r := co.store.latest(s)) is None or r.time_s < t_arrive]
            co.event(f"iteration {k + 1}: no fresh reading from vehicles {missing}", level="warning")
        # estimation instant: the oldest of the vehicles' newest readings, so that every vehicle
        # has a reading at or after it (robust to delivery latency, e.g. at a high speed-up)
        if any(s in co.lost for s in sysids):
            continue  # lost during this iteration: re-form first
        latest = [co.store.latest(s) for s in sysids]
        fresh = [r.time_s for r in latest if r is not None and r.time_s >= t_arrive]
        t_est = min(fresh) if len(fresh) == len(sysids) else co.clock.time()
        last_estimate_t = co.clock.time()
        aligned = co.store.aligned(t_est, sk.reading_window_s, sysids)
        if len(aligned) < 4:
            failures += 1
            co.event(f"iteration {k + 1}: only {len(aligned)} aligned readings (need 4); waiting",
                     level="warning", counts=co.store.counts())
            if failures >= 20:
                raise MissionError(f"no usable readings for {failures} iterations "
                                   f"(rejections: {co.store.counts()['rejected']})")
            await co.clock.sleep(1.0)
            continue
        if getattr(estimate, "needs_all", False) and len(aligned) < len(sysids):
            # the robust estimator tracks each sensor by its index: estimate only with all of them
            co.event(f"iteration {k + 1}: {len(aligned)} of {len(sysids)} readings aligned; the robust "
                     "estimator needs all; waiting", level="warning")
            await co.clock.sleep(0.5)
            continue
        used = sorted(aligned)
        positions = np.array([aligned[s].position_enu_m for s in used])
        values = np.array([aligned[s].value for s in used])
        # the estimate is taken about the centroid of the actual positions, not the commanded
        # centre: with sigma_c = mean of the readings (Theorem 2) or eq. 3, a common offset of the
        # vehicles from their slots (tracking lag) would otherwise bias the gradient by about
        # 3 sigma offset / D^2, enough to make the centre oscillate near the source
        centroid = positions.mean(axis=0)
        try:
            grad = np.asarray(estimate(positions, values, centroid), dtype=float)
        except (GeometryError, ValueError) as exc:
            failures += 1
            co.event(f"iteration {k + 1}: gradient not estimated: {exc}", level="warning")
            if failures >= 20:
                raise MissionError(f"no gradient estimate for {failures} iterations (last: {exc})") from None
            continue
        failures = 0
        retiring = None if watch is None else watch.update(estimate, used, k + 1, co.clock.time())
        new_centre = seek_step(centre, grad, sk.eps, sk.gamma_m)
        if co.envelope is not None:
            clamp = co.envelope.clamp_centre(centre, new_centre)
            if clamp.at_boundary:
                at_fence += 1
                if at_fence in (1, sk.convergence_window):
                    co.event(clamp.message, level="warning")
                new_centre = np.asarray(clamp.centre_enu, dtype=float)
            else:
                at_fence = 0
        step_m = float(np.linalg.norm(new_centre - centre))
        co.distance_flown_m += step_m
        co.iteration = k + 1
        co.gradient = grad
        converged = monitor.update(new_centre)
        co.estimate_enu = monitor.estimate_enu
        co.spread_m = monitor.spread_m
        if co.log is not None:
            co.log.write("iteration", k=k + 1, t_estimate_s=t_est, centre_enu=centre, centroid_enu=centroid,
                         gradient=grad,
                         new_centre_enu=new_centre, step_m=step_m, estimate_enu=co.estimate_enu,
                         spread_m=co.spread_m, distance_flown_m=co.distance_flown_m,
                         readings=[aligned[s] for s in used],
                         positions_enu={s: co._telemetry_position(s) for s in sysids + parked(co)},
                         setpoints_enu={s: co.ramp.setpoint(s) for s in sysids + parked(co)},
                         suspects=_suspects(estimate, used),
                         status=co.vehicle_status())
        centre = new_centre
        co.centre_enu = centre.copy()
        if converged and at_fence:
            co._t_seek_end = co.clock.time()
            return "stopped_at_fence", (f"stopped at the geofence after {k + 1} iterations, centre held at "
                                        f"({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}) m: the "
                                        "source is probably outside the fence (shrunk by the radius)")
        if converged:
            co._t_seek_end = co.clock.time()
            e = co.estimate_enu
            return "converged", (f"converged after {k + 1} iterations: source at ({e[0]:.2f}, {e[1]:.2f}, "
                                 f"{e[2]:.2f}) m, spread {co.spread_m:.2f} m")
        if at_fence >= sk.convergence_window:
            co._t_seek_end = co.clock.time()
            return "stopped_at_fence", ("the formation centre has been held at the geofence for "
                                        f"{at_fence} iterations: the source is probably outside the fence")
        if retiring is not None:
            sysids = await retire_sensor(co, centre, sysids, retiring)
            estimate, watch = make_estimator(est_kind, len(sysids)), make_watch(co, est_kind, sysids)
    co._t_seek_end = co.clock.time()
    return "max_iterations", f"not converged after {sk.max_iterations} iterations"


def _suspects(estimate, used: list[int]) -> list[dict] | None:
    """The robust estimator's suspect sensors as ``{sysid, reason, excluded, noise_std}`` (None otherwise)."""
    get = getattr(estimate, "suspects", None)
    if get is None:
        return None
    try:
        return [{"sysid": used[s.index], "reason": s.reason, "excluded": bool(s.excluded),
                 "noise_std": float(s.noise_std)} for s in get()]
    except (AttributeError, IndexError, ValueError):
        return None
