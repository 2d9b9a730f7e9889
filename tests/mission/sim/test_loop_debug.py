"""No callback of the ground station's event loop is slow: a whole lock-step ``swarmseek run`` with
asyncio's debug mode on (``PYTHONASYNCIODEBUG=1``: ``loop.set_debug(True)``, ``slow_callback_duration``
0.1 s) must log no ``Executing <callback> took X seconds`` warning on the ``asyncio`` logger.

What is measured, and why (``tests/mission/sim/slow_callbacks.py`` does it): asyncio's own check times a
callback with ``loop.time()``, which on the lock-step loop is simulated time and never moves during
a callback; and wall time on a loaded 2-core machine counts the time the OS kept the thread
waiting for a core. So each callback is also timed by what it did to the loop's thread: its CPU
time (``time.thread_time``: the code's work, e.g. a CVT solve or a first import) and its blocked
time (wall minus CPU minus run-queue wait from ``/proc/thread-self/schedstat``: a ``time.sleep``,
a DNS lookup, ``zenoh.open``), each against the 0.1 s limit, logged in asyncio's words. Work the
lock-step loop runs inline for ``run_in_executor`` (a worker thread on the wall clock) is not
counted. The mission runs in a fresh interpreter, so first imports happen where the command does
them. Blocked time can still come from the machine (a page fault or an ``fsync`` waiting on a busy
disk): a run that logs slow callbacks is repeated once (the lock-step run is deterministic: the
same callbacks in the same order), and the test fails on a callback slow in both runs.

Found and fixed with it: the formation's CVT solve (0.2 s of CPU, twice: the preflight's path
check and the takeoff's slot plan) ran in the loop, now in the executor
(``mission.flight.targets.solve_formation``); ``zenoh.open`` blocked the loop 0.5 s (now
``mission.core.zenoh_open.open_session``); the coordinator's modules were first imported inside
the loop (0.3 s), now with the command's module.
"""
from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mission.sim.lockstep import LockstepEventLoop, VirtualClock
from tests.mission.sim.slow_callbacks import CallbackTimer

ROOT = Path(__file__).resolve().parents[3]


def _burn_cpu_s(dt_s: float) -> None:
    t0 = time.thread_time()
    while time.thread_time() - t0 < dt_s:
        pass


def test_the_timer_catches_busy_and_blocked_callbacks_but_not_executor_work():
    """The check can fail: a callback that burns 0.15 s of CPU and one that sleeps 0.15 s are
    slow; 0.15 s of CPU handed to ``run_in_executor`` (inline on the lock-step loop) is not."""
    async def main():
        loop = asyncio.get_running_loop()
        loop.call_soon(_burn_cpu_s, 0.15)
        loop.call_soon(time.sleep, 0.15)
        await asyncio.sleep(0)
        await loop.run_in_executor(None, _burn_cpu_s, 0.15)
        await asyncio.sleep(0.01)

    loop = LockstepEventLoop(VirtualClock())
    loop.set_debug(True)
    loop.slow_callback_duration = 0.1
    try:
        with CallbackTimer() as timer:
            loop.run_until_complete(main())
    finally:
        loop.close()
    slow = sorted(s["callback"].split("(")[0] for s in timer.slow)
    assert slow == ["<Handle _burn_cpu_s", "<Handle sleep"], timer.slow
    by_name = {s["callback"].split("(")[0]: s for s in timer.slow}
    assert by_name["<Handle _burn_cpu_s"]["cpu_s"] >= 0.15
    if timer._wait is not None:
        assert by_name["<Handle sleep"]["blocked_s"] >= 0.1


def _debug_run(tmp_path: Path, k: int) -> dict:
    report = tmp_path / f"report-{k}.json"
    cmd = [sys.executable, str(Path(__file__).with_name("slow_callbacks.py")), str(report), "run", "--json",
           "--log-dir", str(tmp_path / f"run-{k}")]
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONASYNCIODEBUG="1")
    p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert report.is_file(), p.stderr[-3000:]
    out = json.loads(report.read_text())
    assert out["status"] == p.returncode == 0, p.stderr[-3000:]
    assert out["debug"] == "1" and out["slow_callback_duration"] == 0.1 and out["timed"] > 1000, out
    return out


def _sites(report: dict) -> set[str]:
    """The slow callbacks of a run, without object addresses (comparable across runs)."""
    return {re.sub(r"0x[0-9a-f]+", "", w.split(" took ")[0]) for w in report["warnings"]}


@pytest.mark.slow
@pytest.mark.timeout(1300)
def test_no_callback_of_a_lockstep_mission_is_slow(tmp_path):
    first = _debug_run(tmp_path, 1)
    if not first["warnings"]:
        return
    second = _debug_run(tmp_path, 2)
    both = _sites(first) & _sites(second)
    assert not both, "slow in both runs:\n" + "\n".join(sorted(both)) + "\n" + json.dumps(
        {"first": first["slow"], "second": second["slow"]}, indent=1)
