"""Seekers: readings in, next formation centre out (pure numpy, batched over trials).

Every seeker has the same small interface (:class:`Seeker`): ``propose(centre, positions,
values)`` takes the commanded centres ``(K, 3)``, where each reading was actually taken
``(K, N, 3)`` and the readings ``(K, N)``, and returns the next centres ``(K, 3)``. The caller
applies the step cap (``gamma_m``, :func:`cap_move`) and the safety envelope afterwards; a
seeker never sees them. ``K`` is the number of independent trials (1 in the mission).

* ``"gradient"`` (:class:`GradientSeeker`): the paper's gradient ascent, ``c + eps g`` with
  ``g`` Theorem 2 (centred least squares) about the centroid of the readings' positions.
* ``"newton"`` (:class:`NewtonSeeker`): a second-order seeker. The Hessian and gradient of the
  field are fitted (quadratic least squares) to the readings of the current and the previous
  iteration (a CVT of N = 8 alone gives 8 readings for 10 coefficients); a Newton step
  ``-H^-1 g`` where ``H`` is negative definite, else a gradient step, both inside a trust region
  whose radius doubles after a step that did what the model predicted and halves after one
  that made things worse.
* ``"model"`` (:class:`ModelSeeker`): fits a quadratic in ``log`` of the readings (exact for a
  Gaussian source) to the last ``window`` iterations' readings from all vehicles and steps to
  the fitted maximum when the fit's uncertainty on it is small, else along the fitted gradient
  by the trust radius (same trust region).
* ``"plume"`` (:class:`~estimator.seek_plume.PlumeSeeker`): for wind-advected plumes: surge up
  the plume's axis with the most upwind vehicle on it while the signal is there, cast across
  the wind when it is lost, hold at the point where that vehicle read the most before the
  plume ended upwind (``wind_from_deg`` given, or the axis estimated from the readings).
* ``"ste"`` (:class:`~estimator.ste.SteSeeker`): source-term estimation, a particle filter over
  the release point, its amplitude and the wind direction fed every reading (hits and misses),
  moving for information; it reports ``estimate_enu`` with ``region95_m``, the radius of its
  95 % region (seekers without a posterior have no such attributes).

**Reading times.** A seeker with ``takes_times = True`` (``ste``) also takes
``propose(..., times_s=(K, N), sensor_ids=(K, N))``: when and by which sensor each reading was
taken, so that dense readings (every reading of every vehicle while moving) can be weighed by
the independent evidence they carry. :func:`propose_readings` passes them to such a seeker and
calls every other seeker as before (they never see them).

Every seeker also has ``source_estimate(k=0)``: trial ``k``'s estimate of the source as an
:class:`~estimator.estimate.SourceEstimate` (the point, its 95 % region, what that region is), or
None when the seeker has no estimate of its own (``gradient``, ``newton``, ``plume``: the mission
then reports the convergence monitor's mean of the recent centres, labelled as such;
:func:`estimator.estimate.reported_estimate`). ``model``: the fitted maximum, with the sphere
holding 95 % of the fit's covariance; ``ste``: the posterior mean and its 95 % region.

The maths and the failure modes are in ``docs/seekers.md``.
"""
from __future__ import annotations

from collections import deque
from typing import Protocol

import numpy as np

from estimator.estimate import SourceEstimate, sphere_radius95_m
from estimator.gradient import DEFAULT_MAX_CONDITION, estimator_weights
from estimator.seek_inputs import seeker_inputs as _inputs
from estimator.seek_hits import HitEdgeSeeker
from estimator.seek_plume import PlumeSeeker
from estimator.seek_quadratic import fit_quadratic
from estimator.ste import SteSeeker

__all__ = [
    "SEEKERS", "OFFLINE_SEEKERS", "MOVING_SEEKERS", "Seeker", "GradientSeeker", "NewtonSeeker",
    "ModelSeeker", "make_seeker", "cap_move", "propose_readings", "BEST_SEEKER_BY_FIELD", "DEFAULT_SEEKER",
    "best_seeker",
]

#: Seeker names accepted by :func:`make_seeker` (and by the plan's ``[seeking] seeker``).
SEEKERS = ("gradient", "newton", "model", "plume", "ste")
#: Seekers :func:`make_seeker` also builds that plans and the CLI do not offer yet (none left: ``ste``
#: joined :data:`SEEKERS`).
OFFLINE_SEEKERS: tuple[str, ...] = ()
#: Seekers that can use readings taken anywhere, so can sample while moving (``[seeking] sampling
#: = "moving"``); the paper's gradient needs the formation's shape at rest (Theorem 2) and the
#: plume seeker compares readings taken at rest. ``ste`` folds each reading in at the position where
#: it was taken.
MOVING_SEEKERS = ("newton", "model", "ste")

#: the best measured seeker for a field type (``[field] type``, ``swarmseek run --field``; ``simulate
#: --field`` on plumes), when the plan or the command line names none: the source-term estimator on
#: plumes (docs/seekers.md), the log-quadratic ``model`` seeker on every other field (no small-N
#: bias: docs/mission.md)
BEST_SEEKER_BY_FIELD = {"plume": "ste", "intermittent": "ste"}
#: the seeker of a plan or a ``run`` without a field type in :data:`BEST_SEEKER_BY_FIELD`
DEFAULT_SEEKER = "model"


def best_seeker(field_type: str | None) -> str:
    """The seeker a mission on a field of ``field_type`` uses when none is named.

    Parameters
    ----------
    field_type : str or None
        ``[field] type`` of the plan (``swarmseek run --field``); None: no virtual field (a real
        sensor, or a field the plan does not name).

    Returns
    -------
    str
        ``ste`` for the plume fields, ``model`` otherwise.
    """
    return BEST_SEEKER_BY_FIELD.get(field_type, DEFAULT_SEEKER)


class Seeker(Protocol):
    """Readings in, next centre out."""

    name: str

    def propose(self, centre, positions, values) -> np.ndarray:
        """Next centres ``(K, 3)`` from the centres ``(K, 3)``, positions ``(K, N, 3)``, readings ``(K, N)``."""

    def reset(self) -> None:
        """Forget everything seen (a new run)."""

    def source_estimate(self, k: int = 0) -> SourceEstimate | None:
        """Trial ``k``'s estimate of the source with its 95 % region; None: the seeker has none."""


def propose_readings(seeker, centre, positions, values, times_s=None, sensor_ids=None) -> np.ndarray:
    """``seeker.propose(centre, positions, values)``, with the readings' ``times_s`` and
    ``sensor_ids`` (each ``(K, N)``, or None) passed when the seeker takes them (``takes_times``)."""
    if times_s is not None and getattr(seeker, "takes_times", False):
        return seeker.propose(centre, positions, values, times_s=times_s, sensor_ids=sensor_ids)
    return seeker.propose(centre, positions, values)


def cap_move(centre, new_centre, gamma_m: float) -> np.ndarray:
    """``new_centre`` with the move from ``centre`` scaled down to at most ``gamma_m`` (direction kept)."""
    c = np.asarray(centre, dtype=float)
    move = np.asarray(new_centre, dtype=float) - c
    length = np.linalg.norm(move, axis=-1, keepdims=True)
    over = length > gamma_m
    return c + move * np.where(over, gamma_m / np.where(over, length, 1.0), 1.0)


class GradientSeeker:
    """The paper's gradient ascent: ``c + eps g_hat`` (the cap ``gamma`` is applied by the caller).

    Parameters
    ----------
    eps : float
        Step gain (metres per signal unit per metre).
    method : {"cvt", "symmetric"}
        Theorem 2 (centred least squares about the readings' centroid) or eq. (3).
    """

    name = "gradient"

    def __init__(self, eps: float = 1.0, method: str = "cvt", max_condition: float = DEFAULT_MAX_CONDITION):
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"eps must be a positive finite number, got {eps!r}")
        self.eps = float(eps)
        self.method = method
        self.max_condition = float(max_condition)

    def reset(self) -> None:
        """Nothing to forget: the paper's step is memoryless."""

    def source_estimate(self, k: int = 0) -> None:
        """None: the paper's step estimates a gradient, never the source (the mission reports the
        convergence monitor's mean of the recent centres)."""
        return None

    def propose(self, centre, positions, values) -> np.ndarray:
        """``c + eps g`` per trial, ``g`` estimated about the centroid of ``positions``."""
        c, p, v = _inputs(centre, positions, values)
        off = p - p.mean(axis=1, keepdims=True)
        w, _ = estimator_weights(off, self.method, self.max_condition)
        g = np.einsum("kn,kni->ki", v, w)
        return c + self.eps * g


class _TrustRegionSeeker:
    """Quadratic model of a window of readings, stepped inside an adaptive trust region."""

    name = "quadratic"
    log = False
    use_uncertainty = False

    def __init__(self, window: int, radius_m: float = 5.0, min_radius_m: float = 0.25,
                 max_radius_m: float = 20.0, confidence: float = 1.0, confident_m: float = 0.5,
                 merge_m: float = 1.0, shrink: bool = True):
        if int(window) != window or window < 1:
            raise ValueError(f"window must be an integer >= 1, got {window!r}")
        if not (0 < min_radius_m <= radius_m <= max_radius_m and np.isfinite(max_radius_m)):
            raise ValueError("need 0 < min_radius_m <= radius_m <= max_radius_m (finite)")
        self.window = int(window)
        self.radius0_m, self.min_radius_m, self.max_radius_m = float(radius_m), float(min_radius_m), float(max_radius_m)
        self.confidence, self.confident_m = float(confidence), float(confident_m)
        self.merge_m = float(merge_m)
        self.shrink = bool(shrink)
        self.reset()

    def reset(self) -> None:
        """Forget the window and the trust region."""
        self._buf: deque = deque(maxlen=self.window)
        self.radius_m = None
        self._prev = None  # (centre, predicted gain, hit the radius, well inside it)
        self.last_fit = None
        self.last_newton = None
        self.last_centre = None  # the centre the last fit is about

    def source_estimate(self, k: int = 0) -> SourceEstimate | None:
        """None: the ``newton`` seeker's Taylor model of the readings is a local step, not a
        model of the source (its maximum is biased by the field's shape away from the peak, a
        bias its covariance does not see); the mission reports the monitor's mean of the centres."""
        return None

    def _window(self, c, p, v):
        """The window's readings; an iteration whose centre is within ``merge_m`` of the last
        kept one joins it (at most ``4 N`` readings kept there) instead of pushing an older
        position out: readings all about one point cannot show the trace of ``H``."""
        if self._buf:
            c_last, p_last, v_last = self._buf[-1]
            if np.all(np.linalg.norm(c - c_last, axis=-1) <= self.merge_m):
                keep = 4 * p.shape[1]
                self._buf[-1] = (c_last, np.concatenate([p_last, p], axis=1)[:, -keep:],
                                 np.concatenate([v_last, v], axis=1)[:, -keep:])
            else:
                self._buf.append((c, p, v))
        else:
            self._buf.append((c, p, v))
        pos = np.concatenate([b[1] for b in self._buf], axis=1)
        val = np.concatenate([b[2] for b in self._buf], axis=1)
        return pos, val, np.ones(val.shape, dtype=bool)

    def _update_radius(self, fit, c) -> None:
        if self._prev is None:
            return
        c_old, pred, hit, inside = self._prev
        # the outcome of the last step as the current fit sees it: the fitted value here minus
        # the fitted value at the previous centre (both from the readings about them)
        actual = -fit.predicted_gain(c_old - c)
        with np.errstate(invalid="ignore"):
            noise = 2.0 * np.sqrt(2.0) * fit.value_std
            noise = np.where(np.isfinite(noise), noise, np.inf)
            rho = np.where(pred > 0, actual / np.where(pred > 0, pred, 1.0), 0.0)
        worse = (actual < -noise) | ((rho < 0.25) & (pred > noise))
        good = ~worse & (rho > 0.5) & hit & (actual > noise)
        shrink = worse | inside  # a step well inside the region: the region need not be that large
        r = np.where(shrink, self.radius_m / 2.0, np.where(good, self.radius_m * 2.0, self.radius_m))
        self.radius_m = np.clip(r, self.min_radius_m, self.max_radius_m)

    def _newton_ok(self, fit) -> np.ndarray:
        ok = fit.concave & np.all(np.isfinite(fit.newton), axis=-1)
        if self.use_uncertainty:
            length = np.linalg.norm(np.where(ok[:, None], fit.newton, 0.0), axis=-1)
            ok &= fit.newton_std_m <= np.maximum(self.confidence * length, self.confident_m)
        return ok

    @staticmethod
    def _uphill(fit, r):
        """Cauchy step: up the fitted gradient to the model's maximum along it, at most ``r``."""
        g = fit.grad
        g2 = np.einsum("ki,ki->k", g, g)
        curv = np.einsum("ki,kij,kj->k", g, fit.hessian, g)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(curv < 0, g2 / np.where(curv < 0, -curv, 1.0), np.inf)  # metres per unit g
            length = np.minimum(r, t * np.sqrt(g2))
            return g * np.where(g2 > 0, length / np.sqrt(np.where(g2 > 0, g2, 1.0)), 0.0)[:, None]

    def propose(self, centre, positions, values) -> np.ndarray:
        """Fit, adapt the trust radius from the last step's outcome, step (class docstring)."""
        c, p, v = _inputs(centre, positions, values)
        if self.radius_m is None or np.shape(self.radius_m) != (c.shape[0],):
            self.radius_m = np.full(c.shape[0], self.radius0_m)
        fit = fit_quadratic(*self._window(c, p, v), c, self.log)
        self._update_radius(fit, c)
        ok = self._newton_ok(fit)
        r = self.radius_m
        newton = np.where(ok[:, None], fit.newton, 0.0)
        p_len2 = np.sum(newton**2, axis=-1)
        std2 = np.where(ok, np.nan_to_num(fit.newton_std_m, posinf=1e150), 0.0) ** 2
        if self.use_uncertainty and self.shrink:  # shrink a step that is mostly noise: |p|^2 / (|p|^2 + std^2)
            newton = newton * (p_len2 / np.maximum(p_len2 + std2, 1e-300))[:, None]
        n_len = np.linalg.norm(newton, axis=-1)
        newton = newton * np.minimum(1.0, r / np.maximum(n_len, 1e-300))[:, None]
        step = np.where(ok[:, None], newton, self._uphill(fit, r))
        length = np.linalg.norm(step, axis=-1)
        hit = length >= r * (1 - 1e-9)
        self._prev = (c, fit.predicted_gain(step), hit, length < r / 4.0)
        self.last_fit, self.last_newton, self.last_centre = fit, ok, c
        return c + step


class NewtonSeeker(_TrustRegionSeeker):
    """Second-order seeker: quadratic fit of the readings of the last ``window`` (2) iterations,
    Newton steps where the fitted Hessian is negative definite, gradient steps elsewhere, all
    inside the trust region (radius ``radius_m``, halved/doubled within ``[min, max]``)."""

    name = "newton"
    log = False
    use_uncertainty = False

    def __init__(self, window: int = 2, **kwargs):
        super().__init__(window, **kwargs)


class ModelSeeker(_TrustRegionSeeker):
    """Model-based seeker: quadratic in ``log`` of the readings over the last ``window`` (6)
    iterations; steps to the fitted maximum when its RMS uncertainty is at most
    ``max(confidence * |step|, confident_m)``, else up the fitted gradient by the trust radius."""

    name = "model"
    log = True
    use_uncertainty = True
    #: what the region of :meth:`source_estimate` is
    BASIS = ("maximum of the log-quadratic fit; region: the sphere holding 95 % of the fit's covariance "
             "(delta method: the readings' noise, not the model's error)")

    def __init__(self, window: int = 6, **kwargs):
        super().__init__(window, **kwargs)

    def source_estimate(self, k: int = 0) -> SourceEstimate | None:
        """The last fit's maximum ``c + p`` (exact for a Gaussian source) with the radius of the
        sphere about it holding 95 % of ``N(0, cov p)`` (:func:`estimator.estimate.sphere_radius95_m`);
        None before a fit, or while the fit has no maximum (not concave) or too few readings for a
        covariance."""
        point = self.source_point(k)
        if point is None:
            return None
        return SourceEstimate(point[0], sphere_radius95_m(self.last_fit.newton_cov[k]), self.BASIS)

    def source_point(self, k: int = 0) -> tuple[np.ndarray, float] | None:
        """The point of :meth:`source_estimate` (None when it has none) and a lower bound of its
        region's radius, ``1.96 sqrt(lambda_max)`` of the covariance (the 95 % point along its widest
        axis alone), without the region itself, whose computation costs milliseconds
        (:func:`estimator.estimate.sphere_radius95_m`)."""
        fit = self.last_fit
        if fit is None or fit.newton_cov is None or not 0 <= k < len(fit.concave):
            return None
        cov = fit.newton_cov[k]
        if not (fit.concave[k] and np.all(np.isfinite(fit.newton[k])) and np.all(np.isfinite(cov))):
            return None
        if not self._determined(k):
            return None
        lam = float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[-1])
        return self.last_centre[k] + fit.newton[k], 1.959963984540054 * float(np.sqrt(max(lam, 0.0)))

    def _determined(self, k: int, rtol: float = 3e-3) -> bool:
        """Whether the window's readings of trial ``k`` determine the ten coefficients well: the
        weighted design's smallest singular value at least ``rtol`` of its largest. Readings
        repeated at (nearly) the same few points (a formation hovering on its exact slots: 8 points
        for 10 coefficients) leave directions that only the fit's ridge, or a few millimetres of
        spread, fix, and the delta method's covariance is then far too small (offline, sigma_2: the
        source inside the region in 0.42-0.46 of the trials on exact slots, 0.98 with 0.1 m of
        position jitter; ``docs/seekers.md``)."""
        pos = np.concatenate([b[1][k] for b in self._buf], axis=0)
        val = np.concatenate([b[2][k] for b in self._buf], axis=0)
        ok = val > 0
        if np.count_nonzero(ok) < 10:
            return False
        d = pos[ok] - self.last_centre[k]
        d = d / max(float(np.sqrt(np.mean(np.sum(d * d, axis=1)))), 1e-12)
        quad = d[:, [0, 1, 2, 0, 0, 1]] * d[:, [0, 1, 2, 1, 2, 2]]
        f = np.concatenate([np.ones((len(d), 1)), d, quad], axis=1) * val[ok, None]  # sqrt of the weights s^2
        sv = np.linalg.svd(f, compute_uv=False)
        return bool(sv[-1] >= rtol * sv[0])


def make_seeker(name: str, *, eps: float = 1.0, method: str = "cvt", **kwargs) -> Seeker:
    """A seeker by name (:data:`SEEKERS`); ``eps``/``method`` go to the gradient seeker, the
    other keywords (``window``, ``radius_m``, ...; ``wind_from_deg``, ... for ``plume``) to the others;
    ``plume`` with ``patchy=True``: :class:`~estimator.seek_hits.HitEdgeSeeker` (intermittent plumes)."""
    if name == "gradient":
        return GradientSeeker(eps=eps, method=method)
    if name == "newton":
        return NewtonSeeker(**kwargs)
    if name == "model":
        return ModelSeeker(**kwargs)
    if name == "plume":
        if kwargs.pop("patchy", False):  # intermittent plumes: the hit cloud's upwind edge
            return HitEdgeSeeker(**kwargs)
        return PlumeSeeker(**kwargs)
    if name == "ste":  # source-term estimation: a particle filter (estimator.ste)
        return SteSeeker(**kwargs)
    raise ValueError(f"unknown seeker {name!r}; expected one of {', '.join(SEEKERS + OFFLINE_SEEKERS)}")
