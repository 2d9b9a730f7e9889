"""The real-SITL files run on one xdist worker, one after another (tests/conftest.py,
``pytest_xdist_make_scheduler``).

Runs pytest on the fleet files plus two short mock files, with the SITL variables and ``CI`` removed
so the fleet tests skip at once, and reads which worker ran each test (``-v``); the conformance files
(whose mock sessions would run without SITL) are checked through the scope function itself.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

from tests.conftest import (CONFORMANCE_SITL_FILES, FLEET_FILES, SITL_UNIT, TESTS_DIR, WALL_CLOCK_FILES,
                            WALL_CLOCK_UNIT, unit_scope)

_ROOT = Path(__file__).resolve().parents[2]
_OTHERS = ("tests/wire/test_fleet_names.py", "tests/repo/test_no_issue_numbers.py")  # short, CPU-light


def _workers_by_file() -> dict[str, set[str]]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("CI", "SWARMSEEK_PX4_SITL", "SWARMSEEK_ARDUPILOT_SITL", "SWARMSEEK_CPU_HOG_PIDS",
                        "PYTEST_ADDOPTS")}
    files = [f"tests/{name}" for name in FLEET_FILES] + list(_OTHERS)
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-v", "-n", "2",
                           "--dist", "loadfile", "-m", "not unstable_mission", *files],
                          cwd=_ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    where: dict[str, set[str]] = defaultdict(set)
    for m in re.finditer(r"\[(gw\d+)\] \[\s*\d+%\] \w+ (tests/[^:\s]+)::", done.stdout):
        where[m.group(2)].add(m.group(1))
    return where


def test_the_fleet_files_share_one_worker():
    where = _workers_by_file()
    fleet = [f"tests/{name}" for name in FLEET_FILES]
    assert set(fleet) <= set(where), sorted(where)
    assert len(set().union(*(where[f] for f in fleet))) == 1, {f: where[f] for f in fleet}
    assert set(_OTHERS) <= set(where), sorted(where)  # the others ran too


def test_the_conformance_files_join_the_fleets_unit_and_no_other_file_does():
    for name in FLEET_FILES + CONFORMANCE_SITL_FILES:
        assert (TESTS_DIR / name).is_file(), name
        assert unit_scope(_ROOT, f"tests/{name}") == SITL_UNIT, name
    for name in ("tests/conformance/test_conformance_compare.py", "tests/formation/test_geodesy.py", *_OTHERS):
        assert unit_scope(_ROOT, name) == name


def test_the_wall_clock_files_are_one_unit_of_their_own():
    for name in WALL_CLOCK_FILES:
        assert (TESTS_DIR / name).is_file(), name
        assert unit_scope(_ROOT, f"tests/{name}") == WALL_CLOCK_UNIT, name
    assert not set(WALL_CLOCK_FILES) & set(FLEET_FILES + CONFORMANCE_SITL_FILES)
