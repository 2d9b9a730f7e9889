"""The ``ste`` seeker's move options: per-axis steps and the along-wind rule of the
information-seeking candidates (docs/seekers.md, "Round 5")."""
from __future__ import annotations

import numpy as np

from estimator.ste import SteSeeker

# wind toward east (ENU heading 0): up the wind is west (-x); the cast's first side, up x (0, 0, 1), is south
C = np.array([[30.0, 0.0, 15.0]])


def _ring(c: np.ndarray) -> np.ndarray:
    return c[:, None, :] + np.array([[4.0, 0.0, 0.0], [-4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, -4.0, 0.0]])[None]


def test_axis_steps_size_each_axis_by_the_posteriors_spread_along_it():
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, axis_steps=True, min_step_m=0.5,
                  max_step_m=8.0, casting=False, seed=3)
    s.propose(C, _ring(C), np.zeros((1, 4)))
    rng = np.random.default_rng(0)  # a posterior 3 m deviation up the wind, 0.5 m across, 1 m vertically
    s.parts[0, :, :3] = [0.0, 0.0, 15.0] + rng.standard_normal((s.particles, 3)) * [3.0, 0.5, 1.0]
    s.logw[:] = -np.log(s.particles)
    s._summarise()
    cand = s._candidates(C)
    moves = cand[0, 1:7] - C[0]
    np.testing.assert_allclose(np.abs(moves[:2, 0]), 1.4 * 3.0, rtol=0.1)  # up / down the wind
    np.testing.assert_allclose(np.abs(moves[2:4, 1]), 0.7, rtol=0.1)  # across: 1.4 x 0.5 m
    np.testing.assert_allclose(np.abs(moves[4:6, 2]), 0.5 * 1.4, rtol=0.1)  # vertical: half of 1.4 x 1 m
    plain = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, casting=False, seed=3)
    plain.propose(C, _ring(C), np.zeros((1, 4)))
    step = np.clip(0.5 * plain.region95_m[0], plain.min_step_m, plain.max_step_m)
    np.testing.assert_allclose(np.linalg.norm(plain._candidates(C)[0, 1:5] - C[0], axis=1), step)


def test_toward_mean_along_forbids_steps_along_the_wind_away_from_the_mean():
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, prior_upwind_deg=30.0,
                  toward_mean_along=True, seed=5)
    s.propose(C, _ring(C), np.zeros((1, 4)))
    cand = s._candidates(C)
    away = s._away_along(C, cand)[0]
    along = (cand[0] - C[0]) @ s._upwind()[0]
    assert (C[0] - s.estimate_enu[0]) @ s._upwind()[0] < 0  # the mean up the wind of the centre
    np.testing.assert_array_equal(away, along < -0.1)  # exactly the steps down the wind
    assert away.any() and not away.all()
    nxt = s.propose(C, _ring(C), np.zeros((1, 4)))
    assert (nxt[0] - C[0]) @ s._upwind()[0] > -0.1  # never down the wind while the mean is up it


def test_upwind_points_against_the_posteriors_wind():
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, seed=4)  # from the west: up the wind is -x
    s.propose(C, _ring(C), np.zeros((1, 4)))
    np.testing.assert_allclose(s._upwind(), [[-1.0, 0.0, 0.0]], atol=1e-6)


def test_round_nine_settings_go_to_the_mean_below_a_3_m_region_with_a_quarter_region_formation():
    """Round 9's settings (opt-in): ``exploit_m`` 3 m (infotaxis above it, the posterior mean below)
    and ``radius_gain`` 0.25 (the formation's radius a quarter of the region, within 1.5-6 m)."""
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, seed=3, exploit_m=3.0, radius_gain=0.25)
    rng = np.random.default_rng(0)
    for sd_m, to_mean in ((0.6, True), (4.0, False)):  # a 95 % region of about 1.7 m, then about 11 m
        s.propose(C, _ring(C), np.zeros((1, 4)))
        s.parts[0, :, :3] = [0.0, 0.0, 15.0] + rng.standard_normal((s.particles, 3)) * sd_m
        s.logw[:] = -np.log(s.particles)
        s._summarise()
        nxt = s._next_centre(C, _ring(C) - C[:, None, :], s._subsample())
        assert (s.region95_m[0] < 3.0) == to_mean
        assert np.allclose(nxt, s.estimate_enu) == to_mean
        s._size_formation(_ring(C), C)
        np.testing.assert_allclose(s.formation_radius_m, np.clip(0.25 * s.region95_m, 1.5, 6.0))
