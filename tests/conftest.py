"""Test ordering for the two pytest-xdist workers (``-n 2 --dist loadfile``, pyproject.toml).

The longest files (real-SITL missions, conformance against real firmware, wall-clock ground-station
processes: 40-180 s a test) are handed out first, so that the short files fill the other worker
around them instead of both workers ending on one long file each. Order only: every test runs.
"""
from __future__ import annotations

#: the files of the longest tests, longest first (``python -m pytest --durations=40``)
LONG_FIRST = ("test_sitl_faults_px4.py", "test_sitl_ardupilot.py", "test_sitl_px4.py", "test_conformance_px4.py",
              "test_ctl_processes.py", "test_gcs_faults_signals.py", "test_layers.py",
              "test_conformance_ardupilot.py", "test_gcs_faults_output.py")


def pytest_collection_modifyitems(session, config, items):
    """Put the files of :data:`LONG_FIRST` first, in that order; the rest keep theirs."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    order = {id(item): i for i, item in enumerate(items)}
    items.sort(key=lambda item: (rank.get(item.path.name, len(LONG_FIRST)), order[id(item)]))
