"""Faulty-sensor detection for every seeker: the robust estimator's verdicts, whatever moves the centre.

With ``[faults] faulty_sensor = "retire"`` (the default) or ``"keep"``, every seek iteration's
aligned readings (one per sensing vehicle, where each was taken) go to a
:class:`estimator.robust.RobustGradientEstimator` used as a detector (the plan's own estimator
when it is ``robust``, the same object, else one of its own), whatever the plan's estimator and
seeker:

* the sensors it leaves out of that update as ``stuck``, or for a reading rejected as a spike, are
  dropped from the seeker's input for that iteration (:meth:`SensorCheck.keep`): the
  ``newton``/``model``/``plume`` seekers do not see their readings (with moving sampling, none of
  that vehicle's readings since the last estimate), and a seeker with a memory is reset when a
  sensor is newly named ``stuck`` (its window and trust region were built with that sensor's
  readings: a stuck sensor's had shrunk the trust region until the model seeker "converged"
  8 m from the source); the
  paper's gradient step with a non-robust estimator is taken from Theorem 2 on the others
  (:meth:`SensorCheck.gradient`);
* a sensor named ``biased`` is only reported (its readings still go to the seeker, as the
  retirement rule does not retire for it either, :mod:`estimator.retire`): with 8 or fewer
  sensors the field's curvature across the formation looks like a bias on one of them. Acting on
  it cost fault-free missions: 10 default `run` seeds ended 0.145 m from the source on average
  (max 0.264) instead of 0.071 (max 0.127), healthy sensors named ``biased`` in 93 of 204
  iterations; with the paper's gradient step an N = 6 mission ended 2.65 m away instead of 0.11;
* its suspect codes and noise estimates feed the retirement rule (:mod:`mission.flight.faults.retire`,
  ``retire`` only) and the ``suspects`` of the logged iteration.

``faulty_sensor = "off"``: no detector (the plan's estimator alone; the seekers get every reading).
"""
from __future__ import annotations

import numpy as np

__all__ = ["DETECTOR_WARMUP", "SensorCheck", "make_check"]

#: updates before the detector names faults (the robust estimator's own default is 20: the model and
#: newton seekers often converge in about that many iterations, so the detector would never speak)
DETECTOR_WARMUP = 5


class SensorCheck:
    """The detector of one seek's sensing vehicles (module docstring).

    Parameters
    ----------
    sysids : list of int
        The sensing vehicles, in the order of the detector's sensors (sorted).
    shared : RobustGradientEstimator, optional
        The plan's robust estimator, already updated by the seek's estimate (not updated twice).
    """

    def __init__(self, sysids: list[int], shared=None):
        from estimator.robust import RobustGradientEstimator

        self.sysids = sorted(int(s) for s in sysids)
        self.shared = shared is not None
        self.robust = shared if shared is not None else RobustGradientEstimator(len(self.sysids),
                                                                                warmup=DETECTOR_WARMUP)
        self.excluded: set[int] = set()  # sysids left out of the last update
        self.biased: set[int] = set()  # of those, the ones named biased
        self.newly_excluded: set[int] = set()  # named stuck and excluded at the last update, not before
        self._persistent: set[int] = set()
        self.failure: str | None = None  # why the last update was not made (None: it was)

    def update(self, used: list[int], positions, values, centroid) -> None:
        """Feed one iteration's aligned readings (``used`` sysids, in order); sets :attr:`excluded`.

        An update over other vehicles than the detector's (a reading missing) is skipped: the
        sensors named ``stuck``/``biased`` and excluded at the last update stay excluded. A
        degenerate geometry or bad input is not an error for the seek: no update, ``failure`` set.
        """
        from estimator import GeometryError

        self.failure = None
        self.newly_excluded = set()
        if list(used) != self.sysids:
            self.failure = f"readings of {list(used)}, not of every sensing vehicle {self.sysids}"
            return
        if not self.shared:
            try:
                self.robust.update(np.asarray(positions, dtype=float) - np.asarray(centroid, dtype=float),
                                   np.asarray(values, dtype=float))
            except (GeometryError, ValueError) as exc:
                self.failure = str(exc)
                return
        from estimator.robust_faults import REASONS

        out = np.asarray(self.robust.excluded, dtype=bool)
        codes = np.asarray(self.robust.suspect_codes)
        lasting = (REASONS.index("stuck") + 1,)
        self.excluded = {s for s, x in zip(self.sysids, out) if x}
        self.biased = {s for s, x, c in zip(self.sysids, out, codes) if x and c == REASONS.index("biased") + 1}
        persistent = {s for s, x, c in zip(self.sysids, out, codes) if x and c in lasting}
        self.newly_excluded = persistent - self._persistent
        self._persistent = persistent

    @property
    def dropped(self) -> set[int]:
        """The sensors whose readings the seeker does not get this iteration: excluded as ``stuck`` or
        for a spike, not as ``biased`` (module docstring)."""
        return self.excluded - self.biased

    def keep(self, readings: list, positions) -> tuple[list, np.ndarray]:
        """``readings`` (with their sysid) and ``positions`` without those of the :attr:`dropped` sensors."""
        pos = np.asarray(positions, dtype=float).reshape(-1, 3)
        drop = self.dropped
        if not drop:
            return list(readings), pos
        mask = np.array([r.sysid not in drop for r in readings], dtype=bool)
        return [r for r, m in zip(readings, mask) if m], pos[mask]

    def gradient(self, positions, values, used: list[int]):
        """The paper's step's gradient without the :attr:`dropped` sensors (Theorem 2 on the others),
        or None (none dropped, the estimate is the robust one, or fewer than 4 left)."""
        import estimator

        drop = self.dropped
        if self.shared or not drop:
            return None
        keep = [i for i, s in enumerate(used) if s not in drop]
        if len(keep) < 4:
            return None
        p = np.asarray(positions, dtype=float)[keep]
        v = np.asarray(values, dtype=float)[keep]
        try:
            return np.asarray(estimator.gradient(p, v, p.mean(axis=0), method="cvt"), dtype=float)
        except (estimator.GeometryError, ValueError):
            return None

    # the interface of the seek's robust estimate function, for SensorWatch and the logged suspects
    def suspect_codes(self) -> np.ndarray:
        """The detector's suspect codes, one per sensing vehicle (``0``: trusted)."""
        return self.robust.suspect_codes

    def noise_std(self) -> np.ndarray:
        """The detector's noise standard deviation estimates, one per sensing vehicle."""
        return self.robust.noise_std_estimates

    def suspects(self) -> list:
        """The detector's suspects (:class:`estimator.robust.Suspect`)."""
        return list(self.robust.suspects)


def make_check(faults, estimate, sysids: list[int]) -> SensorCheck | None:
    """The seek's :class:`SensorCheck`, or None with ``faulty_sensor = "off"`` or fewer than 4 vehicles.

    ``estimate`` is the seek's estimate (:class:`mission.flight.seeking.GradientEstimate`):
    when it is the robust estimator, the detector is that estimator (``estimate.robust``).
    """
    if faults.faulty_sensor == "off" or len(sysids) < 4:
        return None
    return SensorCheck(sysids, shared=estimate.robust)
