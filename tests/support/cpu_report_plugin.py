"""``--cpu-report PATH``: the CPU seconds each test costs, beside its wall seconds.

On the 2-core CI machine the suite's length is bounded below by its CPU: ``pytest --durations``
says which tests take long, not which ones keep the cores busy (a real-SITL mission waits on the
autopilots' real time; a lock-step mission computes all the time). With ``--cpu-report PATH``
every test's setup, call and teardown are measured with :func:`os.times` around them: the test
process's own user and system time plus that of the child processes it waited for (SITL
autopilots, ``swarmseek`` subprocesses, sensors), and appended to ``PATH`` as one JSON line per
test (``nodeid``, ``wall_s``, ``cpu_s``; ``start_unix_s`` and ``worker``: when and where it ran).
Under xdist every worker appends to the same file (one ``write`` per line, opened in append mode). At the end the session prints the tests that
cost the most CPU, the CPU total and the share of it in the listed tests.

A child that is still running when its test ends (a module fixture's fleet) is counted by the test
during which it is reaped; a grandchild whose parent never waits for it is not counted.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

#: where the session keeps the report's path (``config.stash``)
PATH_KEY = pytest.StashKey[Path]()
#: how many of the costliest tests the summary lists
TOP_N = 25


def pytest_addoption(parser):
    """The ``--cpu-report PATH`` option."""
    parser.addoption("--cpu-report", default=None, metavar="PATH",
                     help="append each test's CPU seconds (its process and the children it waited for) "
                          "and wall seconds to PATH as JSON lines, and list the costliest at the end")


def _cpu_s() -> float:
    """User + system seconds of this process and of its waited-for children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def pytest_configure(config):
    """Remember the report's path; the controller (or the only process) starts it empty."""
    path = config.getoption("--cpu-report")
    if path is None:
        return
    path = Path(path).resolve()
    if path.is_dir():
        raise SystemExit(f"pytest: --cpu-report must name a file, not the directory {path}")
    config.stash[PATH_KEY] = path
    if not hasattr(config, "workerinput"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Measure one test's setup, call and teardown together."""
    path = item.config.stash.get(PATH_KEY, None)
    if path is None:
        yield
        return
    start, wall0, cpu0 = time.time(), time.monotonic(), _cpu_s()
    yield
    worker = getattr(item.config, "workerinput", {}).get("workerid", "main")
    line = json.dumps({"nodeid": item.nodeid, "wall_s": round(time.monotonic() - wall0, 3),
                       "cpu_s": round(_cpu_s() - cpu0, 3), "start_unix_s": round(start, 3), "worker": worker})
    with open(path, "a", encoding="utf-8") as out:
        out.write(line + "\n")


def read_report(path: Path) -> list[dict]:
    """The report's records, costliest CPU first.

    Parameters
    ----------
    path : Path
        A file written by ``--cpu-report``.

    Returns
    -------
    list of dict
        One record per test (``nodeid``, ``wall_s``, ``cpu_s``), sorted by ``cpu_s`` descending.
    """
    records = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    return sorted(records, key=lambda r: r["cpu_s"], reverse=True)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """List the costliest tests by CPU (controller only)."""
    path = config.stash.get(PATH_KEY, None)
    if path is None or hasattr(config, "workerinput") or not path.exists():
        return
    records = read_report(path)
    total_cpu = sum(r["cpu_s"] for r in records)
    total_wall = sum(r["wall_s"] for r in records)
    top = records[:TOP_N]
    tr = terminalreporter
    tr.write_sep("=", f"CPU report: {len(records)} tests, {total_cpu:.1f} CPU s, {total_wall:.1f} test-wall s ({path})")
    for r in top:
        tr.write_line(f"{r['cpu_s']:8.2f} CPU s {r['wall_s']:8.2f} wall s  {r['nodeid']}")
    if total_cpu > 0:
        share = sum(r["cpu_s"] for r in top) / total_cpu
        tr.write_line(f"the {len(top)} listed: {100 * share:.0f} % of the CPU")
