"""Clocks of the simulated world: SimClock scaling and LockstepClock wake-ups."""
from __future__ import annotations

import asyncio
import math
import threading
import time

import pytest

from sitl_mock.clock import LockstepClock, SimClock


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


def test_lockstep_time_moves_only_on_advance():
    clock = LockstepClock(t0_s=100.0)
    assert clock.speedup == math.inf
    assert clock.time() == 100.0
    assert clock.time() == 100.0
    clock.advance(0.25)
    assert clock.time() == pytest.approx(100.25)


@pytest.mark.parametrize("dt", [-0.1, math.nan, math.inf])
def test_lockstep_rejects_bad_advance(dt):
    with pytest.raises(ValueError, match="advance"):
        LockstepClock().advance(dt)


def test_lockstep_sleep_blocking_wakes_when_advanced_past_deadline():
    clock = LockstepClock(t0_s=0.0)
    woke = threading.Event()
    started = threading.Event()

    def sleeper():
        started.set()
        clock.sleep_blocking(1.0)
        woke.set()

    th = threading.Thread(target=sleeper, daemon=True)
    th.start()
    assert started.wait(10.0)
    clock.advance(0.5)
    assert not woke.wait(0.2)
    clock.advance(0.5)
    assert woke.wait(10.0)
    th.join(10.0)


def test_lockstep_async_sleepers_wake_in_deadline_order():
    clock = LockstepClock(t0_s=0.0)
    order: list[float] = []

    async def sleeper(dt):
        await clock.sleep(dt)
        order.append(dt)

    async def main():
        tasks = [asyncio.create_task(sleeper(dt)) for dt in (0.3, 0.1, 0.2)]
        while clock.pending_sleepers() < 3:
            await asyncio.sleep(0)
        assert clock.next_deadline_s() == pytest.approx(0.1)
        for _ in range(4):
            clock.advance(0.1)
            for _ in range(5):
                await asyncio.sleep(0)
        await asyncio.wait_for(asyncio.gather(*tasks), 10.0)

    asyncio.run(main())
    assert order == [0.1, 0.2, 0.3]
    assert clock.pending_sleepers() == 0


def test_lockstep_async_sleep_woken_from_another_thread():
    clock = LockstepClock(t0_s=0.0)

    async def main():
        task = asyncio.create_task(clock.sleep(2.0))
        while clock.pending_sleepers() < 1:
            await asyncio.sleep(0)
        th = threading.Thread(target=clock.advance, args=(2.0,))
        th.start()
        await asyncio.wait_for(task, 10.0)
        th.join(10.0)
        return clock.time()

    assert asyncio.run(main()) == pytest.approx(2.0)


def test_lockstep_cancelled_sleeper_is_forgotten():
    clock = LockstepClock(t0_s=0.0)

    async def main():
        task = asyncio.create_task(clock.sleep(5.0))
        while clock.pending_sleepers() < 1:
            await asyncio.sleep(0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return clock.pending_sleepers()

    assert asyncio.run(main()) == 0


def test_lockstep_zero_sleep_returns_without_advance():
    clock = LockstepClock(t0_s=0.0)
    clock.sleep_blocking(0.0)
    asyncio.run(asyncio.wait_for(clock.sleep(0.0), 10.0))
    assert clock.time() == 0.0
