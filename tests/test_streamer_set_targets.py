"""``SetpointStreamer.set_targets`` (the safety gate's batch, every tick) sets what ``set_target``
one by one sets, and fails the same way."""
from __future__ import annotations

import numpy as np
import pytest

from mission.vehicle.streamer import SetpointStreamer


class _Vehicle:
    def __init__(self, sysid):
        self.sysid = sysid

    def send_position_enu(self, position_enu_m, yaw_rad=None):
        pass


def _pair(n=7):
    return (SetpointStreamer([_Vehicle(s) for s in range(1, n + 1)], rate_hz=10.0),
            SetpointStreamer([_Vehicle(s) for s in range(1, n + 1)], rate_hz=10.0))


def _state(streamer, sysids):
    return [(streamer.target(s), streamer._tracks[s].yaw) for s in sysids]


@pytest.mark.parametrize("seed", range(20))
def test_a_batch_sets_what_one_by_one_sets(seed):
    """Random batches (floats of every size, a subset of the vehicles in any order, after targets
    with a yaw): the same targets (same float tuples) and yaws as ``set_target`` per row."""
    rng = np.random.default_rng(seed)
    batch_streamer, plain = _pair()
    for st in (batch_streamer, plain):
        st.set_target(3, (1.0, 2.0, 3.0), yaw_rad=0.5)
    sysids = [int(s) for s in rng.permutation(np.arange(1, 8))[:rng.integers(1, 8)]]
    rows = rng.normal(0.0, 10.0 ** rng.integers(-3, 6), (len(sysids), 3))
    batch_streamer.set_targets(sysids, rows)
    for s, p in zip(sysids, rows):
        plain.set_target(s, p)
    assert _state(batch_streamer, range(1, 8)) == _state(plain, range(1, 8))
    assert all(type(x) is float for s in sysids for x in batch_streamer.target(s))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_row_fails_as_one_by_one(bad):
    """The rows before the bad one are set, the error is set_target's."""
    batch_streamer, plain = _pair()
    rows = np.arange(12.0).reshape(4, 3)
    rows[2, 1] = bad
    with pytest.raises(ValueError) as batch_err:
        batch_streamer.set_targets([1, 2, 3, 4], rows)
    with pytest.raises(ValueError) as plain_err:
        for s, p in zip([1, 2, 3, 4], rows):
            plain.set_target(s, p)
    assert str(batch_err.value) == str(plain_err.value)
    assert _state(batch_streamer, range(1, 8)) == _state(plain, range(1, 8))


def test_an_unknown_vehicle_fails_as_one_by_one():
    batch_streamer, plain = _pair()
    rows = np.ones((3, 3))
    with pytest.raises(KeyError) as batch_err:
        batch_streamer.set_targets([1, 99, 2], rows)
    with pytest.raises(KeyError) as plain_err:
        for s, p in zip([1, 99, 2], rows):
            plain.set_target(s, p)
    assert str(batch_err.value) == str(plain_err.value)
    assert _state(batch_streamer, range(1, 8)) == _state(plain, range(1, 8))


def test_a_batch_of_the_wrong_shape_is_refused():
    streamer, _ = _pair()
    with pytest.raises(ValueError, match=r"\(2, 3\)"):
        streamer.set_targets([1, 2], np.ones((3, 3)))
