"""The seek's estimators as the mission uses them: the plan's seeker (:class:`MissionSeeker`, one
trial of :mod:`estimator.seekers` with the options the operator knows) and the paper's gradient
estimate (:class:`GradientEstimate`), both fed by :class:`mission.flight.phases.seek.Seek`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GradientEstimate", "MissionSeeker", "fence_box_enu", "make_seeker", "ste_options", "ste_wind"]


def make_seeker(kind: str, wind_from_deg: float | None = None, plume_mode: str = "steady", **ste):
    """The plan's seeker (``[seeking] seeker``): None for ``gradient`` (the loop's own paper step,
    with the plan's estimator), else a :class:`MissionSeeker` around :mod:`estimator.seekers`
    (``wind_from_deg`` and ``plume_mode``, the plan's, go to the ``plume`` and ``ste`` seekers; the
    keywords ``ste`` to the ``ste`` seeker: :func:`ste_options`)."""
    return None if kind == "gradient" else MissionSeeker(kind, wind_from_deg, plume_mode, **ste)


def ste_options(sk, geofence=None) -> dict:
    """The ``ste`` seeker's keywords from the plan's ``[seeking]`` (a
    :class:`~mission.core.plan_types.SeekingPlan`): what the operator knows (the sensor's
    datasheet, the ground, the stability class, a wind prior), never the simulated world's truth;
    with ``prior_box = "fence"`` and the plan's ``geofence`` (a
    :class:`~mission.core.plan_types.GeofencePlan`), the prior's box (:func:`fence_box_enu`)."""
    out = dict(wind_std_deg=sk.wind_std_deg, noise_std=sk.sensor_noise_std,
               detection_floor=sk.sensor_detection_floor, ground_alt_m=sk.ground_alt_m,
               stability=sk.stability, region_m=sk.region_m)
    if sk.prior_box == "fence" and geofence is not None and geofence.polygon_en_m:
        out["prior_box_enu"] = fence_box_enu(geofence, sk.ground_alt_m)
    return out


def fence_box_enu(geofence, ground_alt_m: float) -> tuple:
    """The box the release is in when the fence bounds it: ``((e_min, n_min, u_min), (e_max, n_max,
    u_max))``, the polygon's bounding box, up from the lower of the ground and the fence's floor (a
    release on the ground under a fence whose floor is 2 m is inside it) to the fence's ceiling."""
    en = np.asarray(geofence.polygon_en_m, dtype=float)
    lo, hi = en.min(axis=0), en.max(axis=0)
    return ((float(lo[0]), float(lo[1]), min(float(ground_alt_m), float(geofence.min_alt_m))),
            (float(hi[0]), float(hi[1]), float(geofence.max_alt_m)))


def ste_wind(sk, snapshots, now_s: float) -> tuple[float | None, float, str]:
    """The ``ste`` seeker's wind-direction prior: ``(wind_from_deg, wind_std_deg, what was used)``.

    The plan's ``[seeking] wind_from_deg`` / ``wind_std_deg`` when given; else the autopilots' own
    wind estimates (PX4 ``WIND_COV``, ArduPilot ``WIND``) combined by
    :func:`mission.flight.wind_prior.fleet_wind_prior` from the vehicles' state ``snapshots``; else
    None (the seeker estimates the direction, uniform prior)."""
    from mission.flight.wind_prior import fleet_wind_prior

    if sk.wind_from_deg is not None:
        return sk.wind_from_deg, sk.wind_std_deg, (f"ste wind prior: the plan's, from {sk.wind_from_deg:.0f} deg "
                                                   f"+- {sk.wind_std_deg:.0f} deg")
    prior = fleet_wind_prior(snapshots, now_s=now_s)
    if prior is None:
        return None, sk.wind_std_deg, ("ste wind prior: none (the plan gives no wind and no autopilot reports a "
                                       "usable wind estimate); the seeker estimates the direction")
    return prior.from_deg, prior.std_deg, (f"ste wind prior: the autopilots' estimate, from {prior.from_deg:.0f} "
                                           f"deg +- {prior.std_deg:.0f} deg, {prior.speed_m_s:.1f} m/s "
                                           f"({prior.n_vehicles} vehicles)")


class MissionSeeker:
    """One mission's seeker (K = 1): readings in, the next centre out, capped at ``gamma_m``;
    the safety envelope's ``clamp_centre`` is applied by the caller.

    A seeker with a posterior (``ste``) also gives, after each step, ``estimate_enu`` (the
    posterior mean release point, (3,)), ``region95_m`` (the radius about it holding 95 % of the
    posterior), ``collapses`` (re-seeds so far), ``collapsed`` (this step re-seeded), ``misfit``
    and ``formation_radius_m``; None for the others. ``converges_itself``: the seek ends on the
    seeker's ``arrival`` alone (the posterior's region), not on the centre's steadiness.
    """

    def __init__(self, kind: str, wind_from_deg: float | None = None, plume_mode: str = "steady", **ste):
        from estimator.seekers import make_seeker as _make

        plume = {"wind_from_deg": wind_from_deg, "patchy": plume_mode == "intermittent"}
        kwargs = {"plume": plume, "ste": {**plume, **ste}}.get(kind, {})
        self.seeker = _make(kind, **kwargs)
        self.converges_itself = kind == "ste"
        self.arrival = None  # the seeker's own convergence signal after a step (None: it has none)
        self.failure = None
        self._clear()

    def _clear(self) -> None:
        self.estimate_enu = self.region95_m = self.collapses = self.collapsed = self.misfit = None
        self.formation_radius_m = None

    def reset(self) -> None:
        """Forget the readings seen (a sensor among them turned out faulty)."""
        self.seeker.reset()
        self._clear()

    def step(self, centre, positions, values, gamma_m: float, times_s=None, sensor_ids=None) -> np.ndarray:
        """The next centre; the same centre (hold) if the seeker cannot propose one, with ``self.failure`` set.
        ``times_s`` and ``sensor_ids`` (one per reading): when and by which vehicle each reading was
        taken, for a seeker that takes them (:func:`estimator.seekers.propose_readings`)."""
        from estimator.seekers import cap_move, propose_readings

        c = np.asarray(centre, dtype=float)[None]
        self.failure = self.arrival = None
        self.collapsed = None
        t = None if times_s is None else np.asarray(times_s, dtype=float)[None]
        ids = None if sensor_ids is None else np.asarray(sensor_ids)[None]
        try:
            new = propose_readings(self.seeker, c, np.asarray(positions, dtype=float).reshape(1, -1, 3),
                                   np.asarray(values, dtype=float)[None], t, ids)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            self.failure = f"seeker {self.seeker.name} proposed no centre ({exc}); holding"
            return c[0]
        if not np.all(np.isfinite(new)):
            self.failure = f"seeker {self.seeker.name} proposed a non-finite centre; holding"
            return c[0]
        own = getattr(self.seeker, "arrival", None)
        self.arrival = None if own is None else bool(own[0])
        self._posterior()
        return cap_move(c, new, gamma_m)[0]

    def _posterior(self) -> None:
        """Copy the seeker's posterior summary (trial 0), if it has one."""
        sk = self.seeker
        if getattr(sk, "estimate_enu", None) is None:
            return
        self.estimate_enu = np.asarray(sk.estimate_enu[0], dtype=float).copy()
        self.region95_m = float(sk.region95_m[0])
        self.collapses, self.collapsed = int(sk.collapses[0]), bool(sk.collapsed[0])
        self.misfit = None if sk.misfit is None else bool(sk.misfit[0])
        radius = getattr(sk, "formation_radius_m", None)
        self.formation_radius_m = None if radius is None else float(radius[0])


class GradientEstimate:
    """The seek's gradient estimate, ``estimate(positions (N,3), values (N,), centre (3,)) -> gradient (3,)``,
    with the plan's estimator.

    Attributes
    ----------
    robust : RobustGradientEstimator or None
        The robust estimator (``estimator = "robust"``), shared with the faulty-sensor detector
        (:func:`mission.flight.sensor_check.make_check`); None for the others.
    needs_all : bool
        The estimate needs every sensor's reading (the robust estimator tracks each by its index).
    sysids : None
        Its sensors are the iteration's ``used`` vehicles, in order (a :class:`SensorCheck` names its own).
    """

    sysids = None

    def __init__(self, kind: str, n: int) -> None:
        from estimator.robust import RobustGradientEstimator

        self.kind = kind
        self.robust = RobustGradientEstimator(n) if kind == "robust" else None
        self.needs_all = self.robust is not None

    def __call__(self, positions, values, centre) -> np.ndarray:
        import estimator

        if self.robust is not None:
            return np.asarray(self.robust.update(np.asarray(positions) - centre, np.asarray(values)), dtype=float)
        return estimator.gradient(positions, values, centre, method=self.kind)

    def suspects(self) -> list | None:
        """The robust estimator's suspects (:class:`estimator.robust.Suspect`); None for the others."""
        return None if self.robust is None else list(self.robust.suspects)
