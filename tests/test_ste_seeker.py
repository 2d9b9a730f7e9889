"""The source-term-estimation seeker (estimator.ste): posterior, zeros as information, collapse, region."""
from __future__ import annotations

import numpy as np
import pytest

import formation
from estimator.seekers import cap_move, make_seeker
from estimator.ste import SteSeeker
from estimator.ste_model import plume_mean
from sitl_mock.fields import make_field

SOURCE = np.array([0.0, 0.0, 15.0])
OFFSETS = formation.cvt_sphere(8, 4.0, seed=0)


def _fly(seeker: SteSeeker, field, iterations: int, start=(25.0, 1.0, 13.0)) -> list:
    """Noise-free readings of ``field`` along the seeker's own path (K = 1); the region per iteration."""
    c = np.asarray(start, dtype=float)[None]
    regions = []
    for _ in range(iterations):
        pos = c[:, None, :] + OFFSETS[None]
        nxt = seeker.propose(c, pos, field.value(pos))
        regions.append(float(seeker.region95_m[0]))
        c = cap_move(c, nxt, 20.0)
    return regions


def test_make_seeker_builds_ste_and_checks_arguments():
    assert isinstance(make_seeker("ste", wind_from_deg=270.0), SteSeeker)
    with pytest.raises(ValueError, match="ste"):
        make_seeker("nope")
    with pytest.raises(ValueError, match="temper"):
        SteSeeker(temper=0.0)
    with pytest.raises(ValueError, match="stability"):
        SteSeeker(stability="Q")
    with pytest.raises(ValueError, match="particles"):
        SteSeeker(particles=0)


def test_posterior_concentrates_on_the_source_and_its_region_shrinks():
    field = make_field("plume", SOURCE, background=0.0)
    seeker = SteSeeker(wind_from_deg=270.0, seed=3)
    regions = _fly(seeker, field, 60)
    err = float(np.linalg.norm(seeker.estimate_enu[0] - SOURCE))
    assert err < 1.0, (err, regions[-1])
    assert err <= regions[-1]  # the truth inside the reported 95 % region
    assert regions[-1] < 2.0 and regions[-1] < 0.1 * regions[0], regions
    assert seeker.collapses[0] == 0


def test_region_shrinks_with_more_data():
    field = make_field("plume", SOURCE, background=0.0)
    seeker = SteSeeker(wind_from_deg=270.0, seed=5)
    regions = _fly(seeker, field, 40)
    assert np.median(regions[-5:]) < 0.5 * np.median(regions[:5]), regions


def _mass_reader_in_plume(seeker: SteSeeker, reader: np.ndarray) -> float:
    """Posterior mass of the sources that put ``reader`` in the plume (mean > 0.1)."""
    mu, _ = plume_mean(seeker.parts, reader, **seeker.model)
    return float(np.exp(seeker.logw[0])[mu[0, :, 0] > 0.1].sum())


@pytest.mark.parametrize("patchy, zeros, factor", [(False, 1, 0.5), (True, 1, 0.95), (True, 5, 0.7)])
def test_a_zero_reading_lowers_the_probability_near_the_reader(patchy, zeros, factor):
    """One zero of a steady plume is strong evidence; of an intermittent one weak (a puff plume
    reads zero 40 % of the time on its axis), but it still counts, and zeros add up."""
    kw = dict(wind_from_deg=270.0, patchy=patchy, particles=4000, prior_radius_m=15.0, prior_height_m=3.0, seed=1)
    c = np.array([[10.0, 0.0, 15.0]])
    reader = c[:, None, :]  # one vehicle at the centre
    prior = SteSeeker(**kw)
    prior._init_state(c)
    before = _mass_reader_in_plume(prior, reader)
    assert before > 0.01
    seeker = SteSeeker(**kw)
    for _ in range(zeros):
        seeker.propose(c, reader, np.zeros((1, 1)))
    assert _mass_reader_in_plume(seeker, reader) < factor * before


def test_collapse_reseeds_about_the_formation_and_is_counted():
    seeker = SteSeeker(wind_from_deg=270.0, seed=2)
    c = np.array([[30.0, 5.0, 14.0]])
    pos = c[:, None, :] + OFFSETS[None]
    seeker.propose(c, pos, np.zeros((1, 8)))
    assert seeker.collapses[0] == 0 and not seeker.collapsed[0]
    c2 = np.array([[60.0, -20.0, 14.0]])
    pos2 = c2[:, None, :] + OFFSETS[None]
    nxt = seeker.propose(c2, pos2, np.full((1, 8), 1.0e4))  # no particle can explain these readings
    assert seeker.collapses[0] == 1 and seeker.collapsed[0]
    assert not seeker.arrival[0]  # a re-seeded posterior does not report arrival
    assert np.all(np.isfinite(nxt)) and np.all(np.isfinite(seeker.estimate_enu))
    horizontal = np.linalg.norm(seeker.parts[0, :, :2] - c2[0, :2], axis=1)
    assert np.all(horizontal <= seeker.prior_radius_m + 1.0)  # re-seeded about the new centre
    seeker.propose(c2, pos2, np.zeros((1, 8)))
    assert seeker.collapses[0] == 1 and not seeker.collapsed[0]


def test_estimate_is_always_reported_with_its_region():
    field = make_field("intermittent", SOURCE, seed=4)
    seeker = SteSeeker(patchy=True, seed=0)
    assert seeker.estimate_enu is None and seeker.region95_m is None
    c = np.array([[20.0, 0.0, 15.0], [30.0, 2.0, 14.0]])
    for t in range(5):
        pos = c[:, None, :] + OFFSETS[None]
        c = cap_move(c, seeker.propose(c, pos, field.value(pos, t * 1.0)), 20.0)
        assert seeker.estimate_enu.shape == (2, 3) and np.all(np.isfinite(seeker.estimate_enu))
        assert seeker.region95_m.shape == (2,) and np.all(seeker.region95_m > 0)
        assert seeker.arrival.shape == (2,)
    seeker.reset()
    assert seeker.estimate_enu is None and seeker.region95_m is None


def test_deterministic_for_a_seed():
    field = make_field("plume", SOURCE, background=0.0)
    runs = []
    for seed in (7, 7, 8):
        seeker = SteSeeker(seed=seed)
        _fly(seeker, field, 6)
        runs.append(seeker.estimate_enu.copy())
    assert np.array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])
