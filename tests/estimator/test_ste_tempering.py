"""The ``ste`` seeker's tempering by reading time (estimator.ste_tempering) and the reading-time interface."""
from __future__ import annotations

import numpy as np
import pytest

import formation
from estimator.seekers import GradientSeeker, make_seeker, propose_readings
from estimator.ste import SteSeeker
from estimator.ste_model import plume_mean
from estimator.ste_tempering import shared_counts, time_weights

TAU_S = 5.0
OFFSETS = formation.cvt_sphere(8, 4.0, seed=0)


def _one_sensor(times_s, step_m=0.0):
    t = np.asarray(times_s, dtype=float)
    pos = np.zeros((len(t), 3))
    pos[:, 0] = step_m * np.arange(len(t))
    return t, pos, np.zeros(len(t), dtype=int)


@pytest.mark.parametrize("times_s, total, each", [
    ([0.0, 5.0, 10.0, 20.0], 4.0, 1.0),                    # tau or more apart: 1 each
    ([0.0, 7.5, 100.0], 3.0, 1.0),
    (list(np.arange(10) * 0.05), 1.0 + 0.45 / TAU_S, None),  # a burst within tau: ~1 in total
    (list(np.arange(50) * 0.1), 1.0 + 4.9 / TAU_S, None),    # 10 Hz over 5 s: ~2 (the first and one tau)
])
def test_time_weights_share_one_unit_per_correlation_time(times_s, total, each):
    t, pos, ids = _one_sensor(times_s)
    w = time_weights(t, pos, ids, {}, TAU_S)
    assert w.sum() == pytest.approx(total)
    assert np.all((w > 0) & (w <= 1))
    if each is not None:
        assert np.allclose(w, each)


def test_time_weights_carry_over_updates_and_are_per_sensor():
    last: dict = {}
    t = np.arange(200) * 0.1  # 20 s at 10 Hz, one sensor, in 20 updates of 1 s
    total = sum(time_weights(t[i:i + 10], np.zeros((10, 3)), np.zeros(10, int), last, TAU_S).sum()
                for i in range(0, 200, 10))
    assert total == pytest.approx(1.0 + 19.9 / TAU_S)  # one unit per tau over the whole stream, not per update
    # two sensors reading at the same instants: each its own stream (the cross-sensor share is shared_counts')
    t2 = np.repeat(np.arange(5) * 0.1, 2)
    w2 = time_weights(t2, np.zeros((10, 3)), np.tile([1, 2], 5), {}, TAU_S)
    assert w2.sum() == pytest.approx(2.0 * (1.0 + 0.4 / TAU_S))


def test_time_weights_decorrelate_by_path_and_tau_zero_is_every_reading():
    t, pos, ids = _one_sensor(np.arange(10) * 0.1, step_m=0.3)  # flying 3 m/s, 10 Hz
    assert time_weights(t, pos, ids, {}, TAU_S, corr_path_m=0.3).sum() == pytest.approx(10.0)
    assert time_weights(t, pos, ids, {}, TAU_S, corr_path_m=1.0).sum() == pytest.approx(1.0 + 9 * 0.3)
    assert time_weights(t, pos, ids, {}, 0.0).sum() == 10.0


@pytest.mark.parametrize("other_m, other_dt_s, expect", [(0.0, 0.0, 2.0), (20.0, 0.0, 1.0), (0.0, 3.0, 1.0)])
def test_shared_counts_at_one_instant_and_place(other_m, other_dt_s, expect):
    t = np.array([0.0, other_dt_s])
    pos = np.array([[0.0, 0.0, 10.0], [other_m, 0.0, 10.0]])
    n = shared_counts(t, pos, np.array([1, 2]), 1.0, 0.25)
    assert n == pytest.approx([expect, expect])
    assert np.all(shared_counts(t, pos, np.array([1, 2]), 0.0, 0.25) == 1.0)


def _mass_near(seeker: SteSeeker, reader: np.ndarray) -> float:
    """Posterior mass of the sources that put ``reader`` in the plume (mean > 0.1)."""
    mu, _ = plume_mean(seeker.parts, reader[None, None, :], **seeker.model)
    w = np.exp(seeker.logw[0])
    return float(np.sum(w * (mu[0, :, 0] > 0.1)) / w.sum())


@pytest.mark.parametrize("hits, gain", [(1, 1.03), (5, 1.2)])
def test_a_hit_in_a_burst_is_kept(hits, gain):
    """A burst of 30 readings in 3 s from one vehicle, the last ``hits`` of them hits: the hits
    move the posterior towards sources that put the reader in the plume, by their share of the
    burst (the first-reading thinning dropped them: the posterior of the all-miss burst)."""
    reader = np.array([20.0, 0.0, 13.0])
    pos = np.repeat(reader[None], 30, axis=0)[None]
    t = (np.arange(30) * 0.1)[None]
    masses = []
    for n in (0, hits):
        values = np.zeros((1, 30))
        values[0, 30 - n:] = 0.5
        s = SteSeeker(wind_from_deg=270.0, patchy=True, seed=2)
        s.propose(reader[None], pos, values, times_s=t, sensor_ids=np.zeros((1, 30), int))
        assert np.all(s._buf[-1][3] > 0)  # every reading's weight, the hits' too: never zero
        assert s._buf[-1][3].sum() == pytest.approx(1.0 + 2.9 / TAU_S)  # the burst: ~1 unit
        masses.append(_mass_near(s, reader))
    assert masses[1] > gain * masses[0], masses


def _hover(per_update: int, corr_time_s: float = TAU_S) -> float:
    """The log posterior mass of the sources that put the formation's centre in the plume after 10
    updates 1 s apart of a formation hovering there reading nothing (misses), each update
    ``per_update`` readings per vehicle spread over its second."""
    s = SteSeeker(wind_from_deg=270.0, patchy=True, seed=4, corr_time_s=corr_time_s, radius_gain=0)
    c = np.array([[20.0, 0.0, 13.0]])
    for u in range(10):
        pos = np.tile(c[:, None, :] + OFFSETS[None], (1, per_update, 1))
        t = u + np.repeat(np.arange(per_update) / per_update, 8)[None]
        ids = np.tile(np.arange(8), per_update)[None]
        s.propose(c, pos, np.zeros(pos.shape[:2]), times_s=t, sensor_ids=ids)
    return np.log(_mass_near(s, c[0]))


def test_dense_readings_with_times_are_not_overconfident():
    """Ten readings per vehicle per second with their times give about the posterior of one per
    second; counted as independent (no tempering) the same readings shrink it much further."""
    one = _hover(1)
    dense = _hover(10)
    untempered = _hover(10, corr_time_s=0.0)
    assert abs(dense - one) < 0.5, (dense, one)  # within a factor 1.6 of each other
    assert untempered < one - 10.0, (untempered, one)  # e^-10 less: overconfident


def test_propose_readings_passes_times_only_to_seekers_that_take_them():
    c = np.array([[0.0, 0.0, 10.0]])
    pos = c[:, None, :] + OFFSETS[None]
    v = np.exp(-np.sum(pos ** 2, axis=-1) / 50.0)
    t = np.zeros((1, 8))
    g = propose_readings(GradientSeeker(), c, pos, v, t, np.arange(8)[None])
    assert np.allclose(g, GradientSeeker().propose(c, pos, v))
    ste = make_seeker("ste", wind_from_deg=270.0, patchy=True)
    assert ste.takes_times
    propose_readings(ste, c, pos, np.zeros((1, 8)), t, np.arange(8)[None])
    assert ste._last[0] and set(ste._last[0]) == set(range(8))


def test_the_steady_likelihood_takes_each_sensors_first_reading_of_an_update():
    """Without ``timed`` (the steady likelihood's default) the readings' times pick each sensor's first
    reading of the update and the per-update tempering takes them: the same posterior as being
    given only those (as the mission's thinning did before)."""
    c = np.array([[25.0, 1.0, 13.0]])
    pos = np.tile(c[:, None, :] + OFFSETS[None], (1, 3, 1)) + 0.1 * np.arange(24)[None, :, None]
    v = 0.05 + 0.01 * np.arange(24)[None]
    t = np.repeat(np.arange(3) * 0.1, 8)[None]
    ids = np.tile(np.arange(8), 3)[None]
    a, b = SteSeeker(wind_from_deg=270.0, seed=1), SteSeeker(wind_from_deg=270.0, seed=1)
    assert not a.timed and SteSeeker(patchy=True).timed
    na = a.propose(c, pos, v, times_s=t, sensor_ids=ids)
    nb = b.propose(c, pos[:, :8], v[:, :8])
    np.testing.assert_allclose(na, nb)
    np.testing.assert_allclose(a.logw, b.logw)


@pytest.mark.parametrize("times, ids, match", [
    (np.full((1, 8), np.nan), None, "times_s must be finite"),
    (np.zeros((1, 8)), np.zeros((1, 7), int), "sensor_ids"),
])
def test_bad_times_are_refused(times, ids, match):
    c = np.array([[0.0, 0.0, 10.0]])
    with pytest.raises(ValueError, match=match):
        SteSeeker().propose(c, c[:, None, :] + OFFSETS[None], np.zeros((1, 8)), times_s=times, sensor_ids=ids)
