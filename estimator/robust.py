"""Robust gradient estimation for a formation with faulty sensors (pure numpy, no I/O).

The estimator is Theorem 2 generalised to weighted least squares. For offsets
``r_i = p_i - c`` and readings ``y_i`` with weights ``w_i``::

    g = (sum_i w_i r~_i r~_i^T)^-1 sum_i w_i (y_i - s_c) r~_i

* ``centre="fit"`` (default): ``s_c`` and ``g`` are the joint weighted least-squares fit of
  the local linear model ``y_i = s_c + g . r_i``; equivalently ``r~_i = r_i - rbar_w`` with
  ``rbar_w`` the weighted mean offset and ``s_c`` the weighted mean reading at it. Exact on a
  linear field for *any* weights and any subset of at least 4 non-coplanar sensors (so dropping
  a faulty sensor adds no bias).
* ``centre="weighted_mean"``: ``r~_i = r_i``, ``s_c = sum w_i y_i / sum w_i``. With equal
  weights this is exactly Theorem 2 with the paper's Remark (``s_c`` = mean reading),
  :func:`estimator.gradient` with ``method="cvt"``; it is biased by
  ``M^-1 rbar (rbar . grad) W`` when ``sum w_i r_i != 0`` (e.g. after dropping a sensor).

Online, per sensor, over a sliding window of the last ``window`` updates:

* **prediction errors** of the local linear model, leave-one-out: ``d_i`` is sensor i's reading
  minus the prediction of the weighted fit of the *other* sensors (``d_i = e_i / (1 - h_ii)``
  with ``e_i = y_i - s_c - g . r_i`` and ``h_ii`` the leverage; a sensor left out of the fit
  already has its prediction error). ``E[d_i^2] = var_i + p_i`` with ``p_i`` the variance of
  that prediction, which does not depend on sensor i's own weight: no feedback from a wrong
  weight to its own variance estimate.
* **noise variance**: the mean square of the sensor's windowed prediction errors about their
  median, winsorised at 3 robust standard deviations (``1.4826 MAD``) so that spikes do not
  inflate it, minus the mean prediction variance. Weights
  ``w_i = 1 / max(var_i, floor)`` with ``floor = var_floor_rel * median(var)``: a sensor with 5x
  the noise gets 1/25 of the weight.
* **spiking**: a reading whose residual is more than ``k_mad`` robust standard deviations
  (``1.4826 MAD_i``) from the sensor's windowed median residual is left out of this update's fit
  and counted; the sensor is reported ``spiking`` when more than ``spike_rate`` of its recent
  readings were rejected.
* **stuck**: a sensor whose readings stop changing (exponentially weighted mean of squared
  successive differences, time constant ``window``, below ``stuck_ratio`` times the median of
  the others) while the others vary.
* **biased**: persistent prediction errors (windowed medians ``m_j``) that a bias ``b_i`` on
  one sensor explains: a bias leaks into the others' leave-one-out predictions through the
  known map ``d = D^-1 (I - H) y``, so ``b_i`` is fitted to all the ``m_j`` by that map's
  column ``i``; flagged if it explains at least ``bias_explained`` of their weighted energy and
  ``|b_i|`` exceeds ``k_bias`` standard errors of a windowed median and ``bias_min_std`` times
  the sensor's prediction-error std. (With a rigid formation a bias and the field's curvature
  across the formation can look alike; the last condition keeps the curvature of a large
  formation from being flagged.)
* **noisy**: ``std_i > k_noisy * median(std)`` (reported; handled by the weights).

Stuck and biased sensors are excluded from the fit, spiking readings are excluded one update
at a time; an exclusion happens only while at least ``min_sensors`` (>= 4) sensors remain and
the weighted geometry has ``cond(M) <= max_condition``; otherwise the sensor stays in with
its (small) weight. Faults are only declared after ``warmup`` updates.

The estimator is vectorised over a leading batch of independent formations
(``batch_shape``), which the offline Monte Carlo uses; a mission uses the default ``()``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.gradient import DEFAULT_MAX_CONDITION, GeometryError

__all__ = [
    "CENTRE_MODES",
    "REASONS",
    "Suspect",
    "RobustGradientEstimator",
    "weighted_gradient",
]

#: ways of choosing the centre value ``s_c`` (see the module docstring)
CENTRE_MODES = ("fit", "weighted_mean")
#: suspect reasons, in order of precedence (a sensor is reported once, for the first that applies)
REASONS = ("stuck", "biased", "spiking", "noisy")
_MAD_TO_STD = 1.4826
#: E[min(X^2, 9)] for a standard normal X (winsorising at 3 standard deviations)
_WINSOR3 = 0.99734


@dataclass(frozen=True)
class Suspect:
    """A sensor the estimator distrusts.

    Attributes
    ----------
    index : int
        0-based sensor (vehicle) index in the order of the readings.
    reason : str
        One of :data:`REASONS`.
    excluded : bool
        Whether the last estimate left this sensor out (stuck/biased, or a spike).
    noise_std : float
        Current noise standard deviation estimate of the sensor.
    """

    index: int
    reason: str
    excluded: bool
    noise_std: float


def _moments(r, w, centre):
    """Weighted geometry: ``M`` (...,3,3), weighted mean offset ``rbar`` (...,3), ``r~`` (...,N,3)."""
    wsum = w.sum(axis=-1)
    if centre == "fit":
        rbar = np.einsum("...n,...ni->...i", w, r) / wsum[..., None]
    else:
        rbar = np.zeros(r.shape[:-2] + (3,))
    rt = r - rbar[..., None, :]
    return np.einsum("...n,...ni,...nj->...ij", w, rt, rt), rbar, rt


def _solve_weighted(r, y, w, centre):
    """Weighted fit; returns g (...,3), s_c (...), M (...,3,3), rbar (...,3)."""
    m, rbar, rt = _moments(r, w, centre)
    ybar = np.einsum("...n,...n->...", w, y) / w.sum(axis=-1)
    b = np.einsum("...n,...n,...ni->...i", w, y - ybar[..., None], rt)
    g = np.linalg.solve(m, b[..., None])[..., 0]
    s_c = ybar - np.einsum("...i,...i->...", g, rbar)  # value of the fitted plane at the centre
    return g, s_c, m, rbar


def _condition(m):
    ev = np.linalg.eigvalsh(m)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ev[..., 0] > 0, ev[..., -1] / np.where(ev[..., 0] > 0, ev[..., 0], 1.0), np.inf)


def weighted_gradient(offsets, values, weights=None, centre: str = "fit",
                      max_condition: float = DEFAULT_MAX_CONDITION) -> np.ndarray:
    """Weighted Theorem-2 gradient estimate (no online state).

    Parameters
    ----------
    offsets : array_like, shape (..., N, 3)
        Reading positions relative to the formation centre (metres).
    values : array_like, shape (..., N)
        Readings.
    weights : array_like, shape (..., N), optional
        Non-negative weights (0 excludes a sensor); default all ones.
    centre : {"fit", "weighted_mean"}
        How ``s_c`` is obtained (module docstring). ``"weighted_mean"`` with equal weights is
        exactly :func:`estimator.gradient` ``(method="cvt")``.
    max_condition : float
        Largest accepted condition number of the weighted ``M``.

    Returns
    -------
    numpy.ndarray, shape (..., 3)

    Raises
    ------
    GeometryError
        Fewer than 4 sensors with positive weight, or ``cond(M) > max_condition``.
    ValueError
        Bad shapes, NaN/inf, negative weights, unknown ``centre``.
    """
    r, y, w = _check_inputs(offsets, values, weights, centre)
    if np.any(np.count_nonzero(w > 0, axis=-1) < 4):
        raise GeometryError("need at least 4 sensors with a positive weight to estimate a 3D gradient")
    cond = _condition(_moments(r, w, centre)[0])
    if np.any(~(cond <= max_condition)):
        raise GeometryError(f"weighted formation geometry is degenerate: cond(M) = {float(np.max(cond)):.3g} "
                            f"exceeds max_condition = {max_condition:.3g}")
    return _solve_weighted(r, y, w, centre)[0]


def _check_inputs(offsets, values, weights, centre):
    if centre not in CENTRE_MODES:
        raise ValueError(f"unknown centre mode {centre!r}; expected one of {', '.join(CENTRE_MODES)}")
    r = np.asarray(offsets, dtype=float)
    y = np.asarray(values, dtype=float)
    if r.ndim < 2 or r.shape[-1] != 3:
        raise ValueError(f"offsets must have shape (..., N, 3), got {r.shape}")
    if y.shape != r.shape[:-1]:
        raise ValueError(f"values must have shape {r.shape[:-1]} to match offsets {r.shape}, got {y.shape}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(y))):
        raise ValueError("offsets and values must be finite (no NaN or inf)")
    w = np.ones_like(y) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), y.shape)
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    return r, y, w


class RobustGradientEstimator:
    """Online weighted gradient estimator that finds and sidelines faulty sensors.

    Parameters
    ----------
    n : int
        Number of sensors (readings per update), >= 4.
    window : int
        Length (updates) of the sliding window, >= 5.
    batch_shape : tuple of int
        Leading shape of independent formations estimated at once (default: one formation).
    centre : {"fit", "weighted_mean"}
        How ``s_c`` is obtained (module docstring).
    min_sensors : int
        Never exclude below this many sensors (>= 4).
    warmup : int, optional
        Updates before weights are used and faults declared; default ``max(10, window // 5)``.
    var_floor_rel : float
        Variance floor as a fraction of the median variance (caps any weight at
        ``1 / var_floor_rel`` times the typical weight).
    k_mad : float
        Spike threshold in robust standard deviations.
    k_bias, bias_explained, bias_min_std : float
        Bias thresholds: standard errors of the windowed median; fraction of the sensors'
        persistent errors that one sensor's bias must explain (0..1); multiples of the sensor's
        own prediction-error std (keeps the curvature of the field across a large formation
        from looking like a bias).
    k_noisy : float
        A sensor whose noise std exceeds ``k_noisy`` times the median is reported ``noisy``.
    stuck_ratio : float
        A sensor is stuck when its reading-change energy is below this fraction of the others'.
    spike_rate : float
        Windowed fraction of rejected readings above which a sensor is reported ``spiking``.
    max_condition : float
        Largest accepted condition number of the weighted geometry.
    """

    def __init__(self, n: int, window: int = 100, batch_shape: tuple[int, ...] = (), centre: str = "fit",
                 min_sensors: int = 4, warmup: int | None = None, var_floor_rel: float = 0.25,
                 k_mad: float = 5.0, k_bias: float = 6.0, bias_explained: float = 0.6, bias_min_std: float = 1.5,
                 k_noisy: float = 2.0,
                 stuck_ratio: float = 1e-6, spike_rate: float = 0.05,
                 max_condition: float = DEFAULT_MAX_CONDITION):
        if not isinstance(n, (int, np.integer)) or n < 4:
            raise ValueError(f"n must be an integer >= 4 (a 3D gradient needs 4 sensors), got {n!r}")
        if not (isinstance(window, (int, np.integer)) and window >= 5):
            raise ValueError(f"window must be an integer >= 5 updates, got {window!r}")
        if centre not in CENTRE_MODES:
            raise ValueError(f"unknown centre mode {centre!r}; expected one of {', '.join(CENTRE_MODES)}")
        if not (isinstance(min_sensors, (int, np.integer)) and 4 <= min_sensors <= n):
            raise ValueError(f"min_sensors must be an integer in [4, n={n}], got {min_sensors!r}")
        for name, val in (("var_floor_rel", var_floor_rel), ("k_mad", k_mad), ("k_bias", k_bias),
                          ("bias_min_std", bias_min_std), ("k_noisy", k_noisy), ("stuck_ratio", stuck_ratio),
                          ("spike_rate", spike_rate), ("max_condition", max_condition)):
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a positive finite number, got {val!r}")
        self.n = int(n)
        self.batch_shape = tuple(int(b) for b in batch_shape)
        self.window = int(window)
        self.centre = centre
        self.min_sensors = int(min_sensors)
        self.warmup = int(max(10, self.window // 5) if warmup is None else warmup)
        if not 2 <= self.warmup <= self.window:
            raise ValueError(f"warmup must be in [2, window={self.window}], got {warmup!r}")
        self.var_floor_rel = float(var_floor_rel)
        self.k_mad = float(k_mad)
        self.k_bias = float(k_bias)
        if not 0.0 < bias_explained < 1.0:
            raise ValueError(f"bias_explained must be in (0, 1), got {bias_explained!r}")
        self.bias_explained = float(bias_explained)
        self.bias_min_std = float(bias_min_std)
        self.k_noisy = float(k_noisy)
        self.stuck_ratio = float(stuck_ratio)
        self.spike_rate = float(spike_rate)
        self.max_condition = float(max_condition)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything learnt (e.g. after the formation changed its members)."""
        shape = self.batch_shape + (self.n,)
        self.updates = 0
        self._var = np.zeros(shape)
        self._med_d = np.zeros(shape)
        self._d_buf = np.zeros(shape + (self.window,))
        self._p_buf = np.zeros(shape + (self.window,))
        self._diff2 = np.zeros(shape)
        self._last_y = np.zeros(shape)
        self._spike_ewma = np.zeros(shape)
        self._spike_counts = np.zeros(shape, dtype=np.int64)
        self._code = np.zeros(shape, dtype=np.int8)  # 0 ok, 1 + index in REASONS
        self._excluded = np.zeros(shape, dtype=bool)
        self._weights = np.full(shape, 1.0 / self.n)
        self._hat = np.zeros(shape + (self.n,))

    @property
    def noise_std_estimates(self) -> np.ndarray:
        """Current noise standard deviation estimate of each sensor, shape ``(*batch, N)``."""
        return np.sqrt(self._var)

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights used by the last update (0 = excluded), shape ``(*batch, N)``."""
        return self._weights.copy()

    @property
    def excluded(self) -> np.ndarray:
        """Sensors left out of the last update's fit, shape ``(*batch, N)``."""
        return self._excluded.copy()

    @property
    def spike_counts(self) -> np.ndarray:
        """Readings rejected as spikes so far, per sensor, shape ``(*batch, N)``."""
        return self._spike_counts.copy()

    @property
    def suspect_codes(self) -> np.ndarray:
        """``(*batch, N)`` int: 0 = trusted, ``k + 1`` = suspect for ``REASONS[k]``."""
        return self._code.copy()

    @property
    def suspects(self) -> list[Suspect]:
        """Suspect sensors with their reasons (single formation only; see :meth:`suspects_of`)."""
        if self.batch_shape:
            raise ValueError("suspects is for a single formation; use suspects_of(index) on a batch")
        return self.suspects_of(())

    def suspects_of(self, index) -> list[Suspect]:
        """Suspect sensors of one formation of the batch (``index`` into ``batch_shape``)."""
        code = self._code[index]
        std = np.sqrt(self._var[index])
        exc = self._excluded[index]
        return [Suspect(int(i), REASONS[code[i] - 1], bool(exc[i]), float(std[i]))
                for i in np.flatnonzero(code)]

    # ------------------------------------------------------------------ update
    def update(self, offsets, values) -> np.ndarray:
        """Add one set of readings and return the gradient estimate at the centre.

        Parameters
        ----------
        offsets : array_like, shape (*batch, N, 3)
            Where each reading was taken relative to the formation centre (metres).
        values : array_like, shape (*batch, N)
            The readings.

        Returns
        -------
        numpy.ndarray, shape (*batch, 3)

        Raises
        ------
        ValueError
            Wrong shapes or NaN/inf.
        GeometryError
            The formation itself is degenerate (``cond(M) > max_condition`` with every sensor).
        """
        r, y, _ = _check_inputs(offsets, values, None, self.centre)
        if r.shape != self.batch_shape + (self.n, 3):
            raise ValueError(f"offsets must have shape {self.batch_shape + (self.n, 3)}, got {r.shape}")
        abs_tol = 1e-9 * (1.0 + np.median(np.abs(y), axis=-1, keepdims=True))
        alpha = 1.0 / self.window
        warm = self.updates >= self.warmup
        base_w = self._base_weights(warm)
        persistent = self._excluded_persistent() if warm else np.zeros(base_w.shape, dtype=bool)
        w = self._admissible(r, base_w, persistent, self.min_sensors)
        spikes = np.zeros(w.shape, dtype=bool)
        for _ in range(self.n):
            g, s_c, m, rbar = _solve_weighted(r, y, w, self.centre)
            d, p, hat = self._deleted(r, y, w, g, s_c, m, rbar)
            if self.updates == 0:
                break
            worst = self._worst_spike(d, p, w > 0, abs_tol)
            if not np.any(worst):
                break
            # a spike is dropped only while one residual degree of freedom remains
            w2 = self._admissible(r, base_w, (w == 0) | worst, self.min_sensors + 1, fallback=w)
            if np.array_equal(w2, w):
                break
            spikes |= worst & (w2 == 0)
            w = w2
        # commit the new state only now that the update cannot fail any more
        if self.updates > 0:
            self._diff2 += alpha * ((y - self._last_y) ** 2 - self._diff2)
        self._last_y = y.copy()
        self._hat = hat
        self._learn(d, p, spikes, alpha)
        self.updates += 1
        if self.updates >= self.warmup:
            self._classify()
        self._excluded = w == 0
        self._weights = w / w.sum(axis=-1, keepdims=True)
        return g

    def _base_weights(self, warm):
        """Relative inverse-variance weights (typical sensor = 1), equal before warm-up."""
        if not warm:
            return np.ones(self.batch_shape + (self.n,))
        ref = np.median(self._var, axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = ref / np.clip(self._var, self.var_floor_rel * ref, 1e6 * ref)
        return np.where(ref > 0, w, 1.0)

    def _excluded_persistent(self):
        stuck = REASONS.index("stuck") + 1
        biased = REASONS.index("biased") + 1
        return (self._code == stuck) | (self._code == biased)

    def _admissible(self, r, base_w, drop, min_active, fallback=None):
        """Weights with ``drop`` sensors removed where that keeps ``min_active`` sensors and a
        well-conditioned geometry; otherwise ``fallback`` (default: ``base_w``, nobody
        dropped) for that formation. If the weights themselves starve the geometry, equal
        weights are used."""
        fallback = base_w if fallback is None else fallback
        w = np.where(drop, 0.0, base_w)
        ok = np.count_nonzero(w > 0, axis=-1) >= min_active
        if np.any(ok):
            m = _moments(r, np.where(ok[..., None], w, fallback), self.centre)[0]
            ok &= _condition(m) <= self.max_condition
        w = np.where(ok[..., None], w, fallback)
        if not np.all(ok):
            bad = ~(_condition(_moments(r, w, self.centre)[0]) <= self.max_condition)
            if np.any(bad):
                w = np.where(bad[..., None], 1.0, w)
                cond = _condition(_moments(r, w, self.centre)[0])
                if np.any(~(cond <= self.max_condition)):
                    raise GeometryError(
                        f"formation geometry is degenerate: cond(M) = {float(np.max(cond)):.3g} exceeds "
                        f"max_condition = {self.max_condition:.3g}")
        return w

    def _deleted(self, r, y, w, g, s_c, m, rbar):
        """Leave-one-out prediction error of each sensor, its variance, and the map from
        readings to these errors.

        ``d_i = y_i - (prediction of sensor i by the fit without it)``; for a sensor in the fit
        ``d_i = e_i / (1 - h_ii)``, for one left out ``d_i = e_i``. The prediction variance
        ``p_i = s^2 q_i / (1 - h_ii)`` (Sherman-Morrison) with ``s^2`` the median noise variance
        (the weights are relative to it). ``E[d_i^2] = var_i + p_i`` does not depend on sensor
        i's own weight: no feedback. ``d = D^-1 (I - H) y`` with ``H`` the hat matrix and
        ``D = diag(1 - h)``; that matrix is returned for the bias test. A sensor whose
        prediction is undetermined (``h_ii = 1``) gets ``d = nan``.
        """
        e = y - s_c[..., None] - np.einsum("...ni,...i->...n", r, g)
        wsum = w.sum(axis=-1, keepdims=True)
        rt = r - rbar[..., None, :]
        minv = np.linalg.inv(m)
        kern = 1.0 / wsum[..., None] + np.einsum("...ai,...ij,...bj->...ab", rt, minv, rt)  # (...,N,N)
        hat = kern * w[..., None, :]  # H[j, i] = w_i (1/W + rt_j M^-1 rt_i)
        q = np.diagonal(kern, axis1=-2, axis2=-1)
        h = np.where(w > 0, w * q, 0.0)
        one_minus_h = 1.0 - h
        free = one_minus_h > 1e-6
        omh = np.where(free, one_minus_h, 1.0)
        d = np.where(free, e / omh, np.nan)
        s2 = np.median(self._var, axis=-1, keepdims=True)
        loo = (np.eye(self.n) - hat) / omh[..., :, None]
        return d, np.where(free, s2 * q / omh, 0.0), loo

    def _filled(self):
        return min(self.updates, self.window)

    def _worst_spike(self, d, p, active, abs_tol):
        """Per formation, the active sensor farthest beyond ``k_mad`` robust deviations (if any)."""
        valid = active & np.isfinite(d)
        if self.updates < self.warmup:
            # too little history: compare with the other sensors' prediction errors
            da = np.where(valid, d, np.nan)
            med = np.nanmedian(da, axis=-1, keepdims=True)
            mad = np.nanmedian(np.abs(da - med), axis=-1, keepdims=True)
            scale = np.maximum(_MAD_TO_STD * mad, np.sqrt(np.median(self._var, axis=-1, keepdims=True) + p))
        else:
            med = self._med_d
            scale = np.sqrt(self._var + p)
        dev = np.abs(np.where(valid, d, 0.0) - med)
        score = np.where(valid & (dev > abs_tol), dev / np.maximum(scale, np.finfo(float).tiny), 0.0)
        worst = np.argmax(score, axis=-1)
        mask = np.zeros(d.shape, dtype=bool)
        np.put_along_axis(mask, worst[..., None], True, axis=-1)
        return mask & (score > self.k_mad)

    def _learn(self, d, p, spikes, alpha):
        slot = self.updates % self.window
        k = min(self.updates + 1, self.window)
        prev = self._d_buf[..., (slot - 1) % self.window] if self.updates else np.zeros_like(d)
        self._d_buf[..., slot] = np.where(np.isfinite(d), d, prev)  # undetermined: repeat
        self._p_buf[..., slot] = p
        buf = self._d_buf[..., :k]
        pbar = self._p_buf[..., :k].mean(axis=-1)
        if self.updates + 1 < self.warmup:
            # short history: one pooled variance over sensors and updates (median of chi2(1) = 0.4549)
            pooled = np.median((buf**2).reshape(buf.shape[:-2] + (-1,)), axis=-1) / 0.4549
            total = np.broadcast_to(pooled[..., None], d.shape)
            self._med_d = np.zeros(d.shape)
        else:
            self._med_d = np.median(buf, axis=-1)
            dev = np.abs(buf - self._med_d[..., None])
            scale = _MAD_TO_STD * np.median(dev, axis=-1, keepdims=True)
            # winsorised at 3 robust std: efficient like a mean square, robust like the MAD
            total = np.mean(np.minimum(dev, 3.0 * scale) ** 2, axis=-1) / _WINSOR3
        self._var = np.maximum(total - pbar, 0.05 * total)
        self._spike_ewma += alpha * (spikes - self._spike_ewma)
        self._spike_counts += spikes

    def _classify(self):
        code = np.zeros(self._code.shape, dtype=np.int8)
        n = self.n
        k = self._filled()
        # stuck: readings stop changing while the others' change
        d2 = self._diff2
        others = np.stack([np.median(np.delete(d2, i, axis=-1), axis=-1) for i in range(n)], axis=-1)
        stuck = (d2 <= self.stuck_ratio * others) & (others > 0)
        biased = self._biased(k)
        spiking = self._spike_ewma > self.spike_rate
        med_std = np.sqrt(np.median(self._var, axis=-1, keepdims=True))
        noisy = np.sqrt(self._var) > self.k_noisy * med_std
        for j, mask in reversed(list(enumerate((stuck, biased, spiking, noisy)))):
            code = np.where(mask, np.int8(j + 1), code)
        self._code = code

    def _biased(self, k):
        """One sensor whose bias explains the persistent prediction errors of all of them.

        A bias ``b`` on sensor i shifts the prediction errors by ``b * c_i`` with ``c_i`` the
        i-th column of the leave-one-out map (it leaks into the other sensors' predictions).
        For each candidate, ``b_i`` is the weighted least-squares fit of the windowed median
        errors by ``c_i``; the best candidate is biased if it explains at least
        ``bias_explained`` of their weighted energy and ``|b_i|`` exceeds ``k_bias``
        standard errors and ``bias_min_std`` standard deviations. A sensor already excluded as
        biased stays so while its own median error stays significant.
        """
        std_d = np.sqrt(self._var + self._p_buf[..., :k].mean(axis=-1))
        se = 1.2533 * std_d / np.sqrt(k)
        med = self._med_d
        inv_var = 1.0 / np.maximum(std_d**2, np.finfo(float).tiny)
        cols = self._hat  # loo[..., j, i]: effect on d_j of reading i
        num = np.einsum("...j,...j,...ji->...i", inv_var, med, cols)
        den = np.einsum("...j,...ji,...ji->...i", inv_var, cols, cols)
        b = num / np.maximum(den, np.finfo(float).tiny)
        energy = np.einsum("...j,...j->...", inv_var, med**2)[..., None]
        explained = b**2 * den / np.maximum(energy, np.finfo(float).tiny)
        significant = (np.abs(b) > self.k_bias * se) & (np.abs(b) > self.bias_min_std * std_d)
        score = np.where(significant, explained, 0.0)
        best = np.argmax(score, axis=-1)
        mask = np.zeros(med.shape, dtype=bool)
        np.put_along_axis(mask, best[..., None], True, axis=-1)
        new = mask & (score >= self.bias_explained)
        stay = (self._code == REASONS.index("biased") + 1) & (np.abs(med) > self.k_bias * se) \
            & (np.abs(med) > self.bias_min_std * std_d)
        return new | stay
