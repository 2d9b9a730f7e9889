"""The ``ste`` seeker's move options: the approach (estimator.ste_approach: surge after hits, cast
after misses), per-axis steps and the along-wind rule of the information-seeking candidates."""
from __future__ import annotations

import numpy as np
import pytest

from estimator.ste import SteSeeker
from estimator.ste_approach import approach_centres, upwind_unit

# wind toward east (ENU heading 0): up the wind is west (-x); the cast's first side, up x (0, 0, 1), is south
UP = upwind_unit(np.array([0.0]))
C = np.array([[30.0, 0.0, 15.0]])
HIT_HERE = C.copy()


def test_upwind_unit_points_against_the_wind():
    np.testing.assert_allclose(upwind_unit(np.array([0.0, np.pi / 2])),
                               [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], atol=1e-12)


def test_a_hit_surges_up_the_wind_toward_the_mean_by_at_most_the_surge():
    mean = np.array([[0.0, 3.0, 16.0]])  # 30 m up the wind, 3 m across, 1 m up
    nxt = approach_centres(C, mean, UP, HIT_HERE, np.array([0]), surge_m=10.0)
    np.testing.assert_allclose(nxt, [[20.0, 3.0, 16.0]])
    near = np.array([[26.0, -2.0, 15.0]])  # 4 m up the wind: the surge stops at the mean's place
    np.testing.assert_allclose(approach_centres(C, near, UP, HIT_HERE, np.array([0]), surge_m=10.0),
                               [[26.0, -2.0, 15.0]])
    off = approach_centres(C, near, UP, HIT_HERE, np.array([0]), surge_m=10.0, standoff_m=1.5)
    np.testing.assert_allclose(off, [[27.5, -2.0, 15.0]])  # and short of it by the standoff


def test_the_surge_goes_at_most_surge_m_past_the_last_hit_and_never_down_the_wind():
    mean = np.array([[0.0, 0.0, 15.0]])
    hit_ahead = np.array([[27.0, 0.0, 15.0]])  # the last hit 3 m up the wind of the centre
    nxt = approach_centres(C, mean, UP, hit_ahead, np.array([1]), surge_m=6.0)
    np.testing.assert_allclose(nxt, [[24.0, 0.0, 15.0]])  # 6 m, the surge cap
    hit_behind = np.array([[35.0, 0.0, 15.0]])  # 5 m down the wind: at most 1 m past the centre
    nxt = approach_centres(C, mean, UP, hit_behind, np.array([1]), surge_m=6.0)
    np.testing.assert_allclose(nxt, [[29.0, 0.0, 15.0]])
    far_behind = np.array([[40.0, 0.0, 15.0]])  # 10 m down the wind: no surge, but no retreat either
    np.testing.assert_allclose(approach_centres(C, mean, UP, far_behind, np.array([0]), surge_m=6.0), C)


def test_misses_cast_across_the_wind_alternating_widening_and_back_to_the_hits():
    mean = np.array([[20.0, 0.0, 15.0]])
    kw = dict(surge_m=10.0, cast_m=4.0, cast_after=2)
    across = [float(approach_centres(C, mean, UP, HIT_HERE, np.array([d]), **kw)[0, 1]) for d in range(2, 9)]
    assert across == [-4.0, 4.0, -8.0, 8.0, -10.0, 10.0, -10.0]  # sweep grows by cast_m, capped by the surge
    cast = approach_centres(C, mean, UP, HIT_HERE, np.array([2]), **kw)
    assert cast[0, 0] == pytest.approx(30.0)  # a cast does not surge up the wind
    hit_behind = np.array([[33.0, 0.0, 15.0]])
    back = approach_centres(C, mean, UP, hit_behind, np.array([3]), **kw)
    assert back[0, 0] == pytest.approx(33.0)  # past the last hit: back down the wind to it


def test_vertical_move_is_capped():
    mean = np.array([[30.0, 0.0, 25.0]])
    nxt = approach_centres(C, mean, UP, HIT_HERE, np.array([0]), surge_m=10.0, vertical_m=2.0)
    np.testing.assert_allclose(nxt, [[30.0, 0.0, 17.0]])


def _ring(c: np.ndarray) -> np.ndarray:
    return c[:, None, :] + np.array([[4.0, 0.0, 0.0], [-4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, -4.0, 0.0]])[None]


def test_seeker_approaches_after_a_first_hit_while_the_region_is_wide():
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, prior_upwind_deg=30.0, approach_m=3.0,
                  surge_m=6.0, seed=1)
    nxt = s.propose(C, _ring(C), np.zeros((1, 4)))  # no hit yet: the information-seeking candidates
    assert np.isnan(s.hit_enu[0, 0]) and s.dry[0] == 1
    assert np.min(np.linalg.norm(s._candidates(C) - nxt[:, None, :], axis=-1)) < 1e-9
    nxt = s.propose(C, _ring(C), np.array([[0.0, 5.0, 0.0, 0.0]]))  # a hit at (26, 0, 15)
    np.testing.assert_allclose(s.hit_enu, [[26.0, 0.0, 15.0]])
    assert s.dry[0] == 0 and s.region95_m[0] > 3.0
    expected = approach_centres(C, s.estimate_enu, s._upwind(), s.hit_enu, s.dry, surge_m=6.0)
    np.testing.assert_allclose(nxt, expected)
    assert nxt[0, 0] < C[0, 0] - 1.0  # a surge west, up the wind


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


def test_dry_counts_iterations_since_a_hit_and_arguments_are_checked():
    s = SteSeeker(wind_from_deg=270.0, patchy=True, approach_m=3.0, seed=2)
    pos = C[:, None, :] + np.zeros((1, 2, 3))
    s.propose(C, pos, np.zeros((1, 2)))
    s.propose(C, pos, np.zeros((1, 2)))
    assert s.dry[0] == 2
    s.propose(C, pos, np.array([[0.0, 5.0]]))
    assert s.dry[0] == 0
    for kw, name in ((dict(approach_m=0.0), "approach_m"), (dict(surge_m=-1.0), "surge_m"),
                     (dict(cast_after=0), "cast_after"), (dict(cast_after=1.5), "cast_after"),
                     (dict(standoff_m=float("nan")), "standoff_m")):
        with pytest.raises(ValueError, match=name):
            SteSeeker(**kw)


def test_prior_at_first_hit_reseeds_up_the_wind_of_the_first_hit_only(monkeypatch):
    """The prior is the disk about the first centre until a first hit, then the sector up the wind
    of where that hit was read; later hits do not re-seed."""
    s = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, prior_upwind_deg=30.0,
                  prior_at_first_hit=True, seed=6)
    s.propose(C, _ring(C), np.zeros((1, 4)))
    rel = s.parts[0, :, :2] - C[0, :2]
    assert np.mean(rel[:, 0] > 0) > 0.3  # the disk: much of it down the wind (east) of the first centre
    s.propose(C, _ring(C), np.array([[5.0, 0.0, 0.0, 0.0]]))  # the first hit, read at (34, 0, 15)
    rel = s.parts[0, :, :2] - np.array([34.0, 0.0])
    bearing = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
    assert np.mean(np.abs(bearing - 180.0) <= 30.0 + 1e-6) > 0.9  # up the wind (west) of the hit
    calls = []
    monkeypatch.setattr(s, "_reseed_up_of", lambda idx, where: calls.append(idx))
    s.propose(C, _ring(C), np.array([[0.0, 5.0, 0.0, 0.0]]))
    assert calls == []
    with pytest.raises(ValueError, match="prior_at_first_hit"):
        SteSeeker(prior_at_first_hit=True)
