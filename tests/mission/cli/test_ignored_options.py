"""No option ignored without a word (docs/seekers.md, "Options that do not apply").

An option of another seeker or sampling mode (``--plume-mode``, ``--seek-wind-from``,
``--replan-fraction``, ``--sensor-lag``, ``simulate --method``; the same ``[seeking]`` keys in a
plan) asks for a behaviour the run would not have: refused, exit 2, with the reason. A harmless
setting the chosen seeker does not use (``--eps`` but for the gradient seeker, ``simulate
--min-signal-fraction`` where no signal test runs) is warned about once on stderr.
"""
from __future__ import annotations

import argparse
import copy
import tomllib
from pathlib import Path

import pytest

from mission.cli import main as cli_main
from mission.cli.cmd_run import _check_args, configure
from mission.core.plan import parse_plan
from mission.core.plan_types import PlanError

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


def _run_args(*argv):
    parser = argparse.ArgumentParser()
    configure(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize("argv, why", [
    (["--plume-mode", "intermittent"], "--plume-mode applies to the plume and ste seekers only.*seeker is model"),
    (["--field", "plume", "--seeker", "model", "--plume-mode", "steady"], "--plume-mode applies to the plume and ste seekers"),
    (["--seeker", "newton", "--seek-wind-from", "270"], "--seek-wind-from applies to the plume and ste seekers only.*newton"),
    (["--seeker", "gradient", "--replan-fraction", "0.3"],
     "--replan-fraction applies to sampling while moving only.*samples stop_and_go \\(gradient seeker\\)"),
    (["--seeker", "plume", "--replan-fraction", "0.5"], "--replan-fraction applies to sampling while moving"),
    (["--sampling", "stop_and_go", "--sensor-lag", "1"], "--sensor-lag applies to sampling while moving only"),
    (["--seeker", "model", "--prior-box", "fence"], "--prior-box applies to the ste seeker only.*seeker is model"),
])
def test_run_refuses_an_option_that_cannot_apply(argv, why, capsys):
    import re

    assert cli_main(["run", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarmseek run: error: ") and re.search(why, err), err
    assert err.count("\n") == 1


@pytest.mark.parametrize("argv", [
    ["--seeker", "plume", "--plume-mode", "intermittent", "--seek-wind-from", "270"],
    ["--field", "intermittent", "--plume-mode", "steady"],          # the ste seeker is that field's default
    ["--replan-fraction", "0.3", "--sensor-lag", "0.2"],            # model: moving by default
    ["--seeker", "newton", "--sampling", "moving", "--replan-fraction", "1"],
    ["--field", "intermittent", "--prior-box", "fence", "--fence-side", "60"],  # ste: that field's default
])
def test_run_accepts_the_same_options_where_they_apply(argv, capsys):
    assert _check_args(_run_args(*argv)) is None
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("argv, warned", [
    (["--eps", "2"], True), (["--seeker", "plume", "--eps", "2"], True),
    (["--seeker", "gradient", "--eps", "2"], False), ([], False),
])
def test_run_warns_once_for_eps_the_seeker_does_not_use(argv, warned, capsys):
    assert _check_args(_run_args(*argv)) is None
    err = capsys.readouterr().err
    assert err.count("warning: --eps is the gradient seeker's step gain") == (1 if warned else 0), err
    assert err.count("\n") == (1 if warned else 0)


@pytest.mark.parametrize("changes, key", [
    ({"plume_mode": "intermittent"}, "seeking.plume_mode"),
    ({"seeker": "model", "plume_mode": "steady"}, "seeking.plume_mode"),
    ({"seeker": "newton", "wind_from_deg": 270.0}, "seeking.wind_from_deg"),
    ({"seeker": "gradient", "replan_fraction": 0.3}, "seeking.replan_fraction"),  # the paper's seeker: stop and go
    ({"seeker": "model", "sampling": "stop_and_go", "sensor_lag_s": 0.5}, "seeking.sensor_lag_s"),
    ({"seeker": "plume", "replan_fraction": 0.3}, "seeking.replan_fraction"),
])
def test_a_plan_refuses_a_seeking_key_that_cannot_apply(changes, key):
    doc = tomllib.loads(SAMPLE.read_text())
    doc["seeking"].update(changes)
    with pytest.raises(PlanError, match="applies only with") as info:
        parse_plan(doc)
    problems = dict(info.value.problems)
    assert key in problems and "remove the key" in problems[key], problems


@pytest.mark.parametrize("changes", [
    {"seeker": "plume", "plume_mode": "intermittent", "wind_from_deg": 270.0},
    {"seeker": "model", "sampling": "moving", "replan_fraction": 0.3, "sensor_lag_s": 0.5},
    {"seeker": "model", "eps": 50.0},  # the sample plan's eps with another seeker: harmless, as swarmseek sitl writes it
])
def test_a_plan_accepts_the_same_keys_where_they_apply(changes):
    doc = tomllib.loads(SAMPLE.read_text())
    good = copy.deepcopy(doc)
    good["seeking"].update(changes)
    seeking = parse_plan(good).seeking
    assert all(getattr(seeking, k) == v for k, v in changes.items())


def test_an_invalid_seeking_value_is_reported_once_under_its_key():
    doc = tomllib.loads(SAMPLE.read_text())
    doc["seeking"].update(replan_fraction=1.5)  # out of range and (stop and go) not applicable: the range
    with pytest.raises(PlanError) as info:
        parse_plan(doc)
    keys = [k for k, _ in info.value.problems]
    assert keys.count("seeking.replan_fraction") == 1 and "must be <= 1" in dict(info.value.problems)[
        "seeking.replan_fraction"]


_SHORT = ["--iterations", "40", "--window", "10", "--n", "6"]


@pytest.mark.parametrize("argv, why", [
    (["--seeker", "model", "--seek-wind-from", "270"], "--seek-wind-from applies to the plume and ste seekers only"),
    (["--seeker", "newton", "--method", "symmetric"], "--method .* applies to the gradient seeker only"),
])
def test_simulate_refuses_an_option_that_cannot_apply(argv, why, capsys):
    import re

    assert cli_main(["simulate", *_SHORT, *argv]) == 2
    assert re.search(why, capsys.readouterr().err)


@pytest.mark.parametrize("argv, warning", [
    (["--seeker", "newton", "--gamma", "20", "--eps", "3"], "--eps is the gradient seeker's step size"),
    (["--min-signal-fraction", "0.5"], "--min-signal-fraction is a criterion of the stop-and-go"),
    (["--seeker", "model", "--sampling", "moving", "--gamma", "20", "--min-signal-fraction", "0.5"],
     "--min-signal-fraction is a criterion"),
])
def test_simulate_warns_once_for_a_harmless_unused_option(argv, warning, capsys):
    assert cli_main(["simulate", *_SHORT, "--json", *argv]) == 0
    err = capsys.readouterr().err
    assert err.count(warning) == 1 and err.count("\n") == 1, err


def test_simulate_without_unused_options_warns_nothing(capsys):
    assert cli_main(["simulate", *_SHORT, "--json", "--seeker", "plume", "--gamma", "20", "--seek-wind-from", "270",
                     "--min-signal-fraction", "0.5"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("extra", [["--port-offset", "10"], ["--first-instance", "3"]])
def test_sitl_refuses_a_layout_with_free_layout(extra, capsys):
    """Refused before any SITL instance is looked for or started."""
    assert cli_main(["sitl", "--flavour", "px4", "--free-layout", *extra]) == 2
    assert "--free-layout picks the instance numbers and the port offset itself" in capsys.readouterr().err


@pytest.mark.parametrize("argv, why", [
    (["run", "--seed", "-5"], "--seed must be >= 0, got -5"),
    (["mock", "--seed", "-1"], "--seed must be >= 0"),
    (["simulate", "--seed", "-2"], "--seed must be >= 0"),
    (["dry-run", "--plan", str(SAMPLE), "--timeout", "inf"], "expected a positive number"),
    (["dry-run", "--plan", str(SAMPLE), "--ready-timeout", "nan"], "expected a number >= 0"),
    (["fly", "--plan", "a\x00b"], "NUL byte"),
    (["plot", "x" * 300], "too long"),
])
def test_bad_values_that_gave_tracebacks_are_usage_errors(argv, why, capsys):
    with pytest.raises(SystemExit) as info:
        cli_main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and why in err and "Traceback" not in err, err
