"""Is there a signal? A detection threshold relative to the readings' own noise floor (pure numpy).

A seeker on a plume, and the convergence test, must tell "the formation reads the source's
signal" from "the formation reads background": between the puffs of an intermittent plume, or
off a narrow steady plume, every reading is the background plus noise, the estimated gradient
is noise, the centre hardly moves, and a test of the centre's motion alone takes standing still
for arrival.

:class:`SignalFloor` keeps the last ``history`` iterations' readings of each of ``K`` trials and
estimates the **floor** from their low quantiles, as if the lowest readings were background plus
Gaussian noise ``N(b, sigma^2)``: with ``q05`` and ``q25`` the 5th and 25th percentiles,
``sigma = (q25 - q05) / 0.9763`` and ``b = q25 + 0.6745 sigma`` (the quantiles of a normal law).
A reading is a **detection** when it exceeds

    threshold = b + max(sigmas * sigma, rel_peak * (peak - b))

with ``peak`` the highest reading in the history: noise-relative (``sigmas``, default 3), and
relative to the strongest signal seen (``rel_peak``, default 0.02) so that without noise the
plume's far Gaussian tails (1e-10 above the background) do not count. An iteration has a
signal when at least one reading is a detection.

This holds when at least a quarter of the history's readings are background (a plume narrower
than the formation, or the approach from outside it). When every reading is signal (a smooth
field read from one place only), ``q05``-``q25`` measure the field's variation across the
formation, the threshold is near the top of the readings and an iteration may count as "no
signal" although it has one: the convergence test then waits (it never ends a run early).
"""
from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["SignalFloor", "ArrivalSignal"]

_Z05, _Z25 = 1.6449, 0.6745



def _readings(values) -> tuple[np.ndarray, bool]:
    """``values`` as ``(K, N)`` floats and whether they came as one trial's ``(N,)``.

    Raises
    ------
    ValueError
        Not 1-D/2-D, empty, or not finite.
    """
    v = np.asarray(values, dtype=float)
    one = v.ndim == 1
    v = v[None] if one else v
    if v.ndim != 2 or v.shape[1] == 0 or not np.all(np.isfinite(v)):
        raise ValueError(f"values must be finite readings of shape (K, N) or (N,), got shape {np.shape(values)}")
    return v, one

class SignalFloor:
    """Background, noise and detections of ``K`` trials' readings (module docstring).

    Parameters
    ----------
    sigmas : float
        Detection threshold above the background, in noise standard deviations (> 0).
    rel_peak : float
        ... and at least this fraction of (peak - background), in [0, 1).
    history : int
        Iterations of readings kept (>= 1).
    """

    def __init__(self, sigmas: float = 3.0, rel_peak: float = 0.02, history: int = 40):
        if not (np.isfinite(sigmas) and sigmas >= 0):
            raise ValueError(f"sigmas must be a finite number >= 0, got {sigmas!r}")
        if not (np.isfinite(rel_peak) and 0 <= rel_peak < 1):
            raise ValueError(f"rel_peak must be in [0, 1), got {rel_peak!r}")
        if int(history) != history or history < 1:
            raise ValueError(f"history must be an integer >= 1, got {history!r}")
        self.sigmas, self.rel_peak, self.history = float(sigmas), float(rel_peak), int(history)
        self.reset()

    def reset(self) -> None:
        """Forget every reading."""
        self._buf: deque = deque(maxlen=self.history)
        self.background = self.noise_std = self.threshold = None

    def update(self, values) -> np.ndarray:
        """Add one iteration's readings ``(K, N)`` (or ``(N,)``: K = 1); the detections, same shape.

        Raises
        ------
        ValueError
            Not 1-D/2-D, empty, or not finite.
        """
        v, one = _readings(values)
        if self._buf and self._buf[-1].shape[0] != v.shape[0]:
            self.reset()
        self._buf.append(v)
        allv = np.concatenate(list(self._buf), axis=1)
        q05, q25 = np.percentile(allv, [5.0, 25.0], axis=1)
        sigma = np.maximum(q25 - q05, 0.0) / (_Z05 - _Z25)
        b = q25 + _Z25 * sigma
        peak = allv.max(axis=1)
        thr = b + np.maximum(self.sigmas * sigma, self.rel_peak * np.maximum(peak - b, 0.0))
        self.background, self.noise_std, self.threshold = b, sigma, thr
        det = v > thr[:, None]
        return det[0] if one else det

    def signal(self, values) -> np.ndarray:
        """:meth:`update` and whether each trial's iteration has a detection, ``(K,)`` (a bool for ``(N,)``)."""
        det = self.update(values)
        return bool(det.any()) if det.ndim == 1 else det.any(axis=1)


class ArrivalSignal:
    """Whether an iteration's readings look like arrival at a source rather than background.

    The statistic is the iteration's **mean** reading ``m`` (over the formation's vehicles);
    with ``b`` and ``P`` the lowest and highest ``m`` seen so far in the run, the iteration
    has a signal when ``m >= b + rel_range * (P - b)``. At a smooth field's maximum every
    vehicle reads near the highest level seen (``m`` near ``P``); standing still in a patchy
    plume, most iterations read the background between puffs (``m`` near ``b``), and a puff on
    one or two vehicles lifts the mean much less than the whole formation in the plume.
    The convergence test (:class:`estimator.seeking.ConvergenceMonitor`, criterion 3) asks for
    a signal in a fraction of its window.

    Parameters
    ----------
    rel_range : float
        In (0, 1): the fraction of the range of means seen above which an iteration counts.
    """

    def __init__(self, rel_range: float = 0.5):
        if not (np.isfinite(rel_range) and 0 < rel_range < 1):
            raise ValueError(f"rel_range must be in (0, 1), got {rel_range!r}")
        self.rel_range = float(rel_range)
        self.reset()

    def reset(self) -> None:
        """Forget the range seen."""
        self.low = self.high = None

    def signal(self, values) -> np.ndarray:
        """Add one iteration's readings ``(K, N)`` (or ``(N,)``); whether each has a signal, ``(K,)`` (or a bool).

        Raises
        ------
        ValueError
            Not 1-D/2-D, empty, or not finite.
        """
        v, one = _readings(values)
        m = v.mean(axis=1)
        if self.low is None or self.low.shape != m.shape:
            self.low, self.high = m.copy(), m.copy()
        self.low, self.high = np.minimum(self.low, m), np.maximum(self.high, m)
        out = m >= self.low + self.rel_range * (self.high - self.low)
        return bool(out[0]) if one else out
