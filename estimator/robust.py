"""Robust gradient estimation for a formation with faulty sensors (pure numpy, no I/O).

Theorem 2 generalised to weighted least squares: for offsets ``r_i = p_i - c``, readings
``y_i`` and weights ``w_i``, ``g = (sum w_i r~_i r~_i^T)^-1 sum w_i (y_i - s_c) r~_i``.

* ``centre="fit"`` (default): ``s_c`` and ``g`` are the joint weighted least-squares fit of
  ``y_i = s_c + g . r_i`` (``r~_i = r_i - rbar_w``): exact on a linear field for any weights
  and any subset of >= 4 non-coplanar sensors, so dropping a faulty sensor adds no bias.
* ``centre="weighted_mean"``: ``r~_i = r_i``, ``s_c = sum w_i y_i / sum w_i``; with equal
  weights exactly :func:`estimator.gradient` ``(method="cvt")`` (Theorem 2 with the Remark).

Online, per sensor, over a sliding window of ``window`` updates, from the leave-one-out
prediction errors ``d_i`` (reading minus the prediction of the fit of the *other* sensors,
``E[d_i^2] = var_i + p_i``, no feedback from a sensor's weight to its own variance):

* noise variance: winsorised mean square of ``d_i`` about its median minus the prediction
  variance, shrunk towards the median sensor; weights ``1 / var_i`` (floored);
* spiking: a reading more than ``k_mad`` robust std from its sensor's median is left out of
  that update (worst first) and counted;
* stuck: readings stop changing while the others' change;
* biased: the windowed median errors of all sensors are explained by a bias on one sensor
  leaking through the known leave-one-out map, and what it leaves unexplained is noise (or small
  next to it), not structure such as the field's curvature across the formation;
* noisy: ``std_i > k_noisy * median(std)`` (reported; handled by the weights).

Stuck and biased sensors are excluded while at least ``min_sensors`` remain with a
well-conditioned geometry. Unequal weights break the formation's symmetry, and the field's
curvature across the formation then biases the estimate: ``weighting="auto"`` predicts that
bias from the persistent residuals and keeps equal weights when it would cost more than the
noise saved. The details and the measured effects are in ``docs/safety.md``.

The estimator is vectorised over a leading batch of independent formations (``batch_shape``),
which the offline Monte Carlo uses; a mission uses the default ``()``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.gradient import DEFAULT_MAX_CONDITION, GeometryError
from estimator.robust_wls import (
    CENTRE_MODES,
    _argmax_mask,
    _check_inputs,
    _condition,
    _moments,
    _solve_weighted,
    weighted_gradient,
)

__all__ = [
    "CENTRE_MODES",
    "WEIGHTINGS",
    "REASONS",
    "Suspect",
    "RobustGradientEstimator",
    "weighted_gradient",
]

#: how the weights are chosen (see RobustGradientEstimator)
WEIGHTINGS = ("auto", "inverse_variance", "equal")
#: exponents ``a`` of the weights ``var^-a`` that ``weighting="auto"`` chooses from
_AUTO_EXPONENTS = (0.0, 0.5, 1.0)
#: suspect reasons, in order of precedence (a sensor is reported once, for the first that applies)
REASONS = ("stuck", "biased", "spiking", "noisy")
_MAD_TO_STD = 1.4826
#: the curvature residual kappa is averaged over this many windows
_KAPPA_WINDOWS = 4
#: |b|^2 must exceed this many times its noise-only expectation to count as a curvature bias
_BIAS_SIGNIFICANCE = 9.0
#: a bias is also accepted when what it leaves unexplained is below this fraction of it
_BIAS_DOMINANCE = 0.15
#: strength (in updates) of the shrinkage of each sensor's variance towards the median
_PRIOR_UPDATES = 25
#: E[min(X^2, 9)] for a standard normal X (winsorising at 3 standard deviations)
_WINSOR3 = 0.99734


@dataclass(frozen=True)
class Suspect:
    """A sensor the estimator distrusts: 0-based ``index`` in the order of the readings,
    ``reason`` (one of :data:`REASONS`), whether the last estimate ``excluded`` it, and its
    current ``noise_std`` estimate."""

    index: int
    reason: str
    excluded: bool
    noise_std: float


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
    weighting : {"auto", "inverse_variance", "equal"}
        ``inverse_variance``: ``w_i = 1 / var_i``, best when the field is nearly linear across
        the formation. ``equal``: only outliers (stuck, biased, spikes) are removed; noisy
        sensors are reported but keep their weight. ``auto``: per update, the weights
        ``var_i^-a`` for ``a`` in 0, 0.5, 1 with the smallest predicted error (see
        :attr:`weighting_exponent`): unequal weights break the formation's symmetry, and the
        field's curvature across the formation then biases the estimate, which hurts a seeking
        loop far more than noise does.
    bias_gain : float
        How much more a persistent gradient bias costs than white noise of the same variance
        (for the ``auto`` weighting). For gradient ascent with step ``eps`` near a source
        whose slowest curvature is ``lambda`` (``A * S`` eigenvalue), about ``1 / (eps lambda)``:
        670 for the paper's sigma_2 and ``eps = 1``.
    stuck_ratio : float
        A sensor is stuck when its reading-change energy is below this fraction of the others'.
    spike_rate : float
        Windowed fraction of rejected readings above which a sensor is reported ``spiking``.
    max_condition : float
        Largest accepted condition number of the weighted geometry.
    """

    def __init__(self, n: int, window: int = 100, batch_shape: tuple[int, ...] = (), centre: str = "fit",
                 min_sensors: int = 4, warmup: int | None = None, var_floor_rel: float = 0.25,
                 k_mad: float = 5.0, k_bias: float = 6.0, bias_explained: float = 0.85, bias_min_std: float = 1.5,
                 k_noisy: float = 2.0, stuck_ratio: float = 1e-6, spike_rate: float = 0.02,
                 max_condition: float = DEFAULT_MAX_CONDITION, weighting: str = "auto",
                 bias_gain: float = 500.0):
        if not isinstance(n, (int, np.integer)) or n < 4:
            raise ValueError(f"n must be an integer >= 4 (a 3D gradient needs 4 sensors), got {n!r}")
        if not (isinstance(window, (int, np.integer)) and window >= 5):
            raise ValueError(f"window must be an integer >= 5 updates, got {window!r}")
        if not (isinstance(min_sensors, (int, np.integer)) and 4 <= min_sensors <= n):
            raise ValueError(f"min_sensors must be an integer in [4, n={n}], got {min_sensors!r}")
        for name, val, choices in (("centre", centre, CENTRE_MODES), ("weighting", weighting, WEIGHTINGS)):
            if val not in choices:
                raise ValueError(f"unknown {name} mode {val!r}; expected one of {', '.join(choices)}")
        for name, val in (("var_floor_rel", var_floor_rel), ("k_mad", k_mad), ("k_bias", k_bias),
                          ("bias_min_std", bias_min_std), ("k_noisy", k_noisy), ("stuck_ratio", stuck_ratio),
                          ("spike_rate", spike_rate), ("max_condition", max_condition)):
            if not (np.isfinite(val) and val > 0):
                raise ValueError(f"{name} must be a positive finite number, got {val!r}")
        if not 0.0 < bias_explained < 1.0:
            raise ValueError(f"bias_explained must be in (0, 1), got {bias_explained!r}")
        if not (np.isfinite(bias_gain) and bias_gain >= 0):
            raise ValueError(f"bias_gain must be a finite number >= 0, got {bias_gain!r}")
        self.n = int(n)
        self.batch_shape = tuple(int(b) for b in batch_shape)
        self.window = int(window)
        self.centre = centre
        self.min_sensors = int(min_sensors)
        self.warmup = int(max(10, self.window // 5) if warmup is None else warmup)
        if not 2 <= self.warmup <= self.window:
            raise ValueError(f"warmup must be in [2, window={self.window}], got {warmup!r}")
        thresholds = dict(var_floor_rel=var_floor_rel, k_mad=k_mad, k_bias=k_bias, bias_explained=bias_explained,
                          bias_min_std=bias_min_std, k_noisy=k_noisy, stuck_ratio=stuck_ratio,
                          spike_rate=spike_rate, max_condition=max_condition, bias_gain=bias_gain)
        for name, val in thresholds.items():
            setattr(self, name, float(val))
        self.weighting = weighting
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
        self._kappa = np.zeros(shape)
        self._alpha_used = np.zeros(self.batch_shape)

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
        persistent = warm & np.isin(self._code, (REASONS.index("stuck") + 1, REASONS.index("biased") + 1))
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
        if self.weighting != "inverse_variance" and warm:
            w, g = self._choose_weights(r, y, w)
        else:
            self._alpha_used = np.full(self.batch_shape, 1.0 if warm else 0.0)
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

    def _operator(self, r, w):
        """Gradient rows of the weighted fit: ``g = G y``, shape (..., 3, N)."""
        m, rbar, _ = _moments(r, w, self.centre)
        rbar_w = np.einsum("...n,...ni->...i", w, r) / w.sum(axis=-1)[..., None]
        return np.einsum("...ij,...nj->...in", np.linalg.inv(m), w[..., None] * (r - rbar_w[..., None, :]))

    def _choose_weights(self, r, y, w):
        """Equal weights on the sensors in the fit, or ``var^-a``: the smallest predicted error.

        ``kappa`` is the persistent residual of the equal-weight fit (the part of the field the
        linear model misses: curvature). Weights ``w`` move the estimate by ``b = G_w kappa``
        (a bias) and change its noise variance ``v_w = sum_i |G_w[:, i]|^2 var_i``. Predicted
        error: ``v_w + bias_gain * max(0, |b|^2 - 9 var(b))`` where ``var(b)`` is the part of
        ``|b|^2`` due to the noise in ``kappa`` itself (an exponential mean over
        ``4 * window`` updates).
        """
        active = w > 0
        w_eq = active.astype(float)
        g_eq_op = self._operator(r, w_eq)
        # residual of the equal-weight fit (intercept included)
        g_eq, s_eq, _, _ = _solve_weighted(r, y, w_eq, self.centre)
        e_eq = y - s_eq[..., None] - np.einsum("...ni,...i->...n", r, g_eq)
        alpha_k = 1.0 / (_KAPPA_WINDOWS * self.window)
        self._kappa = np.where(active, self._kappa + alpha_k * (e_eq - self._kappa), self._kappa)
        if self.weighting == "equal":
            self._alpha_used = np.zeros(self.batch_shape)
            return w_eq, g_eq
        var = self._var
        n_eff = (2.0 - alpha_k) / alpha_k
        best_w, best_g = w_eq, g_eq
        best_cost = np.einsum("...in,...n->...", g_eq_op**2, var)
        best_a = np.zeros(self.batch_shape)
        for a in _AUTO_EXPONENTS[1:]:
            w_a = np.where(active, w ** a, 0.0)
            op = self._operator(r, w_a)
            b = np.einsum("...in,...n->...i", op, np.where(active, self._kappa, 0.0))
            var_b = np.einsum("...in,...n->...", (op - g_eq_op) ** 2, var) / n_eff
            cost = np.einsum("...in,...n->...", op**2, var) + self.bias_gain * np.maximum(
                0.0, np.einsum("...i,...i->...", b, b) - _BIAS_SIGNIFICANCE * var_b)
            better = cost < best_cost
            if np.any(better):
                g_a = np.einsum("...in,...n->...i", op, y)
                best_w = np.where(better[..., None], w_a, best_w)
                best_g = np.where(better[..., None], g_a, best_g)
                best_cost = np.where(better, cost, best_cost)
                best_a = np.where(better, a, best_a)
        self._alpha_used = best_a
        return best_w, best_g

    @property
    def weighting_exponent(self) -> np.ndarray:
        """Exponent ``a`` of the weights ``var^-a`` used by the last update (0 = equal)."""
        return self._alpha_used.copy()

    def _base_weights(self, warm):
        """Relative inverse-variance weights (typical sensor = 1), equal before warm-up."""
        if not warm:
            return np.ones(self.batch_shape + (self.n,))
        ref = np.median(self._var, axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = ref / np.clip(self._var, self.var_floor_rel * ref, 1e6 * ref)
        return np.where(ref > 0, w, 1.0)

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
        """Leave-one-out errors ``d = D^-1 (I - H) y`` (``H`` hat matrix, ``D = diag(1 - h)``; a
        sensor out of the fit has ``d_i = e_i``; ``nan`` if undetermined), their prediction
        variances ``p_i = s^2 q_i / (1 - h_ii)`` (Sherman-Morrison, ``s^2`` the median
        variance) and the map ``D^-1 (I - H)`` (for the bias test)."""
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
        return _argmax_mask(score) & (score > self.k_mad)

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
        raw = np.maximum(total - pbar, 0.05 * total)
        # shrink towards the median sensor (as if it had _PRIOR_UPDATES extra readings): a 5x
        # sensor stays ~5x, while chance differences between healthy sensors shrink
        med = np.median(raw, axis=-1, keepdims=True)
        self._var = (k * raw + _PRIOR_UPDATES * med) / (k + _PRIOR_UPDATES)
        self._spike_ewma += alpha * (spikes - self._spike_ewma)
        self._spike_counts += spikes

    def _classify(self):
        code = np.zeros(self._code.shape, dtype=np.int8)
        n = self.n
        k = min(self.updates, self.window)
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
        """A bias ``b_i`` on sensor i moves the median errors by ``b_i c_i`` (``c_i``: column i
        of the leave-one-out map). Best candidate: the largest explained fraction of their
        weighted energy (>= ``bias_explained``) with ``|b_i|`` significant; a sensor already
        excluded as biased stays so while its own median error stays significant."""
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
        # what one bias leaves unexplained must be noise, or small next to the bias: not
        # structure of its own size (strong curvature across the formation looks like that)
        remainder = np.abs(med[..., :, None] - cols * b[..., None, :])  # [..., j, i]: without bias i
        clean = (np.max(remainder / np.maximum(se, 1e-300)[..., :, None], axis=-2) <= self.k_bias) \
            | (np.max(remainder, axis=-2) <= _BIAS_DOMINANCE * np.abs(b))
        score = np.where(significant & clean, explained, 0.0)
        new = _argmax_mask(score) & (score >= self.bias_explained)
        stay = (self._code == REASONS.index("biased") + 1) & (np.abs(med) > self.k_bias * se) \
            & (np.abs(med) > self.bias_min_std * std_d)
        # one biased sensor at a time: the one already excluded, else the new best candidate
        return np.where(np.any(stay, axis=-1, keepdims=True), stay & _argmax_mask(np.where(stay, np.abs(med), -1.0)),
                        new)
