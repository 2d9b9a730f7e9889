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

The weighted least squares are in :mod:`estimator.robust_wls`, the choice of the weights in
:mod:`estimator.robust_weights` and the fault tests in :mod:`estimator.robust_faults`; their
public names are imported from there.
"""
from __future__ import annotations

import numpy as np

from estimator.gradient import DEFAULT_MAX_CONDITION
from estimator.robust_faults import (
    MAD_TO_STD,
    REASONS,
    Suspect,
    biased_mask,
    stuck_mask,
    suspect_codes,
    worst_spike,
)
from estimator.robust_weights import (
    WEIGHTINGS,
    admissible_weights,
    base_weights,
    choose_weights,
)
from estimator.robust_wls import CENTRE_MODES, _check_inputs, _solve_weighted

__all__ = ["RobustGradientEstimator"]

#: strength (in updates) of the shrinkage of each sensor's variance towards the median
_PRIOR_UPDATES = 25
#: E[min(X^2, 9)] for a standard normal X (winsorising at 3 standard deviations)
_WINSOR3 = 0.99734


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
        base_w = base_weights(self._var, self.var_floor_rel, warm)
        persistent = warm & np.isin(self._code, (REASONS.index("stuck") + 1, REASONS.index("biased") + 1))
        w = admissible_weights(r, base_w, persistent, self.min_sensors, self.centre, self.max_condition)
        w, g, d, p, hat, spikes = self._reject_spikes(r, y, w, base_w, abs_tol, warm)
        if self.weighting != "inverse_variance" and warm:
            w, g, self._kappa, self._alpha_used = choose_weights(
                r, y, w, self._kappa, self._var, self.centre, self.weighting, self.window, self.bias_gain)
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

    def _reject_spikes(self, r, y, w, base_w, abs_tol, warm):
        """Fit, and drop the worst spike (one per formation) and fit again until none is left.

        Returns the weights, the gradient, the leave-one-out errors, their prediction
        variances and map of the last fit (see :meth:`_deleted`), and the dropped spikes.
        """
        spikes = np.zeros(w.shape, dtype=bool)
        for _ in range(self.n):
            g, s_c, m, rbar = _solve_weighted(r, y, w, self.centre)
            d, p, hat = self._deleted(r, y, w, g, s_c, m, rbar)
            if self.updates == 0:
                break
            worst = worst_spike(d, p, w > 0, abs_tol, self._var, self._med_d, self.k_mad, warm)
            if not np.any(worst):
                break
            # a spike is dropped only while one residual degree of freedom remains
            w2 = admissible_weights(r, base_w, (w == 0) | worst, self.min_sensors + 1, self.centre,
                                    self.max_condition, fallback=w)
            if np.array_equal(w2, w):
                break
            spikes |= worst & (w2 == 0)
            w = w2
        return w, g, d, p, hat, spikes

    @property
    def weighting_exponent(self) -> np.ndarray:
        """Exponent ``a`` of the weights ``var^-a`` used by the last update (0 = equal)."""
        return self._alpha_used.copy()

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
            scale = MAD_TO_STD * np.median(dev, axis=-1, keepdims=True)
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
        """Suspect codes from the statistics of the window (see :mod:`estimator.robust_faults`)."""
        k = min(self.updates, self.window)
        stuck = stuck_mask(self._diff2, self.stuck_ratio)
        biased = biased_mask(self._var, self._p_buf[..., :k].mean(axis=-1), self._med_d, self._hat,
                             self._code, k, self.k_bias, self.bias_min_std, self.bias_explained)
        spiking = self._spike_ewma > self.spike_rate
        med_std = np.sqrt(np.median(self._var, axis=-1, keepdims=True))
        noisy = np.sqrt(self._var) > self.k_noisy * med_std
        self._code = suspect_codes(stuck, biased, spiking, noisy)
