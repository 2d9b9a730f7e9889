"""The sensor-retirement rule (estimator.retire) alone and fed by the robust estimator."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimator import RobustGradientEstimator, SensorRetirement
from estimator.robust_faults import REASONS
from formation import cvt_sphere, reconfigure

N = 8


def _codes(n=N, **named):
    """Suspect codes with ``{index: reason}`` named."""
    c = np.zeros(n, dtype=np.int8)
    for i, reason in named.items():
        c[int(i.lstrip("s"))] = REASONS.index(reason) + 1
    return c


@pytest.mark.parametrize("after", [1, 2, 5, 20])
@pytest.mark.parametrize("reason", ["stuck", "noisy"])
def test_retires_after_exactly_n_consecutive_namings_and_the_streak_restarts(after, reason):
    rule = SensorRetirement(N, after_updates=after)
    codes = _codes(s3=reason)
    got = [int(rule.update(codes)) for _ in range(2 * after)]
    assert got == ([-1] * (after - 1) + [3]) * 2  # not at every update once due


def test_an_interrupted_streak_starts_again():
    rule = SensorRetirement(N, after_updates=3)
    seq = [_codes(s2="noisy"), _codes(s2="noisy"), _codes(), _codes(s2="noisy"), _codes(s2="noisy")]
    assert [int(rule.update(c)) for c in seq] == [-1] * 5
    assert int(rule.update(_codes(s2="noisy"))) == 2


@pytest.mark.parametrize("reason", ["spiking", "biased"])
def test_spiking_and_biased_are_not_retiring_reasons_by_default_but_can_be(reason):
    assert int(SensorRetirement(N, 1).update(_codes(s5=reason))) == -1
    assert int(SensorRetirement(N, 1, reasons=(reason,)).update(_codes(s5=reason))) == 5
    assert int(SensorRetirement(N, 1, reasons=reason).update(_codes(s5="noisy"))) == -1


@pytest.mark.parametrize(("ratio", "retired"), [(2.9, 4), (3.0, 4), (3.2, -1)])
def test_a_noisy_sensor_counts_only_at_min_noise_ratio_times_the_median(ratio, retired):
    std = np.full(N, 0.1)
    std[4] = 0.31
    rule = SensorRetirement(N, 1, min_noise_ratio=ratio)
    assert int(rule.update(_codes(s4="noisy"), std)) == retired
    assert int(SensorRetirement(N, 1, min_noise_ratio=ratio).update(_codes(s4="stuck"), std * 0 + 0.1)) == 4


def test_the_longest_named_sensor_goes_first():
    rule = SensorRetirement(N, after_updates=2)
    assert int(rule.update(_codes(s6="noisy"))) == -1
    assert int(rule.update(_codes(s1="stuck", s6="noisy"))) == 6
    assert int(rule.update(_codes(s1="stuck", s6="noisy"))) == 1


def test_never_below_min_sensors():
    assert int(SensorRetirement(4, 1).update(_codes(4, s0="stuck"))) == -1
    assert int(SensorRetirement(6, 1, min_sensors=6).update(_codes(6, s0="stuck"))) == -1
    assert int(SensorRetirement(6, 1, min_sensors=5).update(_codes(6, s0="stuck"))) == 0


def test_batches_are_independent():
    rule = SensorRetirement(N, after_updates=2, batch_shape=(3,))
    codes = np.stack([_codes(s3="noisy"), _codes(), _codes(s7="stuck")])
    assert rule.update(codes).tolist() == [-1, -1, -1]
    assert rule.update(codes).tolist() == [3, -1, 7]
    assert rule.streaks[:, [3, 7]].tolist() == [[0, 0], [0, 0], [0, 0]]


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n": 3}, "n must be an integer >= 4"),
    ({"n": 8, "after_updates": 0}, "after_updates must be an integer >= 1"),
    ({"n": 8, "after_updates": 2.5}, "after_updates"),
    ({"n": 8, "min_sensors": 3}, "min_sensors must be an integer >= 4"),
    ({"n": 8, "min_noise_ratio": 0.5}, "min_noise_ratio must be a finite number >= 1"),
    ({"n": 8, "min_noise_ratio": float("nan")}, "min_noise_ratio"),
    ({"n": 8, "reasons": ("noisy", "sleepy")}, r"unknown suspect reason\(s\) \['sleepy'\]"),
])
def test_bad_arguments_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorRetirement(**kwargs)


def test_codes_of_the_wrong_shape_are_refused():
    with pytest.raises(ValueError, match=r"codes must have shape \(8,\), got \(7,\)"):
        SensorRetirement(N).update(np.zeros(7))
    with pytest.raises(ValueError, match=r"noise_std must have shape \(8,\), got \(3,\)"):
        SensorRetirement(N).update(np.zeros(8), np.ones(3))


def _run(noise_std, updates, seed):
    """Robust estimator + rule on a linear field; returns (update of the retirement, index) or None."""
    rng = np.random.default_rng(seed)
    off = Rotation.random(random_state=seed).apply(cvt_sphere(N, 1.0, 0))
    est, rule = RobustGradientEstimator(N), SensorRetirement(N)
    grad = np.array([0.3, -0.2, 0.1])
    for t in range(updates):
        y = off @ grad + 2.0 + rng.standard_normal(N) * noise_std
        est.update(off, y)
        k = int(rule.update(est.suspect_codes, est.noise_std_estimates))
        if k >= 0:
            return t + 1, k
    return None


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("noisy", [0, 5])
def test_a_5x_noisy_sensor_is_retired_and_a_healthy_formation_keeps_all(seed, noisy):
    std = np.full(N, 0.1)
    assert _run(std, 300, seed) is None  # all equal: nobody retired in 300 updates
    std[noisy] = 0.5
    when, who = _run(std, 300, seed)
    assert who == noisy
    # the estimator's warm-up, its noise estimate reaching 3x the median, then 20 updates
    assert 20 <= when <= 120


def test_the_re_formed_survivors_are_a_7_point_cvt_without_the_retired_sensor():
    off = cvt_sphere(N, 1.0, 0)
    rec = reconfigure(off, 3, 1.0)
    assert 3 not in set(rec.survivors.tolist()) and len(rec.survivors) == N - 1
    assert np.allclose(np.linalg.norm(rec.slots, axis=1), 1.0)

