"""``--cpu-report PATH`` (tests/support/cpu_report_plugin.py): each test's CPU, its children's included."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from tests.support.inner_session import run_inner_session

INNER_TEST = '''
import subprocess
import sys
import time

SPIN = "import time\\nt0 = time.process_time()\\nwhile time.process_time() - t0 < 0.6:\\n    pass\\n"


def test_spins_in_a_child():
    subprocess.run([sys.executable, "-c", SPIN], check=True)


def test_waits():
    time.sleep(0.3)
'''


def _run_inner(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return run_inner_session(tmp_path, "cpu_report_plugin", INNER_TEST, *args)


@pytest.mark.parametrize("workers", [[], ["-n", "2"]], ids=["one-process", "xdist"])
def test_the_report_counts_a_child_process_cpu_and_not_a_wait(tmp_path, workers):
    report = tmp_path / "out" / "cpu.jsonl"
    run = _run_inner(tmp_path, "--cpu-report", str(report), *workers)
    assert run.returncode == 0, run.stdout + run.stderr
    records = {r["nodeid"].split("::")[-1]: r for r in map(json.loads, report.read_text().splitlines())}
    assert set(records) == {"test_spins_in_a_child", "test_waits"}
    # the child spun 0.6 s of its own CPU: counted once waited for
    assert records["test_spins_in_a_child"]["cpu_s"] >= 0.55
    # a sleep costs wall, not CPU (loaded or not)
    assert records["test_waits"]["wall_s"] >= 0.3
    assert records["test_waits"]["cpu_s"] < 0.25
    # when and where: the sleeping test started no earlier than the session and ran on a named worker
    assert all(r["start_unix_s"] > 1.7e9 for r in records.values())
    assert {r["worker"] for r in records.values()} <= ({"main"} if not workers else {"gw0", "gw1"})
    assert "CPU report: 2 tests" in run.stdout
    assert "test_spins_in_a_child" in run.stdout.split("CPU report:")[1]


def test_a_directory_is_refused(tmp_path):
    run = _run_inner(tmp_path, "--cpu-report", str(tmp_path))
    assert run.returncode != 0
    assert "--cpu-report must name a file, not the directory" in run.stdout + run.stderr
