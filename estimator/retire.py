"""When a faulty sensor should leave the formation (pure numpy, no I/O).

The robust estimator (:class:`estimator.robust.RobustGradientEstimator`) names suspect sensors
and down-weights or excludes them, but the formation keeps its shape: a sensor that no longer
counts leaves a hole in it, and the others see less in that direction (and the field's
curvature across the now lopsided formation biases the estimate). With one sensor at 5x the
noise of the others, that costs +14 % on the final error of an 8-robot CVT formation, where a
7-robot CVT formation costs only +6 % (``benchmarks/bench_faulty_sensor.py``).

:class:`SensorRetirement` is the rule that turns a persistent suspect into a *retired* sensor:
named for one of ``reasons`` at ``after_updates`` consecutive updates, and only while at least
``min_sensors`` would remain. The caller then re-forms the formation without it (the mission
parks the vehicle at the formation centre, :mod:`mission.flight.faults.retire`) and starts a fresh estimator
and a fresh rule for the others. By default only ``stuck`` and ``noisy`` (at ``min_noise_ratio``
times the median noise or more) retire a sensor:

* ``spiking``: each spike is already left out of its update; the sensor is otherwise as good
  as any;
* ``biased``: with 8 or fewer sensors a bias on one sensor cannot be told from the field's
  curvature across a rigid formation (the residual space has N - 4 dimensions, the curvature 5
  parameters); where the curvature is much larger than the noise (D = 4 m, noise 0.01 on
  sigma_2) the robust estimator names healthy sensors ``biased``, and retiring them would shrink
  the formation one healthy vehicle at a time. A biased sensor is still excluded by the
  estimator; ``reasons`` can add ``biased`` where the curvature is known to be small.

Vectorised over a leading batch of independent formations (``batch_shape``), as the robust
estimator, for the offline Monte Carlo.
"""
from __future__ import annotations

import numpy as np

from estimator.robust_faults import REASONS

__all__ = ["RETIRE_REASONS", "SensorRetirement"]

#: the suspect reasons that retire a sensor by default
RETIRE_REASONS = ("stuck", "noisy")


class SensorRetirement:
    """Decide which suspect sensor, if any, leaves the formation now.

    Parameters
    ----------
    n : int
        Number of sensors of the formation (>= 4).
    after_updates : int
        A sensor is retired once it has been named, for one of ``reasons``, at this many
        consecutive updates (default 20: a 5x-noisy sensor leaves at about update 56, a stuck
        one at about 40; see ``docs/safety.md``).
    reasons : sequence of str
        Suspect reasons that count (a subset of :data:`estimator.robust.REASONS`).
    min_sensors : int
        Never retire when fewer than this many sensors would remain (>= 4).
    batch_shape : tuple of int
        Leading batch shape of independent formations.
    min_noise_ratio : float
        A ``noisy`` sensor counts only while its estimated noise std is at least this many times
        the median sensor's (default 3; the estimator names ``noisy`` from 2x). Where the field's
        curvature across the formation is much larger than the noise (D = 4 m, noise 0.01 on
        sigma_2), the residual-based noise estimates of healthy sensors reach 2-3x; see
        ``docs/safety.md``.

    Raises
    ------
    ValueError
        On a bad argument (the message names it).

    Examples
    --------
    >>> rule = SensorRetirement(8, after_updates=2)
    >>> codes = np.zeros(8, dtype=np.int8); codes[3] = 4  # sensor 3 named "noisy"
    >>> int(rule.update(codes)), int(rule.update(codes))
    (-1, 3)
    """

    def __init__(self, n: int, after_updates: int = 20, reasons=RETIRE_REASONS, min_sensors: int = 4,
                 batch_shape: tuple[int, ...] = (), min_noise_ratio: float = 3.0):
        if not (isinstance(n, (int, np.integer)) and n >= 4):
            raise ValueError(f"n must be an integer >= 4, got {n!r}")
        if not (isinstance(after_updates, (int, np.integer)) and after_updates >= 1):
            raise ValueError(f"after_updates must be an integer >= 1, got {after_updates!r}")
        if not (isinstance(min_sensors, (int, np.integer)) and min_sensors >= 4):
            raise ValueError(f"min_sensors must be an integer >= 4, got {min_sensors!r}")
        if not (np.isfinite(min_noise_ratio) and min_noise_ratio >= 1.0):
            raise ValueError(f"min_noise_ratio must be a finite number >= 1, got {min_noise_ratio!r}")
        if isinstance(reasons, str):
            reasons = (reasons,)
        unknown = [r for r in reasons if r not in REASONS]
        if unknown:
            raise ValueError(f"unknown suspect reason(s) {unknown}; known: {', '.join(REASONS)}")
        self.n = int(n)
        self.after_updates = int(after_updates)
        self.reasons = tuple(reasons)
        self.min_sensors = int(min_sensors)
        self.min_noise_ratio = float(min_noise_ratio)
        self.batch_shape = tuple(int(b) for b in batch_shape)
        self._codes = np.array([REASONS.index(r) + 1 for r in self.reasons], dtype=np.int8)
        self._streak = np.zeros(self.batch_shape + (self.n,), dtype=np.int64)

    @property
    def streaks(self) -> np.ndarray:
        """Consecutive updates each sensor has been named for a retiring reason, ``(*batch, N)``."""
        return self._streak.copy()

    def update(self, codes, noise_std=None) -> np.ndarray:
        """Feed one update's suspect codes; the sensor to retire now per formation, or -1.

        Parameters
        ----------
        codes : array_like of int, shape ``(*batch_shape, N)``
            :attr:`estimator.robust.RobustGradientEstimator.suspect_codes` (0 = not suspect,
            ``1 + REASONS.index(reason)`` otherwise).
        noise_std : array_like of float, shape ``(*batch_shape, N)``, optional
            :attr:`estimator.robust.RobustGradientEstimator.noise_std_estimates`; with it a
            ``noisy`` sensor counts only at ``min_noise_ratio`` times the median std or more.

        Returns
        -------
        numpy.ndarray of int, shape ``batch_shape``
            Index of the sensor to retire (the one named longest; the lowest index on a tie),
            or -1. A returned sensor's streak restarts from 0 (the caller normally starts a
            fresh rule for the remaining sensors).

        Raises
        ------
        ValueError
            ``codes`` of the wrong shape.
        """
        c = np.asarray(codes)
        if c.shape != self._streak.shape:
            raise ValueError(f"codes must have shape {self._streak.shape}, got {c.shape}")
        named = np.isin(c, self._codes)
        if noise_std is not None:
            std = np.asarray(noise_std, dtype=float)
            if std.shape != c.shape:
                raise ValueError(f"noise_std must have shape {c.shape}, got {std.shape}")
            med = np.median(std, axis=-1, keepdims=True)
            weak = (c == REASONS.index("noisy") + 1) & ~(std >= self.min_noise_ratio * med)
            named &= ~weak
        self._streak = np.where(named, self._streak + 1, 0)
        if self.n - 1 < self.min_sensors:
            return np.full(self.batch_shape, -1, dtype=np.int64)
        ready = np.where(self._streak >= self.after_updates, self._streak, 0)
        pick = np.argmax(ready, axis=-1)
        has = np.take_along_axis(ready, pick[..., None], axis=-1)[..., 0] > 0
        out = np.where(has, pick, -1).astype(np.int64)
        if np.any(has):
            mask = np.zeros(self._streak.shape, dtype=bool)
            np.put_along_axis(mask, pick[..., None], has[..., None], axis=-1)
            self._streak[mask] = 0
        return out
