"""Steady Gaussian plume: shape (centreline maximum, crosswind and downwind decay), ground
reflection, upwind background, positivity, gradient direction, validation."""
from __future__ import annotations

import numpy as np
import pytest

from sitl_mock.fields_plume import GaussianPlume, briggs_sigmas
from sitl_mock.fields_config import make_field

H = 15.0


def _strictly(diffs, values, sign):
    """Strictly monotone where the plume is above the background (beyond, flat)."""
    live = values[1:] > 1e-4 + 1e-12
    return bool(np.all(sign * diffs[live] > 0) and np.all(sign * diffs >= 0) and live.sum() > 10)


def _plume(**kw):
    kw.setdefault("wind_from_deg", 200.0)  # not along an axis: exercises the wind frame
    return GaussianPlume((3.0, -4.0, H), **kw)


def test_wind_frame_round_trip_and_downwind_direction():
    p = GaussianPlume((0.0, 0.0, H), wind_from_deg=270.0)  # west wind: blows toward the east
    assert np.allclose(p.downwind_en, [1.0, 0.0], atol=1e-12)
    q = _plume()
    pts = np.random.default_rng(0).uniform(-50, 50, (20, 3))
    assert np.allclose(q.to_enu(*q.wind_frame(pts)), pts)
    x, y, _ = q.wind_frame(q.release + np.array([*q.downwind_en, 0.0]) * 10.0)
    assert x == pytest.approx(10.0) and y == pytest.approx(0.0, abs=1e-12)
    down = p.value(np.array([10.0, 0.0, H]))
    for other in ([-10.0, 0.0, H], [0.0, 10.0, H], [0.0, -10.0, H]):
        assert down > 100 * p.value(np.array(other))


@pytest.mark.parametrize("x_m", [2.0, 10.0, 40.0, 120.0])
def test_crosswind_maximum_is_on_the_centreline_and_decreases_away(x_m):
    p = _plume()
    y = np.linspace(-30.0, 30.0, 601)
    v = p.value(p.to_enu(x_m, y, H))
    assert abs(y[int(np.argmax(v))]) < 1e-9
    left, right = v[:301], v[300:]
    assert _strictly(np.diff(right), right, -1) and _strictly(-np.diff(left[::-1]), left[::-1], 1)


def test_vertical_maximum_near_release_height_downwind():
    p = _plume()
    z = np.linspace(0.0, 40.0, 4001)
    v = p.value(p.to_enu(10.0, 0.0, z))
    assert abs(z[int(np.argmax(v))] - H) < 0.02


def test_centreline_at_release_height_decreases_downwind_and_peaks_at_the_release():
    p = _plume()
    x = np.linspace(0.01, 300.0, 3000)
    v = p.value(p.to_enu(x, 0.0, H))
    assert np.all(np.diff(v) < 0)
    assert np.allclose(p.peak_enu(), p.release, atol=0.02)
    assert p.value(p.release) == pytest.approx(1.0 + p.background, rel=1e-9)  # default emission


def test_ground_level_peak_is_downwind_and_decreases_beyond_it():
    p = _plume()
    peak = p.peak_enu(alt_m=0.0)
    x_peak, y_peak, z_peak = p.wind_frame(peak)
    assert x_peak > 20.0 and abs(y_peak) < 1e-9 and z_peak == pytest.approx(0.0)
    x = np.linspace(x_peak + 0.1, 400.0, 500)
    assert np.all(np.diff(p.value(p.to_enu(x, 0.0, 0.0))) < 0)
    x = np.linspace(1.0, x_peak - 0.1, 500)
    v = p.value(p.to_enu(x, 0.0, 0.0))
    assert _strictly(np.diff(v), v, 1)


def test_ground_reflection_doubles_the_ground_level_plume_and_matches_the_formula():
    with_r = _plume(background=0.0)
    without = _plume(background=0.0, ground_reflection=False)
    for x_m, y_m in ((20.0, 0.0), (50.0, 3.0), (150.0, -10.0)):
        ground = with_r.to_enu(x_m, y_m, 0.0)
        assert with_r.value(ground) == pytest.approx(2.0 * without.value(ground), rel=1e-12)
    x_m, y_m, z_m = 30.0, 2.0, 4.0
    sy, sz = briggs_sigmas(x_m, "C")
    sy, sz = np.hypot(1.0, sy), np.hypot(1.0, sz)
    q, u = with_r.emission_rate, with_r.wind_speed_m_s
    expected = (q / (2 * np.pi * u * sy * sz) * np.exp(-y_m ** 2 / (2 * sy ** 2))
                * (np.exp(-(z_m - H) ** 2 / (2 * sz ** 2)) + np.exp(-(z_m + H) ** 2 / (2 * sz ** 2))))
    assert with_r.value(with_r.to_enu(x_m, y_m, z_m)) == pytest.approx(expected, rel=1e-12)


def test_briggs_spreads_match_the_published_fit():
    sy, sz = briggs_sigmas(100.0, "D")  # 0.08 x (1 + 1e-4 x)^-1/2, 0.06 x (1 + 1.5e-3 x)^-1/2
    assert sy == pytest.approx(8.0 / np.sqrt(1.01)) and sz == pytest.approx(6.0 / np.sqrt(1.15))
    sy, sz = briggs_sigmas(1000.0, "F")
    assert sy == pytest.approx(40.0 / np.sqrt(1.1)) and sz == pytest.approx(16.0 / 1.3)


def test_upwind_is_background():
    p = _plume(background=2e-4)
    for x_m in (-10.0, -30.0, -200.0):
        assert p.value(p.to_enu(x_m, 0.0, H)) == pytest.approx(2e-4, rel=1e-12)
    assert p.value(p.to_enu(-3.0, 0.0, H)) < 0.02  # 3 source radii upwind: exp(-4.5) of the release


def test_positive_and_finite_everywhere_with_finite_gradient():
    p = _plume()
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.uniform(-1e4, 1e4, (5000, 3)), rng.uniform(-30, 30, (5000, 3)),
                          p.release[None, :], np.array([[3.0, -4.0, -5.0]])])
    v = p.value(pts)
    assert np.all(np.isfinite(v)) and np.all(v > 0)
    assert np.all(np.isfinite(p.gradient(pts)))


def test_gradient_points_to_the_centreline_then_up_the_centreline():
    p = _plume()
    off = p.to_enu(20.0, 2.0, H)
    g = p.gradient(off)
    cross = np.array([-p.downwind_en[1], p.downwind_en[0], 0.0])
    assert np.dot(g, cross) < 0  # back toward y = 0
    on = p.to_enu(20.0, 0.0, H)
    g = p.gradient(on)
    assert np.dot(g[:2], p.downwind_en) < 0  # upwind, toward the release
    assert abs(np.dot(g, cross)) < 1e-6 * np.linalg.norm(g)  # finite differences
    fd = (p.value(on + [0.01, 0, 0]) - p.value(on - [0.01, 0, 0])) / 0.02
    assert g[0] == pytest.approx(fd, rel=1e-4)


def test_make_field_plume_and_its_errors():
    p = make_field("plume", (1.0, 2.0, 10.0), wind_speed_m_s=4.0, stability="B")
    assert isinstance(p, GaussianPlume) and np.allclose(p.source_enu(), [1.0, 2.0, 10.0])
    assert p.newton_gain() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="wind_speed_m_s"):
        GaussianPlume((0, 0, 10), wind_speed_m_s=0.0)
    with pytest.raises(ValueError, match="stability"):
        GaussianPlume((0, 0, 10), stability="G")
    with pytest.raises(ValueError, match="below the ground"):
        GaussianPlume((0, 0, -1.0))
    with pytest.raises(ValueError, match="background"):
        GaussianPlume((0, 0, 10), background=-1.0)
    with pytest.raises(ValueError, match="has no parameter seed"):
        make_field("plume", (0, 0, 10), seed=3)
    with pytest.raises(ValueError, match="has no parameter wind_speed_m_s"):
        make_field("sigma2", wind_speed_m_s=3.0)
