"""``ste``: a source-term-estimation seeker (a particle filter over the release, pure numpy).

Behind the seeker interface (:class:`estimator.seekers.Seeker`, batched over ``K`` trials):
``propose(centre, positions, values)`` folds every reading of the iteration (each at the
position where it was taken) into a posterior over the release point (3D), its amplitude and,
when not given, the wind direction, and returns the next centre. The forward model and the
likelihoods are :mod:`estimator.ste_model`. Per iteration:

1. **Update**: ``log w += sum_i (temper / n_i) log L(v_i | particle)`` over the iteration's readings
   (``temper`` < 1 because the readings of one instant, and of nearby instants, see the same
   meander: they are not independent, and counting them as such makes the posterior overconfident;
   ``n_i`` the number of the iteration's readings within about ``corr_length_m`` of reading ``i``,
   itself included, so readings that see the same puff share one reading's weight). Given the
   readings' times and sensors (``propose(..., times_s=, sensor_ids=)``) and the intermittent
   likelihood (``timed``), each reading's exponent is instead its share of independent evidence
   (:mod:`estimator.ste_tempering`: one unit per sensor per ``corr_time_s``), so every reading,
   dense or not, can be given; the steady likelihood then keeps each sensor's first reading.
2. **Collapse**: when even the best particle explains the iteration's readings worse than
   ``collapse_nats`` per reading on average (every weight effectively zero), the trial's
   particles are re-seeded from the prior about the current centre and the last ``memory``
   iterations' readings are applied to them; :attr:`collapses` counts it, :attr:`collapsed` flags it.
3. **Resample** (systematic) when the effective sample size falls below half the particles, then
   **roughen** (Liu & West 2001 kernel shrinkage: ``a x + (1 - a) mean + N(0, h^2 cov)``,
   ``a = sqrt(1 - h^2)``: the cloud's mean and covariance are kept) with a small floor.
4. **Report**: :attr:`estimate_enu` the posterior mean release point and :attr:`region95_m` the
   radius about it holding 95 % of the weight; :attr:`arrival` (the convergence signal) is
   ``region95_m <= region_m`` with no collapse in the last ``memory`` iterations (a posterior
   just re-seeded from a few readings can be tight and wrong) and no :attr:`misfit`: the last
   ``memory`` iterations' readings scored under the posterior predictive (steady: ``z^2`` of
   a Gaussian predictive; intermittent: ``-2 log P(hit or miss)``), their total deviance minus
   its expectation over its deviation if the model held (:attr:`fit_z`) above ``misfit_z`` says
   the field is not a plume the model can represent (a tight posterior there is tight and wrong).
5. **Move**: while the region is larger than ``exploit_m`` (default ``region_m``), the candidate (stay; ``step`` up/down
   wind, across it, up/down; toward the posterior mean) whose formation readings carry the most
   expected information about the particles (the mutual information of each vehicle's hit / miss,
   summed over vehicles, on a resampled subset of the particles: myopic infotaxis, Vergassola et
   al. 2007); ``step`` is half the region, within ``[min_step_m, max_step_m]``. Once the region is
   below ``exploit_m``: the posterior mean. With ``casting``, two steps across the wind both ways
   and the two up-wind diagonals are candidates too.
6. **Formation**: :attr:`formation_radius_m` ``= radius_gain * region95_m`` within
   ``[min_radius_m, max_radius_m]`` (wide to find the plume, tight about the release at the end,
   where the plume is ~1 m across); the move's information is computed for the formation at that
   radius. A caller that does not honour it (the mission, for now) keeps its own formation.

The caller caps the move (``gamma_m``) and applies the safety envelope, as for every seeker.
"""
from __future__ import annotations

import numpy as np

from estimator.estimate import PlanPosterior, SourceEstimate
from estimator.seek_inputs import seeker_inputs
from estimator.ste_prior import check_box, draw_prior, trial_boxes
from estimator.ste_readings import first_per_sensor, formation_points, reading_times
from estimator.ste_tempering import shared_counts, time_weights
from estimator.ste_fast import (hit_probability_fast, loglik_patchy_fast, loglik_steady_fast, plume_mean_fast,
                                steady_hit_probability_fast)
from estimator.ste_model import BRIGGS_RURAL, deviance_patchy, deviance_steady

__all__ = ["SteSeeker"]

_AXIS_STEP = 1.4  # ``axis_steps``: a step is this many of the posterior's deviations along its axis (half the
#                  95 % radius of a round Gaussian)
_FLOOR = np.array([0.03, 0.03, 0.03, 0.01, 0.003])  # roughening floor (m, m, m, log A, rad)


def _positive(name: str, value, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


def _entropy2(p: np.ndarray) -> np.ndarray:
    """Binary entropy (nats) of probabilities ``p``."""
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    return -(p * np.log(p) + (1.0 - p) * np.log1p(-p))


def _systematic(w: np.ndarray, count: int, u: np.ndarray) -> np.ndarray:
    """Systematic resampling indices ``(K, count)`` from weights ``(K, P)`` and offsets ``u`` in [0, 1) (K,)."""
    k, p = w.shape
    cdf = np.cumsum(w, axis=1)
    cdf = cdf / cdf[:, -1:] + np.arange(k)[:, None]  # rows made disjoint: one searchsorted for all
    grid = (u[:, None] + np.arange(count)[None, :]) / count + np.arange(k)[:, None]
    flat = np.searchsorted(cdf.ravel(), grid.ravel()).reshape(k, count) - p * np.arange(k)[:, None]
    return np.clip(flat, 0, p - 1)


class SteSeeker:
    """Particle-filter source-term estimation with an information-seeking move (module docstring).

    Parameters
    ----------
    wind_from_deg : float or None
        The wind's direction (where it comes from, degrees clockwise from north); None: estimated
        (uniform prior).
    wind_std_deg : float
        Prior standard deviation about a given ``wind_from_deg``.
    patchy : bool
        The intermittent-plume likelihood (hits and misses) instead of the steady one.
    particles : int
        Particles per trial.
    prior_radius_m, prior_height_m : float
        The prior over the release: uniform in a vertical cylinder of this radius and half-height
        about the first centre (not below ``ground_alt_m``).
    prior_upwind_deg : float or None
        The formation starts downwind of the release (the usual approach, and the benchmark's and
        ``swarmseek run``'s starts): the first prior's release is in the sector of this half-angle
        up each particle's own wind from the first centre (so it holds with the wind not given
        too); None: the whole disk. A re-seed after a collapse uses the whole disk.
    prior_box_enu : array_like or None
        A search box ``[[e_min, n_min, u_min], [e_max, n_max, u_max]]`` (ENU m; shape ``(2, 3)``, or
        ``(K, 2, 3)``: one per trial) the release is known to be in (in missions the plan's geofence:
        a release outside it cannot be reached): every prior draw and re-seed is inside it too
        (:mod:`estimator.ste_prior`), and so is every particle after roughening; the first centre
        must be inside it. None: no box.
    amplitude_range : (float, float)
        The prior of ``A`` (the release-point mean), log-uniform.
    stability, source_radius_m, ground_alt_m :
        The dispersion model (Briggs class, ``s0``, the ground's ``U``).
    noise_std, background, detection_floor : float
        The sensor: noise deviation, background, floor (readings below it report 0); a hit is a
        reading above ``background + max(3 noise_std, detection_floor)``.
    rel_error : float
        Steady likelihood: the model's relative error ``rho``.
    hit_fraction, hit_shape, hit_log_sd, false_hit : float
        Patchy likelihood: ``pi0``, ``beta``, ``s`` and ``eps`` (:mod:`estimator.ste_model`).
    temper : float
        Exponent of each iteration's likelihood, in (0, 1].
    corr_length_m : float
        Readings of one iteration closer than about this see the same puffs and meander: each
        reading's exponent is ``temper / n_i``, ``n_i = sum_j exp(-d_ij^2 / 2 L^2)`` over the
        iteration's readings (itself included; 1 for a formation spread wider than ``L``);
        0: ``temper`` for every reading.
    corr_iterations : int
        The readings of this many previous iterations near reading ``i`` add to ``n_i`` too (a
        formation that stays put reads the same meander again within its ~5 s correlation time);
        0: the iteration's own readings only.
    region_m : float
        Convergence: the 95 % region's radius at most this.
    exploit_m : float or None
        Below this region radius the centre goes to the posterior mean (None: ``region_m``, i.e.
        infotaxis until converged).
    collapse_nats : float
        Mean deviance per reading of the best particle above which the posterior has collapsed.
    memory : int
        Iterations of readings re-applied after a collapse.
    info_particles : int
        Particles resampled from the posterior for the move's information and the model check.
    radius_gain : float
        The formation's radius (:attr:`formation_radius_m`, which the caller may honour) is
        ``radius_gain * region95_m`` within ``[min_radius_m, max_radius_m]``: wide while the release
        is uncertain, tight about it at the end; 0: the seeker does not size the formation
        (``formation_radius_m`` None).
    min_radius_m, max_radius_m : float
        Bounds of the formation radius (the minimum keeps an 8-vehicle CVT's spacing above 1.5 m).
    casting : bool
        Add crosswind casts (two steps across the wind, both ways) and up-wind diagonals to the
        move's candidates.
    misfit_z : float
        Model check: the readings of the last ``memory`` iterations are scored under the posterior
        predictive; their deviance standardised by its expectation and deviation if the model held
        (:attr:`fit_z`) above this flags :attr:`misfit` and withholds ``arrival``.
    corr_time_s : float
        With reading times (``propose(..., times_s=)``): the plume's correlation time ``tau`` (s);
        per sensor, a reading weighs ``min(1, max(dt / tau, ds / corr_path_m))`` of an independent
        one, ``dt``, ``ds`` to that sensor's previous reading (:mod:`estimator.ste_tempering`). Default 5 s: the simulated intermittent plume's
        meander time (``meander_time_s``, docs/fields.md); 0: every reading weighs 1.
    corr_path_m : float or None
        With reading times: the path a sensor flies for its readings to decorrelate; None: infinite
        (time alone: readings along a path see the same meander).
    time_temper : float
        With reading times: the exponent applied to those weights, in (0, 1] (readings of different
        sensors far apart at one instant still share the meander).
    same_time_s : float
        With reading times: readings of other sensors within this time and about ``corr_length_m``
        share reading ``i``'s weight (the per-update sharing of ``corr_length_m``, by time).
    timed : bool or None
        Use the readings' times when given (the tempering by time); False: keep each sensor's
        first reading of an update and the per-update tempering (``temper``). None: the
        intermittent likelihood only (``patchy``): the steady likelihood's error is the model's, a
        function of place correlated along the whole path, which time does not decorrelate
        (measured in lock-step missions: docs/seekers.md, "ste in missions").
    path_samples : int
        A candidate's information is computed for the formation at ``path_samples`` points evenly
        along the way to it (the last at the candidate): with sampling while moving the readings
        taken on the way count too; 1: at the candidate only.
    axis_steps : bool
        The move's candidate steps up, across the wind and vertically each sized by the posterior's
        spread along that axis (``1.4`` deviations, within ``[min_step_m, max_step_m]``) instead of
        all by half the 95 % region: short casts once the release's line is known while its
        distance up the wind is not.
    toward_mean_along : bool
        No information-seeking candidate steps along the wind away from the posterior mean's place
        (the formation then never drifts down the wind of an estimate up the wind of it).
    seed : int
        Seed of the filter's random numbers (reset re-seeds).
    """

    name = "ste"

    def __init__(self, wind_from_deg: float | None = None, *, wind_std_deg: float = 10.0, patchy: bool = False,
                 particles: int = 3000, prior_radius_m: float = 60.0, prior_height_m: float = 15.0,
                 amplitude_range: tuple = (0.05, 20.0), stability: str = "C", source_radius_m: float = 1.0,
                 ground_alt_m: float = 0.0, noise_std: float = 0.01, background: float = 0.0,
                 detection_floor: float = 0.0, rel_error: float = 0.3, hit_fraction: float = 0.6,
                 hit_shape: float = 0.8, hit_log_sd: float = 1.3, false_hit: float = 0.01, temper: float = 0.35,
                 corr_length_m: float = 1.0, region_m: float = 1.0, exploit_m: float | None = None,
                 min_step_m: float = 1.0, max_step_m: float = 8.0,
                 collapse_nats: float = 4.0, memory: int = 10, info_particles: int = 256, radius_gain: float = 0.5,
                 min_radius_m: float = 1.5, max_radius_m: float = 6.0, casting: bool = True, misfit_z: float = 4.0,
                 corr_iterations: int = 0, path_samples: int = 1, corr_time_s: float = 5.0,
                 corr_path_m: float | None = None, time_temper: float = 1.0, same_time_s: float = 0.25,
                 timed: bool | None = None, prior_upwind_deg: float | None = None,
                 axis_steps: bool = False, toward_mean_along: bool = False, prior_box_enu=None, seed: int = 0):
        if stability not in BRIGGS_RURAL:
            raise ValueError(f"unknown stability class {stability!r}; known: {', '.join(BRIGGS_RURAL)}")
        if wind_from_deg is not None and not np.isfinite(float(wind_from_deg)):
            raise ValueError(f"wind_from_deg must be finite, got {wind_from_deg!r}")
        for name, v in (("particles", particles), ("memory", memory), ("info_particles", info_particles),
                        ("path_samples", path_samples)):
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        lo, hi = (_positive("amplitude_range", a) for a in amplitude_range)
        if not lo < hi:
            raise ValueError(f"amplitude_range must be increasing, got {amplitude_range!r}")
        if not 0 < float(temper) <= 1:
            raise ValueError(f"temper must be in (0, 1], got {temper!r}")
        self.patchy, self.particles, self.memory = bool(patchy), int(particles), int(memory)
        self.wind_from_deg = None if wind_from_deg is None else float(wind_from_deg)
        self.wind_std_rad = np.deg2rad(_positive("wind_std_deg", wind_std_deg, allow_zero=True))
        self.info_particles = int(info_particles)
        self.path_samples = int(path_samples)
        self.log_amp = (np.log(lo), np.log(hi))
        self.model = dict(stability=stability, s0_m=_positive("source_radius_m", source_radius_m),
                          ground_alt_m=float(ground_alt_m), smooth=self.patchy)
        self.prior_radius_m = _positive("prior_radius_m", prior_radius_m)
        self.prior_height_m = _positive("prior_height_m", prior_height_m)
        if prior_upwind_deg is not None and not 0 < float(prior_upwind_deg) <= 180:
            raise ValueError(f"prior_upwind_deg must be in (0, 180] or None, got {prior_upwind_deg!r}")
        self.prior_upwind_deg = None if prior_upwind_deg is None else float(prior_upwind_deg)
        self.prior_box_enu = check_box(prior_box_enu, ground_alt_m=float(ground_alt_m))
        noise = _positive("noise_std", noise_std)
        self.background = _positive("background", background, allow_zero=True)
        self.threshold = max(3.0 * noise, _positive("detection_floor", detection_floor, allow_zero=True))
        self.steady_kw = dict(background=self.background, noise_std=noise, rel_error=_positive("rel_error", rel_error))
        self.patchy_kw = dict(threshold=self.threshold, pi0=_positive("hit_fraction", hit_fraction),
                              beta=_positive("hit_shape", hit_shape), log_sd=_positive("hit_log_sd", hit_log_sd),
                              eps=_positive("false_hit", false_hit))
        self.temper, self.seed = float(temper), int(seed)
        self.corr_length_m = _positive("corr_length_m", corr_length_m, allow_zero=True)
        if isinstance(corr_iterations, bool) or int(corr_iterations) != corr_iterations or corr_iterations < 0:
            raise ValueError(f"corr_iterations must be an integer >= 0, got {corr_iterations!r}")
        self.corr_iterations = int(corr_iterations)
        self.corr_time_s = _positive("corr_time_s", corr_time_s, allow_zero=True)
        self.corr_path_m = np.inf if corr_path_m is None else _positive("corr_path_m", corr_path_m)
        if not 0 < float(time_temper) <= 1:
            raise ValueError(f"time_temper must be in (0, 1], got {time_temper!r}")
        self.time_temper = float(time_temper)
        self.same_time_s = _positive("same_time_s", same_time_s, allow_zero=True)
        self.timed = self.patchy if timed is None else bool(timed)
        self.region_m = _positive("region_m", region_m)
        self.exploit_m = self.region_m if exploit_m is None else _positive("exploit_m", exploit_m)
        self.min_step_m, self.max_step_m = _positive("min_step_m", min_step_m), _positive("max_step_m", max_step_m)
        self.collapse_nats = _positive("collapse_nats", collapse_nats)
        self.radius_gain = _positive("radius_gain", radius_gain, allow_zero=True)
        self.min_radius_m = _positive("min_radius_m", min_radius_m)
        self.max_radius_m = _positive("max_radius_m", max_radius_m)
        if self.min_radius_m > self.max_radius_m:
            raise ValueError(f"min_radius_m {min_radius_m!r} must be at most max_radius_m {max_radius_m!r}")
        self.casting, self.misfit_z = bool(casting), _positive("misfit_z", misfit_z)
        self.axis_steps, self.toward_mean_along = bool(axis_steps), bool(toward_mean_along)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything (a new run); the random numbers restart from ``seed``."""
        self.rng = np.random.default_rng(self.seed)
        self._k = None
        self.arrival = None
        self.estimate_enu = None
        self.region95_m = None
        self.formation_radius_m = None
        self.fit_z = None
        self.misfit = None

    def _init_state(self, c: np.ndarray) -> None:
        k = c.shape[0]
        self._box = trial_boxes(self.prior_box_enu, c)  # raises before any state changes
        self._k = k
        self.parts = np.empty((k, self.particles, 5))
        self.logw = np.zeros((k, self.particles))
        self.collapses = np.zeros(k, dtype=int)
        self.collapsed = np.zeros(k, dtype=bool)
        self.hits = np.zeros(k, dtype=int)
        self.since_collapse = np.full(k, self.memory + 1)
        self.iterations = 0
        self._buf: list = []  # the last ``memory`` updates: (positions, values, applied weights, unit weights)
        self._last: list = [{} for _ in range(k)]  # per trial: sensor -> its newest (time_s, position)
        self._seed_prior(np.arange(k), c, upwind=True)

    def _seed_prior(self, idx: np.ndarray, c: np.ndarray, upwind: bool = False) -> None:
        """Particles of trials ``idx`` drawn from the prior about centres ``c[idx]``, equal weights
        (:func:`estimator.ste_prior.draw_prior`); with ``upwind`` and ``prior_upwind_deg``, in the
        sector up each particle's wind only; with ``prior_box_enu``, inside the box."""
        half = np.deg2rad(self.prior_upwind_deg) if upwind and self.prior_upwind_deg is not None else None
        self.parts[idx] = draw_prior(self.rng, c[idx], self.particles, radius_m=self.prior_radius_m,
                                     height_m=self.prior_height_m, ground_alt_m=self.model["ground_alt_m"],
                                     log_amp=self.log_amp, wind_from_deg=self.wind_from_deg,
                                     wind_std_rad=self.wind_std_rad, upwind_half_rad=half,
                                     box=None if self._box is None else self._box[idx])
        self.logw[idx] = -np.log(self.particles)

    # ------------------------------------------------------------------ the filter
    def _loglik(self, parts: np.ndarray, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Per-reading log-likelihoods ``(K, P, M)`` of readings ``v`` (K, M) at ``p`` (K, M, 3)."""
        if self.patchy:
            return loglik_patchy_fast(parts, p, v, model=self.model, background=self.background, **self.patchy_kw)
        return loglik_steady_fast(parts, p, v, model=self.model, **self.steady_kw)

    def _tempers(self, p: np.ndarray, recent: bool = False) -> np.ndarray:
        """Each reading's likelihood exponent ``(K, M)`` from the positions ``(K, M, 3)`` of one
        iteration's readings (``temper``, ``corr_length_m``); with ``recent``, the readings of the
        last ``corr_iterations`` iterations near them count too."""
        if self.corr_length_m == 0:
            return np.full(p.shape[:2], self.temper)
        near = p
        if recent and self.corr_iterations > 0 and self._buf:
            near = np.concatenate([p] + [b[0] for b in self._buf[-self.corr_iterations:]], axis=1)
        d2 = np.sum((p[:, :, None, :] - near[:, None, :, :]) ** 2, axis=-1)
        return self.temper / np.exp(-0.5 * d2 / self.corr_length_m ** 2).sum(axis=2)

    def _timed_weights(self, p: np.ndarray, v: np.ndarray, t: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Each reading's unit weight ``(K, M)`` in (0, 1] from its time and sensor
        (:mod:`estimator.ste_tempering`: per sensor by ``corr_time_s`` / ``corr_path_m``,
        shared across sensors within ``same_time_s`` and ``corr_length_m``)."""
        out = np.empty(v.shape)
        for k in range(v.shape[0]):
            w = time_weights(t[k], p[k], ids[k], self._last[k], self.corr_time_s, self.corr_path_m)
            out[k] = w / shared_counts(t[k], p[k], ids[k], self.corr_length_m, self.same_time_s)
        return out

    def _update(self, c: np.ndarray, p: np.ndarray, v: np.ndarray, unit: np.ndarray | None = None) -> None:
        """Fold the readings in (steps 1-2 of the module docstring); no readings: nothing to fold.
        ``unit``: each reading's weight from its time (:meth:`_timed_weights`, applied times
        ``time_temper``); None: the per-update tempering (``temper``, ``corr_length_m``)."""
        if v.shape[1] == 0:
            self.collapsed = np.zeros(v.shape[0], dtype=bool)
            self.since_collapse = self.since_collapse + 1
            return
        if unit is None:
            applied, again, unit = self._tempers(p, recent=True), self._tempers(p), np.ones(v.shape)
        else:
            applied = again = self.time_temper * unit
        ll = self._loglik(self.parts, p, v)
        best = ll.mean(axis=2).max(axis=1)  # the best particle's mean log-likelihood per reading
        collapsed = (-best > self.collapse_nats) & (v.shape[1] >= 4)
        self.logw = self.logw + np.einsum("kpm,km->kp", ll, applied)
        self.collapsed = collapsed
        self.since_collapse = np.where(collapsed, 0, self.since_collapse + 1)
        if collapsed.any():
            idx = np.flatnonzero(collapsed)
            self.collapses[idx] += 1
            self._seed_prior(idx, c)
            for bp, bv, bw, _ in self._buf[-self.memory:] + [(p, v, again, unit)]:
                self.logw[idx] += np.einsum("kpm,km->kp", self._loglik(self.parts[idx], bp[idx], bv[idx]), bw[idx])
        self.logw -= self.logw.max(axis=1, keepdims=True)
        self.logw -= np.log(np.exp(self.logw).sum(axis=1, keepdims=True))
        self._buf = (self._buf + [(p, v, again, unit)])[-self.memory:]

    def _circular(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean ``(K, 5)`` (the angle's circular mean) and deviations ``(K, P, 5)`` (wrapped)."""
        th = self.parts[..., 4]
        mean = np.einsum("kp,kpi->ki", w, self.parts)
        mean[:, 4] = np.arctan2(np.einsum("kp,kp->k", w, np.sin(th)), np.einsum("kp,kp->k", w, np.cos(th)))
        dev = self.parts - mean[:, None, :]
        dev[..., 4] = (dev[..., 4] + np.pi) % (2.0 * np.pi) - np.pi
        return mean, dev

    def _resample(self, h: float = 0.2) -> None:
        """Systematic resampling where the effective sample size is below half, then Liu-West roughening."""
        w = np.exp(self.logw)
        ess = 1.0 / np.sum(w * w, axis=1)
        idx = np.flatnonzero(ess < 0.5 * self.particles)
        if idx.size == 0:
            return
        pick = _systematic(w[idx], self.particles, self.rng.uniform(0.0, 1.0, idx.size))
        mean, dev = self._circular(w)
        cov = np.einsum("kp,kpi,kpj->kij", w, dev, dev)[idx] + np.diag(_FLOOR ** 2)
        chol = np.linalg.cholesky(cov)
        a = np.sqrt(1.0 - h * h)
        chosen = np.take_along_axis(dev[idx], pick[..., None], axis=1)
        noise = np.einsum("kij,kpj->kpi", chol, self.rng.standard_normal(chosen.shape))
        new = mean[idx, None, :] + a * chosen + h * noise
        new[..., 2] = np.maximum(new[..., 2], self.model["ground_alt_m"] + 0.1)
        if self._box is not None:
            new[..., :3] = np.clip(new[..., :3], self._box[idx, None, 0], self._box[idx, None, 1])
        new[..., 3] = np.clip(new[..., 3], *self.log_amp)
        self.parts[idx] = new
        self.logw[idx] = -np.log(self.particles)

    def _summarise(self) -> None:
        """Posterior mean release point and the radius about it that holds 95 % of the weight."""
        w = np.exp(self.logw)
        mean = np.einsum("kp,kpi->ki", w, self.parts[..., :3])
        d = np.linalg.norm(self.parts[..., :3] - mean[:, None, :], axis=-1)
        order = np.argsort(d, axis=1)
        cum = np.cumsum(np.take_along_axis(w, order, axis=1), axis=1)
        at = np.minimum(np.argmax(cum >= 0.95, axis=1), self.particles - 1)
        self.estimate_enu = mean
        self.region95_m = np.take_along_axis(d, np.take_along_axis(order, at[:, None], 1), 1)[:, 0]

    def _check_fit(self, sub: np.ndarray) -> None:
        """Model check (class docstring, ``misfit_z``) of the buffered readings on the particles ``sub``."""
        pos = np.concatenate([b[0] for b in self._buf], axis=1)
        val = np.concatenate([b[1] for b in self._buf], axis=1)
        u = np.concatenate([b[3] for b in self._buf], axis=1)  # a reading's share of independent evidence
        if self.patchy:
            d, e, var = deviance_patchy(hit_probability_fast(sub, pos, model=self.model, **self.patchy_kw).mean(axis=1),
                                        val - self.background > self.threshold)
        else:
            mu, _ = plume_mean_fast(sub, pos, **self.model)
            spread = self.steady_kw["noise_std"] ** 2 + self.steady_kw["rel_error"] ** 2 * (mu * mu).mean(axis=1)
            d, e, var = deviance_steady(mu.mean(axis=1), spread + mu.var(axis=1), val, background=self.background)
        self.fit_z = np.sum(u * (d - e), axis=1) / np.sqrt(np.maximum(np.sum(u * var, axis=1), 1e-12))
        self.misfit = self.fit_z > self.misfit_z
        self.arrival = (self.region95_m <= self.region_m) & (self.since_collapse > self.memory) & ~self.misfit

    def _size_formation(self, p: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Set :attr:`formation_radius_m`; the offsets ``(K, N, 3)`` of the next formation about its centre."""
        off = p - c[:, None, :]
        if self.radius_gain == 0 or off.shape[1] < 2:
            return off
        radius = np.clip(self.radius_gain * self.region95_m, self.min_radius_m, self.max_radius_m)
        self.formation_radius_m = radius
        base = np.linalg.norm(off, axis=-1).mean(axis=1)
        return off * (radius / np.maximum(base, 1e-9))[:, None, None]

    # ------------------------------------------------------------------ the move
    def _p_hit(self, parts: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Each particle's probability of a hit at ``pts`` (K, M, 3): ``(K, P, M)`` (the move's outcome model)."""
        if self.patchy:
            return hit_probability_fast(parts, pts, model=self.model, **self.patchy_kw)
        return steady_hit_probability_fast(parts, pts, model=self.model, threshold=self.threshold,
                                           noise_std=self.steady_kw["noise_std"], rel_error=self.steady_kw["rel_error"])

    def _upwind(self) -> np.ndarray:
        """Unit vectors ``(K, 3)`` up the posterior's (circular) mean wind."""
        w = np.exp(self.logw)
        th = np.arctan2(np.einsum("kp,kp->k", w, np.sin(self.parts[..., 4])),
                        np.einsum("kp,kp->k", w, np.cos(self.parts[..., 4])))
        return np.stack([-np.cos(th), -np.sin(th), np.zeros_like(th)], axis=1)

    def _candidates(self, c: np.ndarray) -> np.ndarray:
        """Candidate centres ``(K, C, 3)``: 8, or 12 with ``casting`` (module docstring, step 5);
        with ``axis_steps`` the steps up, across the wind and vertically each from the posterior's
        spread along that axis."""
        up = self._upwind()
        cross = np.stack([-up[:, 1], up[:, 0], np.zeros(len(up))], axis=1)
        vert = np.broadcast_to([0.0, 0.0, 1.0], up.shape)
        step = np.clip(0.5 * self.region95_m, self.min_step_m, self.max_step_m)[:, None]
        to_mean = self.estimate_enu - c
        dist = np.linalg.norm(to_mean, axis=1, keepdims=True)
        toward = c + to_mean * np.minimum(1.0, step / np.maximum(dist, 1e-9))
        if self.axis_steps:
            s_up, s_cross, s_z = (np.clip(_AXIS_STEP * sd, self.min_step_m, self.max_step_m)[:, None]
                                  for sd in self._spreads(up, cross))
            up, cross, vert, step = up * s_up, cross * s_cross, vert * s_z, 1.0
        dirs = [np.zeros_like(up), up, -up, cross, -cross, 0.5 * vert, -0.5 * vert]
        if self.casting:
            dirs += [2.0 * cross, -2.0 * cross, (up + cross) / np.sqrt(2.0), (up - cross) / np.sqrt(2.0)]
        return np.stack([c + step * d for d in dirs] + [toward], axis=1)

    def _away_along(self, c: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """``(K, C)``: candidates that step along the wind away from the posterior mean's place
        (down the wind of a centre that is down the wind of the mean, or up the wind of one up the
        wind of it; more than 0.1 m each)."""
        up = self._upwind()
        a = np.einsum("ki,ki->k", self.estimate_enu - c, up)
        step = np.einsum("kci,ki->kc", cand - c[:, None, :], up)
        return (np.abs(a)[:, None] > 0.1) & (np.abs(step) > 0.1) & (np.sign(step) != np.sign(a)[:, None])

    def _spreads(self, up: np.ndarray, cross: np.ndarray) -> tuple:
        """The posterior's standard deviations ``(K,)`` of the release up the wind, across it and vertically."""
        w = np.exp(self.logw)
        dev = self.parts[..., :3] - self.estimate_enu[:, None, :]
        return tuple(np.sqrt(np.einsum("kp,kp->k", w, np.einsum("kpi,ki->kp", dev, axis) ** 2))
                     for axis in (up, cross, np.broadcast_to([0.0, 0.0, 1.0], up.shape)))

    def _subsample(self) -> np.ndarray:
        """``info_particles`` particles per trial resampled from the posterior, equal weights."""
        k, s = self._k, min(self.info_particles, self.particles)
        pick = _systematic(np.exp(self.logw), s, self.rng.uniform(0.0, 1.0, k))
        return np.take_along_axis(self.parts, pick[..., None], axis=1)

    def _next_centre(self, c: np.ndarray, off: np.ndarray, sub: np.ndarray) -> np.ndarray:
        """The candidate with the most expected information for a formation of offsets ``off``,
        or the posterior mean (step 5)."""
        k = c.shape[0]
        cand = self._candidates(c)
        frac = np.arange(1, self.path_samples + 1) / self.path_samples  # points along the way (path_samples)
        way = c[:, None, None, :] + frac[None, None, :, None] * (cand - c[:, None, :])[:, :, None, :]  # (K, C, F, 3)
        pts = (way[:, :, :, None, :] + off[:, None, None, :, :]).reshape(k, -1, 3)
        q = self._p_hit(sub, pts)  # (K, S, C * F * N)
        info = (_entropy2(q.mean(axis=1)) - _entropy2(q).mean(axis=1)).reshape(k, cand.shape[1], -1).sum(axis=2)
        if self.toward_mean_along:
            info = np.where(self._away_along(c, cand), -np.inf, info)
        best = np.take_along_axis(cand, np.argmax(info, axis=1)[:, None, None], axis=1)[:, 0]
        return np.where((self.region95_m < self.exploit_m)[:, None], self.estimate_enu, best)

    #: :meth:`propose` takes the readings' times and sensors (:func:`estimator.seekers.propose_readings`)
    takes_times = True

    def propose(self, centre, positions, values, times_s=None, sensor_ids=None) -> np.ndarray:
        """Next centres ``(K, 3)`` from centres ``(K, 3)``, positions ``(K, M, 3)``, readings ``(K, M)``.

        ``times_s`` ``(K, M)``: when each reading was taken (s, any epoch); each reading is then
        weighted by its share of independent evidence (:mod:`estimator.ste_tempering`), so every
        reading since takeoff can be given, densely; ``sensor_ids`` ``(K, M)`` which sensor took it
        (None: column ``m`` is sensor ``m``). Without times: the per-update tempering (``temper``,
        ``corr_length_m``), calibrated for one reading per vehicle per update.
        """
        c, p, v = seeker_inputs(centre, positions, values)
        t, ids = reading_times(times_s, sensor_ids, v.shape)
        if t is not None and not self.timed:
            p, v, t, ids = first_per_sensor(p, v, t, ids)
        if self._k != c.shape[0]:
            self._init_state(c)
        self.iterations += 1
        self.hits += np.sum(v - self.background > self.threshold, axis=1)
        self._update(c, p, v, None if t is None else self._timed_weights(p, v, t, ids))
        self._summarise()
        sub = self._subsample()
        self._check_fit(sub)
        nxt = self._next_centre(c, self._size_formation(formation_points(p, t, ids), c), sub)
        self._resample()
        return nxt

    # ------------------------------------------------------------------ the estimate, reported
    def source_estimate(self, k: int = 0, plan_map: bool = True) -> SourceEstimate | None:
        """Trial ``k``'s posterior mean release point with its 95 % region (:attr:`region95_m`,
        the radius about the mean holding 95 % of the weight) and, with ``plan_map``, the plan-view
        posterior (:meth:`posterior_map`); None before the first update."""
        if self.estimate_enu is None or not 0 <= k < self._k:
            return None
        return SourceEstimate(self.estimate_enu[k], float(self.region95_m[k]), "posterior 95 % region",
                              self.posterior_map(k) if plan_map else None)

    def posterior_map(self, k: int = 0, cells: int = 24) -> PlanPosterior | None:
        """Trial ``k``'s posterior over the release's (east, north): the particles' weighted
        histogram on ``cells x cells`` cells about the posterior mean, the grid's half-side
        ``1.5 region95_m`` (at least 1 m); None before the first update."""
        if self.estimate_enu is None or not 0 <= k < self._k:
            return None
        w = np.exp(self.logw[k])
        half = max(1.5 * float(self.region95_m[k]), 1.0)
        return PlanPosterior.weighted(self.parts[k, :, 0], self.parts[k, :, 1], w / w.sum(),
                                      self.estimate_enu[k, :2], half, cells)
