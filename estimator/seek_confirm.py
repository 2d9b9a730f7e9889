"""Convergence confirmed by the seeker's own 95 % region (pure numpy).

The window test (:class:`estimator.seeking.ConvergenceMonitor`) knows nothing of the source: it
waits until ``window`` (a plan's 12) commanded centres have stood still within ``tol_m``. At a
mission's 2 iterations per second that costs about 5.5 s after the formation has arrived, more
than half the straight-line flight of the default mission (25 m at 3 m/s), although the ``model``
seeker has by then located the source to a few centimetres (``docs/seekers.md``, "Confirming
convergence").

A seeker with a model of the source reports its estimate with a 95 % region
(:class:`~estimator.estimate.SourceEstimate`; the ``model`` seeker: the fitted maximum and the
sphere holding 95 % of its covariance). The **region rule** declares convergence after an
iteration when, for ``hold`` consecutive iterations ending with it:

1. the seeker reported an estimate whose 95 % region has a radius ``<= tol_m`` (a region, not
   None: the centres' mean of the seekers without a model never qualifies);
2. the formation is on it: the next commanded centre and the centroid of the positions where
   the iteration's readings were taken are both within ``tol_m`` of the estimate (the readings
   that made the fit surround the source, where the fitted model is checked by the readings
   themselves, not extrapolated);
3. the estimate stands: every one of the ``hold`` estimates lies within ``tol_m / 2`` of their mean;
4. the iteration had a detection (the convergence test's signal, criterion 3 of
   :mod:`estimator.seeking`) when ``min_signal_fraction > 0``.

The window test still applies; the seek ends on whichever passes first
(:class:`SeekConvergenceMonitor`). Why this is safe, with the offline and mission numbers
(false convergences, final error), is in ``docs/seekers.md``.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from estimator.estimate import SourceEstimate
from estimator.seeking import ConvergenceMonitor

__all__ = ["DEFAULT_HOLD", "RegionConfirmation", "SeekConvergenceMonitor", "region_scan", "seeker_estimate"]

#: consecutive iterations the region rule must hold
DEFAULT_HOLD = 3


def seeker_estimate(seeker, k: int = 0) -> SourceEstimate | None:
    """``seeker.source_estimate(k)`` when the seeker has a model of the source, else None (never the
    centres' mean of :func:`estimator.estimate.reported_estimate`: that region is not a confidence region)."""
    own = getattr(seeker, "source_estimate", None)
    return None if own is None else own(k)


def _check(tol_m: float, hold: int) -> None:
    if not (np.isfinite(tol_m) and tol_m > 0):
        raise ValueError(f"tol_m must be a positive finite number, got {tol_m!r}")
    if int(hold) != hold or hold < 2:
        raise ValueError(f"hold must be an integer >= 2, got {hold!r}")


def _qualifies(centre, formation_centre, estimate_enu, region_m, signal, tol_m: float) -> np.ndarray:
    """Criteria 1, 2 and 4 of the module docstring for one iteration (any leading shape; NaN fails)."""
    with np.errstate(invalid="ignore"):
        tight = np.asarray(region_m, dtype=float) <= tol_m
        on_c = np.linalg.norm(np.asarray(centre) - estimate_enu, axis=-1) <= tol_m
        on_f = np.linalg.norm(np.asarray(formation_centre) - estimate_enu, axis=-1) <= tol_m
    return tight & on_c & on_f & np.asarray(signal, dtype=bool)


def _standing(estimates: np.ndarray, tol_m: float) -> np.ndarray:
    """Criterion 3 over ``estimates`` (hold, ..., 3): every one within ``tol_m / 2`` of their mean."""
    dev = np.linalg.norm(estimates - estimates.mean(axis=0), axis=-1)
    with np.errstate(invalid="ignore"):
        return np.all(dev <= 0.5 * tol_m, axis=0)


class RegionConfirmation:
    """The region rule online (module docstring), one iteration at a time.

    Parameters
    ----------
    tol_m : float
        The convergence tolerance (a plan's ``convergence_tol_m``), metres.
    hold : int
        Consecutive iterations the rule must hold (>= 2).
    use_signal : bool
        Criterion 4: an iteration without a detection breaks the run.

    Examples
    --------
    >>> from estimator.estimate import SourceEstimate
    >>> rule = RegionConfirmation(tol_m=0.5, hold=3)
    >>> est = SourceEstimate([1.0, 2.0, 3.0], 0.2, "a fit")
    >>> [rule.update([1.0, 2.0, 3.1], est, [1.1, 2.0, 3.0]) for _ in range(3)]
    [False, False, True]
    """

    def __init__(self, tol_m: float = 0.5, hold: int = DEFAULT_HOLD, use_signal: bool = True):
        _check(tol_m, hold)
        self.tol_m, self.hold, self.use_signal = float(tol_m), int(hold), bool(use_signal)
        self._estimates: deque = deque(maxlen=self.hold)
        self.passed = False

    def reset(self) -> None:
        """Forget the run of qualifying iterations."""
        self._estimates.clear()
        self.passed = False

    def update(self, centre, estimate: SourceEstimate | None, formation_centre_enu=None,
               signal: bool | None = None) -> bool:
        """One iteration: the next commanded ``centre``, the seeker's ``estimate`` (None: it has
        none), the centroid of where the readings were taken (None: ``centre``) and whether the
        iteration had a detection (None: yes); whether the rule passes now."""
        formation = centre if formation_centre_enu is None else formation_centre_enu
        sig = True if (signal is None or not self.use_signal) else bool(signal)
        if estimate is None or estimate.region95_m is None or not _qualifies(
                centre, formation, estimate.enu, estimate.region95_m, sig, self.tol_m):
            self.reset()
            return False
        self._estimates.append(np.asarray(estimate.enu, dtype=float).copy())
        self.passed = len(self._estimates) == self.hold and bool(
            _standing(np.asarray(self._estimates), self.tol_m))
        return self.passed


def region_scan(centres, formation_centres, estimates_enu, regions_m, signal=None, *, tol_m: float,
                hold: int = DEFAULT_HOLD) -> np.ndarray:
    """The region rule over whole runs (vectorised, the maths of :class:`RegionConfirmation`).

    Parameters
    ----------
    centres : array_like, shape (T, ..., 3)
        The commanded centre after each iteration.
    formation_centres : array_like, shape (T, ..., 3)
        The centroid of where each iteration's readings were taken.
    estimates_enu : array_like, shape (T, ..., 3)
        The seeker's estimate after each iteration (NaN: none).
    regions_m : array_like, shape (T, ...)
        Its 95 % region's radius (NaN: none).
    signal : array_like of bool, shape (T, ...), optional
        Whether each iteration had a detection; None: every one.
    tol_m, hold : float, int
        As :class:`RegionConfirmation`.

    Returns
    -------
    ndarray of int, shape (...)
        Index of the first iteration after which the rule passes, ``-1`` if never.
    """
    _check(tol_m, hold)
    c = np.asarray(centres, dtype=float)
    est = np.asarray(estimates_enu, dtype=float)
    sig = np.ones(c.shape[:-1], dtype=bool) if signal is None else np.broadcast_to(signal, c.shape[:-1])
    ok = _qualifies(c, np.asarray(formation_centres, dtype=float), est, regions_m, sig, tol_m)
    first = np.full(c.shape[1:-1], -1)
    for t in range(hold - 1, c.shape[0]):
        run = np.all(ok[t - hold + 1:t + 1], axis=0) & _standing(est[t - hold + 1:t + 1], tol_m)
        first = np.where((first < 0) & run, t, first)
    return first


class SeekConvergenceMonitor(ConvergenceMonitor):
    """The seek's convergence test: the window test of :class:`~estimator.seeking.ConvergenceMonitor`
    or the region rule (:class:`RegionConfirmation`), whichever passes first.

    Parameters
    ----------
    window, tol_m, drift_factor, min_signal_fraction
        As :class:`~estimator.seeking.ConvergenceMonitor` (``tol_m`` is the region rule's too;
        criterion 4 applies when ``min_signal_fraction > 0``).
    hold : int
        The region rule's consecutive iterations; 0: no region rule (the window test alone).

    Attributes
    ----------
    declared_by : str or None
        ``"window"`` or ``"region"``: which test passed on the last update (None: neither).
    """

    def __init__(self, window: int = 400, tol_m: float = 1.0, drift_factor: float = 0.5,
                 min_signal_fraction: float = 0.0, hold: int = DEFAULT_HOLD):
        super().__init__(window=window, tol_m=tol_m, drift_factor=drift_factor,
                         min_signal_fraction=min_signal_fraction)
        self.region = (None if hold == 0 else
                       RegionConfirmation(tol_m=tol_m, hold=hold, use_signal=min_signal_fraction > 0))
        self.declared_by: str | None = None

    @property
    def spread_m(self) -> float:
        """RMS distance of the centres the passing test looked at to their mean: the last ``hold``
        when the region rule declared (the window's would include the approach), else the window's."""
        if self.declared_by != "region":
            return super().spread_m
        last = np.asarray(self._centres)[-self.region.hold:]
        return float(np.sqrt(np.mean(np.sum((last - last.mean(axis=0)) ** 2, axis=-1))))

    def reset(self) -> None:
        """Forget every centre and estimate seen."""
        super().reset()
        if self.region is not None:
            self.region.reset()
        self.declared_by = None

    def update(self, centre, signal: bool | None = None, estimate: SourceEstimate | None = None,
               formation_centre_enu=None) -> bool:
        """Record the newest centre, signal, the seeker's ``estimate`` (None: none) and the
        centroid of the iteration's readings; whether either test passes."""
        by_window = super().update(centre, signal)
        by_region = self.region is not None and self.region.update(centre, estimate, formation_centre_enu, signal)
        self.declared_by = "window" if by_window else "region" if by_region else None
        return self.declared_by is not None
