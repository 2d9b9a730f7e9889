"""Test ordering for the four pytest-xdist workers (``-n 4 --dist loadfile``, pyproject.toml).

Two work units (``pytest_xdist_make_scheduler``), each run by one worker, one file after another,
at a higher CPU priority (``_real_time_priority``, tests/support/priority.py): the real-SITL files
(fleets and conformance checks against real firmware, never two autopilot sets at once) and the
files whose mock missions run against the wall clock in processes of their own
(``WALL_CLOCK_FILES``). The other two workers run the lock-step missions and the rest, which only
take longer when starved; real firmware and wall-clock missions misbehave (a PX4 fleet's mission
ended at its takeoff on CI's loaded machine; when the wall-clock files ran side by side at the start
of a session, a page load took over 30 s). The files of ``ALONE_FILES`` (a PX4 SIH fleet: 1.4 cores
of 2) run with no other test beside them (tests/support/quiet_room.py). The longest files (the
units first) are handed out first, so that the short files fill the other workers around them.
Order only: every test runs. pytest-xdist hands files out in this order only with
``--no-loadscope-reorder`` (pyproject.toml): by default (since 3.5) it sorts them by their number
of tests, most first, which puts a long file of few tests behind the many short ones.

The suite is laid out like the code (``tests/__init__.py``); fixtures shared by one folder are in
that folder's ``conftest.py``.
"""
from __future__ import annotations

#: ``--cpu-hogs N``: the suite beside N CPU-bound processes (tests/support/cpu_hogs_plugin.py);
#: ``--cpu-report PATH``: each test's CPU seconds (tests/support/cpu_report_plugin.py)
pytest_plugins = ["tests.support.cpu_hogs_plugin", "tests.support.cpu_report_plugin"]

import sys
from pathlib import Path

import pytest

from tests.support.bytecode import compile_sources, rewrite_tests
from tests.support.priority import BOOST, SITL_BOOST, raised_priority
from tests.support.quiet_room import QuietRoom

TESTS_DIR = Path(__file__).resolve().parent

#: the real-SITL files whose fleet runs alone (``_alone``, tests/support/quiet_room.py): four PX4 SIH
#: autopilots at 3x real time need about 1.4 of CI's 2 cores; beside three workers' mock missions,
#: their higher priority notwithstanding, a PX4 mission failed in two CI runs in a row
ALONE_FILES = ("sitl/test_sitl_resume_px4.py", "sitl/test_sitl_px4.py")
#: the real-SITL files that fly a fleet (2-6 autopilot processes, a core or more between them)
FLEET_FILES = ("sitl/test_sitl_faults_ardupilot_link.py", "sitl/test_sitl_faults_ardupilot.py",
               "sitl/test_sitl_ardupilot.py", "sitl/test_sitl_faults_px4.py") + ALONE_FILES
#: the conformance files that run one real SITL autopilot beside a mock session in real time
CONFORMANCE_SITL_FILES = ("conformance/test_conformance_px4_hold_failsafes.py",
                          "conformance/test_conformance_px4_failsafes.py", "conformance/test_conformance_px4.py",
                          "conformance/test_conformance_ardupilot.py", "conformance/test_conformance_ap_failsafes.py")
#: one work unit, so one worker runs them one after another. Two or three fleets at once on 2 cores
#: starved each other (a PARAM_SET unanswered for 20 s, a mission over before its fault was injected);
#: a conformance check beside a PX4 fleet (1.7 cores) once saw real PX4 refuse OFFBOARD, and its mock
#: session, starved, react 7.3 s late and not start its RTL in 60 s
#: (the files that run alone last: by then the other workers run shorter tests, which end sooner when
#: the room is to be emptied for them)
ONE_SITL_AT_A_TIME = tuple(f for f in FLEET_FILES if f not in ALONE_FILES) + CONFORMANCE_SITL_FILES + ALONE_FILES
#: the scope of that work unit
SITL_UNIT = "real-SITL autopilots"
#: files whose mock missions run against the wall clock in processes of their own (``fly``, ``run --speedup``,
#: ``ctl``/``watch``, the map): starved, their vehicles land late (a mock vehicle left airborne at the end,
#: twice in one fresh-clone run once the real-SITL unit alone had the higher priority)
WALL_CLOCK_FILES = ("mission/telemetry/test_map_browser.py", "mission/flight/test_gcs_faults_signals.py",
                    "mission/flight/test_gcs_faults_output.py", "mission/telemetry/test_ctl_processes.py",
                    "mission/telemetry/test_ctl_processes_routed.py", "mission/telemetry/test_map_fly.py")
#: the scope of their work unit: one worker runs them one after another (at the start of a session the
#: first of them used to run side by side, with the real-SITL unit: three prioritised workers of four,
#: and two of them failed in one CI run, a page load over 30 s and a seek over before an operator's land)
WALL_CLOCK_UNIT = "wall-clock missions"
#: the files run at a higher CPU priority (``_real_time_priority``): real autopilots and wall-clock missions;
#: the lock-step missions of the other files only take longer when they get less
REAL_TIME_FILES = ONE_SITL_AT_A_TIME + WALL_CLOCK_FILES

#: the files of the longest tests, longest first (``python -m pytest --cpu-report=PATH``: wall and CPU
#: seconds of each test), relative to tests/; the real-SITL unit first (the longest)
LONG_FIRST = ONE_SITL_AT_A_TIME + WALL_CLOCK_FILES + (
    "sitl_mock/test_fields_config.py", "mission/flight/test_sensor_check.py", "mission/sim/test_e2e_mission.py",
    "mission/flight/test_abandon.py", "experiments/test_sweep.py", "mission/flight/test_layers.py")


def unit_scope(rootdir: Path, scope: str) -> str:
    """The xdist scope of a ``--dist loadfile`` scope (a file's node id): :data:`SITL_UNIT` for the
    files of :data:`ONE_SITL_AT_A_TIME`, :data:`WALL_CLOCK_UNIT` for those of :data:`WALL_CLOCK_FILES`,
    else the file itself."""
    relative = _relative(rootdir / scope)
    if relative in ONE_SITL_AT_A_TIME:
        return SITL_UNIT
    return WALL_CLOCK_UNIT if relative in WALL_CLOCK_FILES else scope


@pytest.fixture(scope="module", autouse=True)
def _real_time_priority(request):
    """The files of :data:`REAL_TIME_FILES` run at a higher CPU priority, with every process they
    start (tests/support/priority.py; the real-SITL files higher than the wall-clock ones): module
    scope, so a module fixture's autopilot gets it too.
    Where that is not allowed, a warning in the session's summary says so."""
    if _relative(request.path) not in REAL_TIME_FILES:
        yield
        return
    boost = SITL_BOOST if _relative(request.path) in ONE_SITL_AT_A_TIME else BOOST
    with raised_priority(boost) as refused:
        if refused:
            request.node.warn(pytest.PytestWarning(refused))
        yield


@pytest.fixture(scope="session")
def _quiet_room(request, tmp_path_factory):
    """The session's :class:`~tests.support.quiet_room.QuietRoom` under pytest-xdist (in the directory
    every worker's base temporary directory is in); None in a single process, where tests never
    run side by side."""
    if not hasattr(request.config, "workerinput"):
        return None
    return QuietRoom(tmp_path_factory.getbasetemp().parent / "quiet-room")


@pytest.fixture(scope="module", autouse=True)
def _alone(request, _quiet_room):
    """The files of :data:`ALONE_FILES` run with no other worker's test beside them (module scope:
    before the module's fixtures start an autopilot)."""
    if _quiet_room is None or _relative(request.path) not in ALONE_FILES:
        yield
        return
    with _quiet_room.alone():
        yield


@pytest.fixture(autouse=True)
def _share_the_room(request, _quiet_room):
    """Every other test waits while a file of :data:`ALONE_FILES` runs (or waits to)."""
    if _quiet_room is None or _relative(request.path) in ALONE_FILES:
        yield
        return
    with _quiet_room.shared():
        yield


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with the files of :data:`ONE_SITL_AT_A_TIME` as one work unit."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    rootdir = config.rootpath

    class _OneFleetAtATime(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return unit_scope(rootdir, super()._split_scope(nodeid))

    return _OneFleetAtATime(config, log)


def pytest_configure(config):
    """Refuse to run with a :data:`LONG_FIRST` entry that names no file (a test file moved or renamed);
    in the main process, under ``PYTHONDONTWRITEBYTECODE``, compile the sources once for every worker and
    subprocess, and with workers, the test modules' assertion rewriting once for all of them
    (tests/support/bytecode.py)."""
    missing = [name for name in LONG_FIRST if not (TESTS_DIR / name).is_file()]
    if missing:
        raise pytest.UsageError(f"tests/conftest.py LONG_FIRST names files that do not exist: {', '.join(missing)}")
    if sys.dont_write_bytecode and not hasattr(config, "workerinput"):
        compile_sources(TESTS_DIR.parent)
        if getattr(config.option, "numprocesses", None) and config.getoption("assertmode") == "rewrite":
            if rewrite_tests(TESTS_DIR, config):
                config.issue_config_time_warning(pytest.PytestWarning(
                    "the test modules' rewritten bytecode was not all written: each worker rewrites them"), 2)


def _relative(path: Path) -> str:
    """``path`` relative to tests/ (``/``-separated), or its full path when it is outside."""
    try:
        return path.resolve().relative_to(TESTS_DIR).as_posix()
    except ValueError:
        return str(path)


def pytest_collection_modifyitems(session, config, items):
    """Put the files of :data:`LONG_FIRST` first, in that order; the rest keep theirs."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    order = {id(item): i for i, item in enumerate(items)}
    where = {path: _relative(path) for path in {item.path for item in items}}
    items.sort(key=lambda item: (rank.get(where[item.path], len(LONG_FIRST)), order[id(item)]))
