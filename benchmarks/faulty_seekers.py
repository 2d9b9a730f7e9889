"""The faulty-sensor Monte Carlo of ``bench_faulty_sensor.py --seeker NAME`` (newton, model, plume).

Each trial is one formation flown by its own seeker (K = 1, as in the mission: the readings a
trial's seeker gets depend on what that trial's detector excluded) about the paper's sigma_2,
with one faulty robot (``trial mod N``) and its own random rotation. Variants, as the mission
(``mission.flight.sensor_check``, ``[faults] faulty_sensor``):

* ``all readings`` (``off``): the seeker gets every reading;
* ``detect`` (``keep``): a robust estimator (warm-up ``DETECTOR_WARMUP``, the mission's) sees
  every iteration's readings; the sensors it leaves out of that update as stuck or for a spike
  (not as biased: only reported) are left out of the seeker's input, and the seeker is reset
  when a sensor is newly named stuck;
* ``detect+retire`` (``retire``, the default): as ``detect``, plus
  :class:`estimator.retire.SensorRetirement` (its defaults, 20 iterations): the retired robot is
  parked at the centre (its readings ignored), the others re-formed into a warm-started
  (N-1)-CVT, with a fresh detector and rule.

The step of every seeker is capped at ``gamma`` (the mission's 20 m by default for these seekers).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from estimator.retire import SensorRetirement
from estimator.robust_faults import REASONS
from estimator.robust import RobustGradientEstimator
from estimator.seekers import cap_move, make_seeker
from formation import cvt_sphere, reconfigure
from mission.flight.sensor_check import DETECTOR_WARMUP
from sitl_mock.fields_gaussian import sigma2

__all__ = ["VARIANTS", "run_seeker"]

VARIANTS = ("all readings", "detect", "detect+retire")
_STUCK = REASONS.index("stuck") + 1
_BIASED = REASONS.index("biased") + 1


class _Trial:
    """One formation: its offsets, seeker, detector, retirement rule and the readings it keeps."""

    def __init__(self, off, seeker: str, variant: str, radius_m: float, retire_after: int):
        self.off = off.copy()
        self.n = len(off)
        self.seeker = make_seeker(seeker)
        self.variant = variant
        self.radius_m = radius_m
        self.retire_after = retire_after
        self.sensing = list(range(self.n))  # robot indices the detector watches
        self.retired = -1
        self.retired_at = -1
        self.healthy_excluded = 0  # iterations with a healthy robot's readings left out
        self._fresh()

    def _fresh(self):
        m = len(self.sensing)
        self.det = None if self.variant == "all readings" else RobustGradientEstimator(m, warmup=DETECTOR_WARMUP)
        self.rule = SensorRetirement(m, self.retire_after) if self.variant == "detect+retire" else None
        self.lasting: set[int] = set()

    def step(self, t, c, y, faulty, gamma):
        """The next centre from this iteration's readings ``y`` (N,) about centre ``c``."""
        keep = list(self.sensing)
        if self.det is not None:
            off = self.off[self.sensing]
            try:
                self.det.update(off - off.mean(axis=0), y[self.sensing])
            except ValueError:  # a degenerate geometry: no exclusion this iteration
                pass
            else:
                out = self.det.excluded
                codes = self.det.suspect_codes
                drop = out & (codes != _BIASED)  # as the mission: biased is only reported
                lasting = {self.sensing[i] for i in np.flatnonzero(out) if codes[i] == _STUCK}
                if lasting - self.lasting:
                    self.seeker.reset()
                self.lasting = lasting
                keep = [s for i, s in enumerate(self.sensing) if not drop[i]]
                self.healthy_excluded += any(s != faulty for i, s in enumerate(self.sensing) if drop[i])
                self._maybe_retire(t)
        pos = c + self.off[keep]
        new = self.seeker.propose(c[None], pos[None], y[keep][None])[0]
        if not np.all(np.isfinite(new)):
            return c
        return cap_move(c[None], new[None], gamma)[0]

    def _maybe_retire(self, t):
        if self.rule is None or self.retired >= 0:
            return
        pick = int(self.rule.update(self.det.suspect_codes, noise_std=self.det.noise_std_estimates))
        if pick < 0:
            return
        robot = self.sensing[pick]
        rec = reconfigure(self.off[self.sensing], pick, self.radius_m)
        survivors = [self.sensing[i] for i in rec.survivors]
        self.off[survivors] = rec.slots[rec.assignment]
        self.off[robot] = 0.0
        self.retired, self.retired_at = robot, t + 1
        self.sensing = survivors
        self.seeker.reset()
        self._fresh()


def _readings(fault, clean, noise, faulty, first, rng_spike, noise_std):
    y = clean + noise
    if fault == "stuck":
        y[faulty] = first[faulty]
    elif fault == "biased":
        y[faulty] += 5 * noise_std
    elif fault == "spiking" and rng_spike.random() < 0.05:
        y[faulty] += 50 * noise_std * rng_spike.choice([-1.0, 1.0])
    return y


def run_seeker(fault, variant, seeker, trials, iterations, tail, radius_m, seed, noise_std, gamma,
               start_enu, retire_after=20, n_robots=8):
    """One (fault, variant) cell: final errors (trials,), and the retirement figures
    ``(faulty retired, healthy retired, median retirement iteration, mean fraction of
    iterations with a healthy robot excluded)``."""
    field = sigma2()
    base = cvt_sphere(n_robots, radius_m, 0)
    n = len(base)
    rot = Rotation.random(trials, random_state=seed).as_matrix()
    rng = np.random.default_rng(seed + 1)
    rng_spike = np.random.default_rng(seed + 2)
    final = np.empty(trials)
    retired_right = retired_wrong = 0
    when, healthy_frac = [], []
    for k in range(trials):
        faulty = k % n
        std = np.full(n, noise_std)
        if fault == "noisy 5x":
            std[faulty] = 5 * noise_std
        elif fault == "noisy 10x":
            std[faulty] = 10 * noise_std
        trial = _Trial(base @ rot[k].T, seeker, variant, radius_m, retire_after)
        c = np.asarray(start_enu, dtype=float).copy()
        first, dist = None, np.empty(iterations)
        for t in range(iterations):
            clean = field.value(c + trial.off)
            noise = rng.standard_normal(n) * std
            first = clean + noise if first is None else first
            y = _readings(fault, clean, noise, faulty, first, rng_spike, noise_std)
            c = trial.step(t, c, y, faulty, gamma)
            dist[t] = np.linalg.norm(c - field.source_enu())
        final[k] = dist[-tail:].mean()
        right = fault != "none" and trial.retired == faulty  # with no fault, any retirement is of a healthy robot
        retired_right += right
        retired_wrong += trial.retired >= 0 and not right
        if right:
            when.append(trial.retired_at)
        healthy_frac.append(trial.healthy_excluded / iterations)
    med = float(np.median(when)) if when else float("nan")
    return final, (retired_right / trials, retired_wrong / trials, med, float(np.mean(healthy_frac)))
