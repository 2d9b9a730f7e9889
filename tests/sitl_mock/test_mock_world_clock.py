"""The simulated world's scaled wall clock: SimClock."""
from __future__ import annotations

import asyncio
import math
import threading
import time

import pytest

from sitl_mock.clock import SimClock


@pytest.mark.parametrize("speedup", [1.0, 10.0, 50.0])
def test_simclock_runs_speedup_times_faster_than_wall(speedup):
    clock = SimClock(speedup=speedup, t0_s=1000.0)
    wa = time.monotonic()
    s0 = clock.time()
    w0 = time.monotonic()
    deadline = w0 + 5.0
    while time.monotonic() - w0 < 0.05 and time.monotonic() < deadline:
        pass  # let some wall time pass (polling, no sleep)
    w1 = time.monotonic()
    s1 = clock.time()
    wb = time.monotonic()
    assert s0 >= 1000.0
    # the simulated interval is bracketed by speedup times the wall intervals around it
    assert speedup * (w1 - w0) - 1e-6 <= s1 - s0 <= speedup * (wb - wa) + 1e-6


def test_simclock_default_t0_is_unix_time():
    before = time.time()
    clock = SimClock()
    assert clock.speedup == 1.0
    assert before - 1.0 <= clock.time() <= time.time() + 1.0


@pytest.mark.parametrize("speedup", [0.0, -1.0, math.inf, math.nan])
def test_simclock_rejects_bad_speedup(speedup):
    with pytest.raises(ValueError, match="speedup"):
        SimClock(speedup=speedup)


@pytest.mark.parametrize("speedup", [20.0, 100.0])
def test_simclock_sleeps_simulated_time(speedup):
    clock = SimClock(speedup=speedup)
    t0 = clock.time()
    clock.sleep_blocking(1.0)
    assert clock.time() - t0 >= 1.0 - 1e-6
    t1 = clock.time()
    asyncio.run(clock.sleep(1.0))
    assert clock.time() - t1 >= 1.0 - 1e-6


def test_simclock_rejects_nonfinite_sleep():
    with pytest.raises(ValueError, match="finite"):
        SimClock().sleep_blocking(math.nan)
