"""Fuzzing the command line: random argument lists for every ``swarmseek`` subcommand.

Arguments are drawn from each subcommand's real options (read from its argparse parser: the
option names, their choices) with edge values (negative, zero, NaN, infinities, huge, empty,
unicode, zenoh wildcards, paths that cannot be written) and, for ``--plan``, plan files mutated
from the sample plan. The CLI runs in-process through :func:`mission.cli.main` with its output
captured. Whatever the arguments, it must end with a documented exit status (0, 1, 2 or 3; 2
with a message on stderr) and never with a Python traceback.

Nothing long starts: the step after validation (the mock fleet's start, the vehicles' connection,
the zenoh session, the SITL launch, the paper's and the simulation's computations) is replaced by
:class:`Reached`, raised when an argument list passed every check. ``test_valid_arguments_reach_
the_mission`` shows that each guard is reachable, so valid lists do get through the real checks.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import io
import os
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mission.cli import COMMANDS, build_parser
from mission.cli import main as cli_main
from mission.sim.sitl_plan import to_toml

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"
#: exit statuses the commands document (0 ok, 1 failed, 2 invalid options, 3 nobody answered)
STATUSES = {0, 1, 2, 3}
#: examples per command; SWARMSEEK_CLI_FUZZ_EXAMPLES=N runs N random (not derandomized) ones
EXAMPLES = int(os.environ.get("SWARMSEEK_CLI_FUZZ_EXAMPLES", "0")) or 45
DERANDOMIZE = "SWARMSEEK_CLI_FUZZ_EXAMPLES" not in os.environ
#: tokens replaced by a file made for the example
PLAN, LOG, BAD_FILE = "<plan>", "<log>", "<bad-file>"

EDGE = ["0", "1", "-1", "-5", "0.5", "3", "8", "255", "65536", "nan", "inf", "-inf", "1e309", "-0",
        "99999999999999999999999", "", " ", "é", "\u202e", "\x7f", "*", "**", "$*", "a/b", "x" * 300,
        "1,2,3", "-1,2,3", "nan,1,2", "1,2", "91,0,0", "x=1", "2:loss_uplink=0.2", "2:nope=1",
        "tcp/127.0.0.1:7447", "tcp/", "udp:127.0.0.1:14550", "udp:256.1.1.1:1", "tcp:127.0.0.1:5762",
        "/nonexistent/dir/x", "/proc/swarmseek", ".", BAD_FILE]
FLEETS = ["swarmseek", "sitl", "", "*", "**", "$*", "a$*b", "a/b", "a b", "@x", "a#b", "a?b", "é", "x" * 65,
          "\t", "f"]
#: option destination -> values that fit it (mixed with EDGE), so that some lists pass validation
GOOD = {
    "plan": [PLAN, PLAN, str(SAMPLE)], "log": [LOG, BAD_FILE, "missing.jsonl"], "log_dir": ["logs", "."],
    "fleet": FLEETS, "connect": ["tcp:127.0.0.1:5762", "udpin:0.0.0.0:14550"],
    "origin": ["47.0,8.0,500", "-35.36,149.16,584"], "zenoh_connect": ["tcp/127.0.0.1:7447"],
    "zenoh_listen": ["tcp/127.0.0.1:7447"], "source": ["0,0,20", "10,30,14"], "start": ["0,25,20"],
    "n": ["4", "8", "3", "254", "255"], "seed": ["0", "7", "-5", "4294967296"], "sitl_dir": ["sitl"],
    "out": ["out", "udp:127.0.0.1:14550"], "timeout": ["1", "0"], "iterations": ["10", "0"],
}


class Reached(BaseException):
    """The argument list passed every check: the command would start now (a BaseException, so
    that no command's own broad ``except Exception`` takes it for a failure)."""


def _raise_reached(*_args, **_kwargs):
    raise Reached()


@pytest.fixture(scope="module")
def guards():
    """Replace each command's first long step by :class:`Reached` (module-wide)."""
    import formation
    import zenoh

    import companion.cmd_publish as cmd_publish
    import experiments.cmd_simulate as cmd_simulate
    import experiments.offline as offline
    import experiments.paper as paper
    import experiments.sweep as sweep
    import mission.cli.cmd_dryrun as cmd_dryrun
    import mission.cli.cmd_fly as cmd_fly
    import mission.cli.cmd_resume as cmd_resume
    import mission.cli.cmd_run as cmd_run
    import mission.sim.sitl_fleet as sitl_fleet
    import sitl_mock.fleet as mock_fleet
    import sitl_mock.virtual_sensor as virtual_sensor
    from mission.flight.phases.resume import load_resume_state

    real_cvt, real_symmetric = formation.cvt_sphere, formation.symmetric_cylinder

    def cvt(n, *args, **kwargs):  # a huge --n would only take long: reaching it is enough
        return _raise_reached() if n > 64 else real_cvt(n, *args, **kwargs)

    def symmetric(n, *args, **kwargs):
        return _raise_reached() if n > 64 else real_symmetric(n, *args, **kwargs)

    def resume(log_path, *, plan=None, **_kwargs):  # the log is read and checked, then Reached
        load_resume_state(Path(log_path), plan)
        raise Reached()

    with pytest.MonkeyPatch.context() as mp:
        for target, name, value in [
            (cmd_run, "_make_fleet", _raise_reached), (cmd_fly, "fly", _raise_reached),
            (cmd_dryrun, "dry_run", _raise_reached), (cmd_resume, "resume", resume),
            (zenoh, "open", _raise_reached), (mock_fleet.MockFleet, "start", _raise_reached),
            (virtual_sensor, "open_mavlink", _raise_reached), (cmd_publish, "open_input", _raise_reached),
            (paper, "generate", _raise_reached),
            (sitl_fleet.SitlFleet, "start", _raise_reached), (sitl_fleet, "resolve_sitl_dir", lambda *a, **k: Path(".")),
            (offline, "simulate", _raise_reached), (cmd_simulate, "_simulate_seeker", _raise_reached),
            (cmd_simulate, "_simulate_moving", _raise_reached), (formation, "cvt_sphere", cvt),
            (formation, "symmetric_cylinder", symmetric),
            (sweep, "ProcessPoolExecutor", _raise_reached),  # --seeds --jobs: the workers would not see these guards
        ]:
            mp.setattr(target, name, value)
        yield


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A scratch working directory (relative --log-dir / --out land here), with the files the
    tokens stand for."""
    work = tmp_path_factory.mktemp("clifuzz")
    (work / "bad-file").write_bytes(b"\x00\xff not a plan, not a log {\n")
    (work / "mission.jsonl").write_text('{"record": "event", "t_s": 0}\n{"broken\n')
    old = Path.cwd()
    os.chdir(work)
    try:
        yield work
    finally:
        os.chdir(old)


@functools.cache
def _actions(command: str) -> tuple[argparse.Action, ...]:
    """The command's argparse actions, read from its parser once per command (not at every draw:
    building the parser was a third of this file's CPU)."""
    parser = build_parser([command])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return tuple(a for a in sub.choices[command]._actions if not isinstance(a, argparse._HelpAction))


def _values(action: argparse.Action):
    good = list(action.choices or ()) + GOOD.get(action.dest, [])
    pool = st.sampled_from(EDGE) | st.text(max_size=6)
    return st.sampled_from(good) | pool if good else pool


@st.composite
def _seeking_changes(draw):
    keys = {"seeker": ["gradient", "newton", "model", "plume", "ste", "nope"], "sampling": ["moving", "stop_and_go", ""],
            "region_m": [1.0, 0.0, float("nan")], "stability": ["C", "Z", 1], "wind_std_deg": [10.0, -1.0],
            "sensor_noise_std": [0.01, 0.0, float("inf")],
            "plume_mode": ["steady", "intermittent", 3], "replan_fraction": [0.3, 0.0, 2.0, float("nan")],
            "wind_from_deg": [270.0, -1.0, float("inf")], "sensor_lag_s": [0.5, -1.0],
            "gamma_m": [20.0, 0.0, 1e308], "max_iterations": [10, 0, -3, 2**70]}
    chosen = draw(st.lists(st.sampled_from(sorted(keys)), unique=True, max_size=4))
    return {k: draw(st.sampled_from(keys[k])) for k in chosen}


@st.composite
def plans(draw):
    """The sample plan with a random fleet name and random [seeking] and top-level changes."""
    doc = tomllib.loads(SAMPLE.read_text())
    if draw(st.booleans()):
        doc["fleet"] = draw(st.sampled_from(FLEETS) | st.text(max_size=8))
    doc["seeking"].update(draw(_seeking_changes()))
    if draw(st.booleans()):
        key = draw(st.sampled_from(["max_speed_m_s", "min_separation_m", "takeoff_alt_m", "stagger_s"]))
        doc[key] = draw(st.sampled_from([-1.0, 0.0, 1e9, float("nan"), "x"]))
    return doc


@st.composite
def argvs(draw, command: str):
    """``[command, ...]``: the required options and positionals, and a few optional ones."""
    actions = _actions(command)
    optional = [a for a in actions if a.option_strings and not a.required and not isinstance(a, argparse._VersionAction)]
    chosen = [a for a in actions if a.required and a.option_strings and draw(st.integers(0, 9)) > 0]
    chosen += draw(st.lists(st.sampled_from(optional), max_size=5)) if optional else []
    argv = [command]
    for action in chosen:
        flag = draw(st.sampled_from(action.option_strings))
        if action.nargs == 0:
            argv.append(flag)
        else:  # FLAG=VALUE: a value that starts with '-' stays a value
            argv.append(f"{flag}={draw(_values(action))}")
    argv += [draw(_values(a)) for a in actions if not a.option_strings]
    if draw(st.integers(0, 19)) == 0:
        argv.insert(draw(st.integers(1, len(argv))), draw(st.sampled_from(["--bogus", "-", "--", "--help"])))
    return argv


def _materialise(argv: list[str], plan_doc: dict, work: Path) -> list[str]:
    (work / "plan.toml").write_text(to_toml(plan_doc))
    files = {PLAN: str(work / "plan.toml"), LOG: str(work / "mission.jsonl"), BAD_FILE: str(work / "bad-file")}
    return [next((arg.replace(t, f) for t, f in files.items() if t in arg), arg) for arg in argv]


def run_cli(argv: list[str]) -> tuple[object, str, str]:
    """``(status or "reached", stdout, stderr)`` of ``swarmseek ARGV`` run in-process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = cli_main(list(argv))
        except SystemExit as exc:  # argparse: 2 for a usage error, 0 for --help
            status = exc.code
        except Reached:
            status = "reached"
    return status, out.getvalue(), err.getvalue()


def _check(argv, status, out, err) -> None:
    shown = f"swarmseek {argv!r} -> {status!r}\nstdout: {out[-800:]}\nstderr: {err[-1500:]}"
    assert "Traceback" not in err + out, shown
    assert status == "reached" or status in STATUSES, shown
    if status == 2:
        assert err.strip(), f"exit 2 without a message: {shown}"


@pytest.mark.parametrize("command", list(COMMANDS))
@settings(max_examples=EXAMPLES, deadline=None, derandomize=DERANDOMIZE,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_no_argument_list_gives_a_traceback(guards, workdir, command, data):
    argv = data.draw(argvs(command), label="argv")
    if any(PLAN in a for a in argv):
        argv = _materialise(argv, data.draw(plans(), label="plan"), workdir)
    else:
        argv = _materialise(argv, {}, workdir)
    _check(argv, *run_cli(argv))


VALID = {
    "run": ["run", "--seed", "3", "--log-dir", "logs"],
    "fly": ["fly", "--plan", str(SAMPLE), "--log-dir", "logs"],
    "dry-run": ["dry-run", "--plan", str(SAMPLE)],
    "watch": ["watch", "swarmseek", "--zenoh-connect", "tcp/127.0.0.1:7447"],
    "ctl": ["ctl", "swarmseek", "land", "--zenoh-connect", "tcp/127.0.0.1:7447"],
    "paper": ["paper", "--out", "paper-out", "--quick"],
    "simulate": ["simulate", "--seeker", "plume", "--seek-wind-from", "270"],
    "sitl": ["sitl", "--flavour", "px4", "--fleet", "dry"],
    "mock": ["mock", "--fleet", "demo", "--seed", "4"],
    "sensor": ["sensor", "--connect", "tcp:127.0.0.1:5762", "--origin", "47,8,500", "--field", "sigma2",
               "--zenoh-connect", "tcp/127.0.0.1:7447", "--fleet", "demo"],
    "publish": ["publish", "--connect", "tcp:127.0.0.1:5762", "--serial", "/dev/ttyUSB0", "--fleet", "demo",
                "--zenoh-connect", "tcp/127.0.0.1:7447"],
}


@pytest.mark.parametrize("command", sorted(VALID))
def test_valid_arguments_reach_the_mission(guards, workdir, command):
    """Each guard is reachable: a valid argument list passes every check (so the fuzz's valid
    lists exercise the real validation, not a stub)."""
    status, out, err = run_cli(VALID[command])
    assert status == "reached", (status, out, err)


def test_resume_reads_the_log_before_it_would_start(guards, workdir):
    status, out, err = run_cli(["resume", str(workdir / "mission.jsonl")])
    assert status == 2 and "swarmseek resume:" in err and "Traceback" not in err, (status, err)
