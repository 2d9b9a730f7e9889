"""``--cpu-hogs N``: run the test session beside N CPU-bound processes (the suite under load).

A field laptop is rarely idle, and a test that only passes on a quiet machine hides a timing
assumption. ``python -m pytest --cpu-hogs 2`` starts two processes that spin on the CPU for the
whole session (on the 2-core CI machine: the tests get what is left) and stops them at the end,
pass or fail. Under xdist only the controller starts them. Each hog also ends by itself when the
pytest process that started it is gone, so a killed session leaves none behind.

The hogs' process ids are in the environment variable ``SWARMSEEK_CPU_HOG_PIDS`` (comma-separated)
of every test, and the session's summary says how many ran.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: environment variable naming the hogs' process ids, for the tests of this plugin
PIDS_ENV = "SWARMSEEK_CPU_HOG_PIDS"

#: where the session keeps its hogs (``config.stash``)
HOGS_KEY = pytest.StashKey[list]()

#: the hog: spin; every few million steps check that the parent (pytest) is still there
HOG_CODE = (
    "import os\n"
    "parent = os.getppid()\n"
    "while os.getppid() == parent:\n"
    "    for _ in range(2_000_000):\n"
    "        pass\n"
)


def pytest_addoption(parser):
    """The ``--cpu-hogs N`` option."""
    parser.addoption("--cpu-hogs", type=int, default=0, metavar="N",
                     help="run the session beside N CPU-bound processes (the suite under load; "
                          "the CI machine has 2 cores, so 2 takes about everything a worker would get)")


def pytest_configure(config):
    """Start the hogs (in the xdist controller, or the only pytest process)."""
    n = config.getoption("--cpu-hogs")
    if n < 0:
        raise SystemExit(f"pytest: --cpu-hogs must be 0 or more, not {n}")
    config.stash[HOGS_KEY] = []
    if n == 0 or hasattr(config, "workerinput"):
        return
    hogs = [subprocess.Popen([sys.executable, "-c", HOG_CODE], stdin=subprocess.DEVNULL)
            for _ in range(n)]
    config.stash[HOGS_KEY] = hogs
    os.environ[PIDS_ENV] = ",".join(str(p.pid) for p in hogs)


def pytest_report_header(config):
    """Say on the first lines that the session runs under load."""
    hogs = config.stash.get(HOGS_KEY, [])
    if hogs:
        return f"under load: {len(hogs)} CPU-bound process{'es' if len(hogs) != 1 else ''} beside the tests (--cpu-hogs)"
    return None


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Repeat it in the summary, next to the result."""
    hogs = config.stash.get(HOGS_KEY, [])
    if hogs:
        terminalreporter.write_line(f"ran beside {len(hogs)} CPU-bound process{'es' if len(hogs) != 1 else ''} "
                                    f"(--cpu-hogs {len(hogs)})")


def pytest_unconfigure(config):
    """Stop the hogs, whatever the outcome."""
    for hog in config.stash.get(HOGS_KEY, []):
        hog.kill()
        hog.wait(timeout=10)
    config.stash[HOGS_KEY] = []
