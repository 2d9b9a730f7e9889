"""Test ordering for the three pytest-xdist workers (``-n 3 --dist loadfile``, pyproject.toml).

The longest files (real-SITL missions, conformance against real firmware, wall-clock ground-station
processes: 40-180 s a test) are handed out first, so that the short files fill the other worker
around them instead of the workers ending on one long file each. Three workers on two cores: the
real-SITL and wall-clock files mostly wait on real time (the whole suite used about 1.1 cores on
average with two workers). Order only: every test runs.
"""
from __future__ import annotations

#: the files of the longest tests, longest first (``python -m pytest --durations=40``)
LONG_FIRST = ("test_sitl_faults_px4.py", "test_sitl_faults_ardupilot.py", "test_map_fly.py", "test_sitl_ardupilot.py",
              "test_sitl_px4.py", "test_conformance_px4.py", "test_map_browser.py", "test_ctl_processes.py",
              "test_gcs_faults_signals.py", "test_conformance_ap_failsafes.py", "test_conformance_px4_failsafes.py",
              "test_layers.py",
              "test_conformance_ardupilot.py", "test_gcs_faults_output.py")


def pytest_collection_modifyitems(session, config, items):
    """Put the files of :data:`LONG_FIRST` first, in that order; the rest keep theirs."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    order = {id(item): i for i, item in enumerate(items)}
    items.sort(key=lambda item: (rank.get(item.path.name, len(LONG_FIRST)), order[id(item)]))
