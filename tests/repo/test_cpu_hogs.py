"""``--cpu-hogs N`` (tests/support/cpu_hogs_plugin.py): the hogs run during the session and are gone after it."""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from tests.support.inner_session import run_inner_session

INNER_TEST = '''
import os
import time
from pathlib import Path


def _cpu_ticks(pid):
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime


def test_the_hogs_spin():
    pids = [int(p) for p in os.environ["SWARMSEEK_CPU_HOG_PIDS"].split(",")]
    Path(os.environ["HOG_PID_FILE"]).write_text(",".join(map(str, pids)))
    assert len(pids) == int(os.environ["HOGS_WANTED"])
    before = [_cpu_ticks(p) for p in pids]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if all(_cpu_ticks(p) > b for p, b in zip(pids, before)):
            return
        time.sleep(0.05)
    raise AssertionError("a hog used no CPU in 60 s")
'''


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def _run_inner(tmp_path: Path, *args: str, hogs_wanted: int = 2) -> subprocess.CompletedProcess:
    env = dict(os.environ, HOG_PID_FILE=str(tmp_path / "pids"), HOGS_WANTED=str(hogs_wanted))
    env.pop("SWARMSEEK_CPU_HOG_PIDS", None)
    return run_inner_session(tmp_path, "cpu_hogs_plugin", INNER_TEST, *args, env=env)


@pytest.mark.parametrize("workers, hogs", [([], 2), (["-n", "2"], 1)], ids=["one-process", "xdist"])
def test_hogs_spin_during_the_session_and_are_gone_after(tmp_path, workers, hogs):
    """Two hogs in one process, one beside xdist workers (each hog spins for the whole inner
    session, the workers' start included: CPU the outer suite pays for)."""
    run = _run_inner(tmp_path, "--cpu-hogs", str(hogs), *workers, hogs_wanted=hogs)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"under load: {hogs} CPU-bound process" in run.stdout
    assert f"ran beside {hogs} CPU-bound process" in run.stdout
    pids = [int(p) for p in (tmp_path / "pids").read_text().split(",")]
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in pids), f"hogs {pids} still running after the session"


def test_a_negative_count_is_refused(tmp_path):
    run = _run_inner(tmp_path, "--cpu-hogs", "-1")
    assert run.returncode != 0
    assert "--cpu-hogs must be 0 or more, not -1" in run.stdout + run.stderr
