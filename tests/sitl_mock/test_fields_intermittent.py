"""Intermittent (puff) plume: deterministic for a seed, time-average equal to its ensemble mean
and close to the steady plume, patchy in time (with memory), positive and finite."""
from __future__ import annotations

import numpy as np
import pytest

from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_plume import GaussianPlume
from sitl_mock.fields_config import make_field

H = 15.0
T0 = 1767225600.0  # the lock-step clock's epoch: the mock fleet's times are this large


def _plume(seed=4, **kw):
    return FilamentPlume((0.0, 0.0, H), seed=seed, wind_from_deg=250.0, **kw)


def _independent_times(f: FilamentPlume, n: int, rng) -> np.ndarray:
    """Times further apart than a puff's life plus two meander steps: no shared puff or meander
    value, so the readings are independent draws (and at uniformly random release phases)."""
    gap = f.max_range_m / f.steady.wind_speed_m_s + 2.0 * f.meander_time_s + 1.0
    return T0 + np.arange(n) * gap + rng.uniform(0.0, 1.0, n)


def _samples(f, pts, times):
    return f.value(np.broadcast_to(pts, (len(times),) + pts.shape), times[:, None])


def test_deterministic_for_a_seed_and_independent_of_call_order():
    f, g = _plume(seed=4), _plume(seed=4)
    pts = f.steady.to_enu(np.array([5.0, 20.0, 40.0]), np.array([0.0, 1.0, -2.0]), H)
    times = T0 + np.array([0.0, 0.37, 12.5, 300.0])
    batch = _samples(f, pts, times)
    one_by_one = np.array([[g.value(p, t) for p in pts] for t in times[::-1]])[::-1]
    assert np.array_equal(batch, one_by_one)
    other = _samples(_plume(seed=5), pts, times)
    assert not np.allclose(batch, other)


def test_time_average_converges_to_the_ensemble_mean_and_the_steady_shape():
    f = _plume()
    rng = np.random.default_rng(0)
    pts = f.steady.to_enu(np.array([10.0, 20.0, 20.0, 40.0, 40.0, 80.0]),
                          np.array([0.0, 0.0, 3.0, 0.0, -5.0, 0.0]), np.array([H, H, H, H, H - 2.0, 4.0]))
    n = 1500
    v = _samples(f, pts, _independent_times(f, n, rng))
    mean = f.mean_value(pts)
    sem = v.std(axis=0, ddof=1) / np.sqrt(n)
    # independent draws: the sample mean is within 4.5 standard errors (6 points: false alarm ~4e-5)
    assert np.all(np.abs(v.mean(axis=0) - mean) <= 4.5 * sem), (v.mean(axis=0), mean, sem)
    steady = f.steady.value(pts)
    # the ensemble mean is the steady plume smoothed along the wind by the source radius
    assert np.all(np.abs(mean - steady) <= 0.01 * steady)


def test_mean_upwind_and_far_away_is_background():
    f = _plume()
    far = f.steady.to_enu(np.array([-20.0, 30.0, 400.0]), np.array([0.0, 60.0, 0.0]), H)
    assert np.allclose(f.mean_value(far), f.background, rtol=1e-9)
    assert np.allclose(_samples(f, far, T0 + np.arange(50) * 0.7), f.background, rtol=1e-9)


def test_patchy_in_time_with_memory():
    f = _plume()
    rng = np.random.default_rng(1)
    centre = f.steady.to_enu(20.0, 0.0, H)[None, :]
    side = f.steady.to_enu(20.0, 2.0 * f.steady.spreads(20.0)[0], H)[None, :]
    times = _independent_times(f, 1000, rng)
    for pt, lo, hi in ((centre, 0.2, 0.55), (side, 0.6, 0.95)):
        v = _samples(f, pt, times)[:, 0]
        zero = np.mean(v < 0.05 * f.mean_value(pt)[0])  # "zero" readings: < 5 % of the mean
        assert lo <= zero <= hi, zero
        assert v.std() > f.mean_value(pt)[0]  # fluctuations larger than the mean (c.v. > 1)
    steady = GaussianPlume((0.0, 0.0, H), wind_from_deg=250.0)
    assert steady.value(centre)[0] > 0.05 * f.mean_value(centre)[0]  # the steady plume is never "zero"
    # memory: patches last; readings 0.25 s apart are nearly the same, 60 s apart unrelated
    t = T0 + np.arange(1200) * 0.25
    v = _samples(f, centre, t)[:, 0]
    near = np.corrcoef(v[:-1], v[1:])[0, 1]
    far = np.corrcoef(v[:-240], v[240:])[0, 1]
    assert near > 0.9 and abs(far) < 0.3, (near, far)


def test_positive_and_finite_everywhere():
    f = _plume()
    rng = np.random.default_rng(2)
    pts = np.concatenate([rng.uniform(-300, 300, (3000, 3)), rng.uniform(-10, 40, (3000, 3))])
    v = f.value(pts, T0 + 5.3)
    assert np.all(np.isfinite(v)) and np.all(v >= f.background) and f.background > 0
    assert np.all(np.isfinite(f.value(pts, 0.0))) and np.all(np.isfinite(f.gradient(pts)))


def test_parameters_and_errors():
    f = make_field("intermittent", (0.0, 0.0, 10.0), seed=7, wind_speed_m_s=4.0, source_radius_m=2.0)
    assert f.time_dependent and f.release_rate_hz == pytest.approx(4.0)  # 2 U / s0
    assert np.allclose(f.source_enu(), [0.0, 0.0, 10.0])
    assert np.allclose(f.gradient(np.array([5.0, 1.0, 9.0])), f.steady.gradient(np.array([5.0, 1.0, 9.0])))
    for kw, match in (({"puff_fraction": 1.0}, "puff_fraction"), ({"meander_fraction": 1.5}, "meander_fraction"),
                      ({"seed": 1.5}, "seed"), ({"release_rate_hz": 1e6}, "too many")):
        with pytest.raises(ValueError, match=match):
            FilamentPlume((0.0, 0.0, 10.0), **kw)
    with pytest.raises(ValueError, match="finite"):
        f.value(np.zeros(3), np.nan)
