"""The source-term-estimation seeker (estimator.ste): posterior, zeros as information, collapse, region."""
from __future__ import annotations

import numpy as np
import pytest

import formation
from estimator.seekers import cap_move, make_seeker
from estimator.ste import SteSeeker
from estimator.ste_model import plume_mean
from sitl_mock.fields_config import make_field

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


class _FixedRadius:
    """A seeker that stays put and asks for a formation radius; records where it was read."""

    name = "fixed-radius"

    def __init__(self, radius_m):
        self.radius_m_asked = radius_m
        self.seen = []

    def reset(self):
        self.formation_radius_m = None
        self.seen = []

    def propose(self, centre, positions, values):
        self.seen.append(np.asarray(positions) - np.asarray(centre)[:, None, :])
        self.formation_radius_m = np.full(len(centre), self.radius_m_asked)
        return np.asarray(centre)


def test_offline_runner_honours_the_formation_radius_and_times_the_vehicles_flights():
    from experiments.offline_seek import StopAndGo, simulate_seeker

    field = make_field("plume", SOURCE, background=0.0)
    starts = np.array([[20.0, 0.0, 15.0], [30.0, 2.0, 14.0]])
    seeker = _FixedRadius(2.0)
    run = simulate_seeker(OFFSETS, field, starts, seeker, gamma_m=20.0, iterations=3, seed=1)
    radii = [np.linalg.norm(off, axis=-1) for off in seeker.seen]
    assert np.allclose(radii[0], 4.0) and np.allclose(radii[1], 2.0) and np.allclose(radii[2], 2.0)
    assert np.allclose(run.radii_m[0], 4.0) and np.allclose(run.radii_m[1:], 2.0)
    t = run.iteration_s(StopAndGo())
    # the first iteration: no centre move, but every vehicle flies 2 m inward to its new slot
    assert np.all(t[0] >= StopAndGo().iteration_s(np.array([2.0, 0.0, 0.0])) - 1e-9)
    assert np.all(t[0] > t[1]) and np.allclose(t[1], StopAndGo().iteration_s(np.zeros(3)))
    # a seeker that does not size the formation keeps the given offsets and the centre-move time
    plain = simulate_seeker(OFFSETS, field, starts, make_seeker("model"), gamma_m=20.0, iterations=3, seed=1)
    assert plain.radii_m is None
    assert np.allclose(plain.iteration_s(StopAndGo()), StopAndGo().iteration_s(plain.moves()))


def test_formation_radius_follows_the_posterior_within_its_bounds():
    from experiments.offline_seek import simulate_seeker

    field = make_field("plume", SOURCE, background=0.0)
    seeker = SteSeeker(wind_from_deg=270.0, seed=3, min_radius_m=1.5, max_radius_m=6.0)
    run = simulate_seeker(OFFSETS, field, np.array([[25.0, 1.0, 13.0]]), seeker, gamma_m=20.0, iterations=60, seed=2)
    r = run.radii_m[1:, 0]
    assert np.all((r >= 1.5 - 1e-9) & (r <= 6.0 + 1e-9))
    assert r[0] == pytest.approx(6.0)  # the prior is wide: the widest formation
    assert r[-1] < 2.0 and seeker.region95_m[0] < 2.0  # tight about the release at the end
    assert np.linalg.norm(run.centres[-1, 0] - SOURCE) < 1.0
    fixed = SteSeeker(wind_from_deg=270.0, radius_gain=0.0)
    _fly(fixed, field, 2)
    assert fixed.formation_radius_m is None


def test_tempering_is_shared_by_readings_that_see_the_same_puffs():
    seeker = SteSeeker(temper=0.4, corr_length_m=1.0)
    spread = (OFFSETS * 4.0)[None]  # 16 m formation: independent readings
    assert np.allclose(seeker._tempers(spread), 0.4, atol=1e-6)
    clustered = np.zeros((1, 4, 3))  # four readings at one point: one reading's worth between them
    assert np.allclose(seeker._tempers(clustered), 0.1)
    assert np.allclose(SteSeeker(temper=0.4, corr_length_m=0.0)._tempers(clustered), 0.4)
    again = SteSeeker(temper=0.4, corr_length_m=1.0, corr_iterations=1)
    again._buf = [(clustered, np.zeros((1, 4)))]  # the last iteration read the same four points
    assert np.allclose(again._tempers(clustered, recent=True), 0.05)
    assert np.allclose(again._tempers(spread, recent=True), 0.4, atol=1e-6)  # elsewhere: not shared
    with pytest.raises(ValueError, match="corr_iterations"):
        SteSeeker(corr_iterations=-1)


def test_deviances_have_the_stated_expectation_when_the_model_holds():
    from estimator.ste_model import deviance_patchy, deviance_steady

    rng = np.random.default_rng(0)
    p = rng.uniform(0.01, 0.9, 20000)
    d, e, var = deviance_patchy(p, rng.uniform(size=p.size) < p)
    z = (d.sum() - e.sum()) / np.sqrt(var.sum())
    assert abs(z) < 4.0
    d_wrong, e_w, var_w = deviance_patchy(p, rng.uniform(size=p.size) < 1.0 - p)  # the hits where misses are due
    assert (d_wrong.sum() - e_w.sum()) / np.sqrt(var_w.sum()) > 20.0
    mu = rng.uniform(0.0, 1.0, 5000)
    d, e, var = deviance_steady(mu, np.full(mu.size, 0.04), mu + 0.2 * rng.standard_normal(mu.size), background=0.0)
    assert abs((d.sum() - e.sum()) / np.sqrt(var.sum())) < 4.0


def test_a_field_the_model_cannot_fit_is_flagged_and_never_reports_arrival():
    """The paper's sigma_2 (a Gaussian blob, no wind): the plume model misfits it."""
    from experiments.offline_seek import simulate_seeker

    field = make_field("sigma2", SOURCE)
    starts = SOURCE + np.array([[20.0, 0.0, 0.0], [0.0, -25.0, 2.0], [-15.0, 15.0, -2.0], [30.0, 10.0, 0.0]])
    runs = {}
    for misfit_z in (4.0, 1e9):  # the default check, and none
        seeker = SteSeeker(seed=4, radius_gain=0.0, casting=False, misfit_z=misfit_z)
        runs[misfit_z] = simulate_seeker(OFFSETS, field, starts, seeker, gamma_m=20.0, iterations=40,
                                         noise_std=0.01, seed=3)
    assert seeker.misfit.shape == (4,) and seeker.fit_z.shape == (4,)
    assert runs[1e9].signal[1:].any()  # without the check: tight, wrong and "arrived"
    assert not runs[4.0].signal[1:].any()  # with it: arrival never reported
    assert np.any(seeker.fit_z > 4.0)


def test_the_model_check_passes_where_the_model_holds():
    field = make_field("plume", SOURCE, background=0.0)
    seeker = SteSeeker(wind_from_deg=270.0, seed=3)
    _fly(seeker, field, 40)
    assert not seeker.misfit[0] and seeker.fit_z[0] < seeker.misfit_z


def test_path_samples_value_the_readings_along_the_way(monkeypatch):
    """With ``path_samples`` = 3 a candidate's information is computed for the formation at 1/3,
    2/3 and all of the way to it (the readings taken while moving), not at its end alone."""
    field = make_field("plume", SOURCE)
    seen = {}
    for samples in (1, 3):
        s = SteSeeker(wind_from_deg=270.0, seed=1, path_samples=samples, radius_gain=0.0)
        orig_hit, orig_cand = s._p_hit, s._candidates
        monkeypatch.setattr(s, "_p_hit", lambda parts, pts, o=orig_hit, k=samples: seen.setdefault(k, pts) is pts and o(parts, pts))
        monkeypatch.setattr(s, "_candidates", lambda c, o=orig_cand, k=samples: seen.setdefault(("cand", k), o(c)))
        c = np.array([[25.0, 1.0, 13.0]])
        s.propose(c, c[:, None, :] + OFFSETS[None], field.value(c[:, None, :] + OFFSETS[None]))
        cand = seen[("cand", samples)][0]
        pts = seen[samples][0].reshape(len(cand), samples, len(OFFSETS), 3)
        for f in range(samples):
            np.testing.assert_allclose(pts[:, f] - OFFSETS[None], np.broadcast_to(
                c[0] + (f + 1) / samples * (cand - c[0]), (len(OFFSETS), len(cand), 3)).transpose(1, 0, 2), atol=1e-9)
    with pytest.raises(ValueError, match="path_samples"):
        SteSeeker(path_samples=0)


def test_an_update_without_readings_changes_nothing_and_warns_nothing():
    """The mission may hand the seeker no reading (all thinned out): the posterior stays as it was."""
    import warnings

    s = SteSeeker(wind_from_deg=270.0, seed=3)
    c = np.array([[25.0, 1.0, 13.0]])
    pos = c[:, None, :] + OFFSETS[None]
    s.propose(c, pos, make_field("plume", SOURCE).value(pos))
    before = s.logw.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        s.propose(c, np.zeros((1, 0, 3)), np.zeros((1, 0)))
    np.testing.assert_array_equal(s.logw, before)
    assert not s.collapsed[0] and np.isfinite(s.region95_m[0])


def test_upwind_prior_puts_the_release_up_each_particles_wind():
    """``prior_upwind_deg``: the first prior's release lies in the sector up the particle's own wind
    from the first centre (wind given or not); a collapse re-seeds from the whole disk."""
    c = np.array([[30.0, 0.0, 15.0]])
    given = SteSeeker(wind_from_deg=270.0, wind_std_deg=0.0, patchy=True, prior_upwind_deg=30.0, seed=4)
    given._init_state(c)
    rel = given.parts[0, :, :2] - c[0, :2]
    bearing = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))  # wind toward east: upwind is west, 180 deg
    assert np.all(np.abs((bearing % 360.0) - 180.0) <= 30.0 + 1e-9)
    assert np.all(np.linalg.norm(rel, axis=1) <= given.prior_radius_m + 1e-9)
    free = SteSeeker(patchy=True, prior_upwind_deg=45.0, seed=4)
    free._init_state(c)
    rel = free.parts[0, :, :2] - c[0, :2]
    up = free.parts[0, :, 4] + np.pi  # each particle's upwind direction
    off = (np.arctan2(rel[:, 1], rel[:, 0]) - up + np.pi) % (2.0 * np.pi) - np.pi
    assert np.all(np.abs(off) <= np.deg2rad(45.0) + 1e-9)
    assert np.ptp(rel[:, 0]) > 100.0 and np.ptp(rel[:, 1]) > 100.0  # marginally the whole disk
    free._seed_prior(np.array([0]), c)  # a re-seed (collapse): the disk, whatever the wind
    rel = free.parts[0, :, :2] - c[0, :2]
    off = (np.arctan2(rel[:, 1], rel[:, 0]) - free.parts[0, :, 4] - np.pi + np.pi) % (2.0 * np.pi) - np.pi
    assert np.mean(np.abs(off) > np.deg2rad(90.0)) > 0.4
    for bad in (0.0, -10.0, 200.0, float("nan")):
        with pytest.raises(ValueError, match="prior_upwind_deg"):
            SteSeeker(prior_upwind_deg=bad)
