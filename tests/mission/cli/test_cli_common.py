"""The command-line pieces the commands share (one home each): the one-line error of
``wire.cli_args``, the zenoh endpoint options of ``wire.zenoh_flags`` and the mission commands'
options, plan loading and run-failure report of ``mission.cli.common``."""
from __future__ import annotations

import argparse
import errno

import pytest
import zenoh

from mission.cli.common import add_mission_outputs, add_plan_argument, load_plan_or_fail, run_or_fail
from wire.cli_args import USAGE_STATUS, fail, usage_error
from wire.zenoh_flags import add_endpoint_arguments
from wire.zenoh_secrets import ZenohSecurityError


def test_fail_prints_one_line_and_returns_the_status(capsys):
    assert fail("swarmseek x", "cannot do it", 1) == 1
    assert usage_error("swarmseek x", "--n must be >= 4") == USAGE_STATUS == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == "swarmseek x: cannot do it\nswarmseek x: error: --n must be >= 4\n"


def test_endpoint_options_are_checked_repeatable_and_in_the_asked_order():
    parser = argparse.ArgumentParser(exit_on_error=False)
    add_endpoint_arguments(parser, listen_help="L", connect_help="C", connect_first=True)
    flags = [a.option_strings[0] for a in parser._actions if a.option_strings[0].startswith("--zenoh")]
    assert flags == ["--zenoh-connect", "--zenoh-listen"]
    args = parser.parse_args(["--zenoh-listen", "tcp/127.0.0.1:7447", "--zenoh-listen", "udp/0.0.0.0:7448"])
    assert args.zenoh_listen == ["tcp/127.0.0.1:7447", "udp/0.0.0.0:7448"] and args.zenoh_connect == []
    with pytest.raises(argparse.ArgumentError):
        parser.parse_args(["--zenoh-connect", "not an endpoint"])


def test_an_endpoint_option_without_help_is_not_added():
    parser = argparse.ArgumentParser()
    add_endpoint_arguments(parser, listen_help="only listen")
    assert not hasattr(parser.parse_args([]), "zenoh_connect")


def test_the_mission_outputs_with_and_without_log_dir_and_forwarding():
    full, bare = argparse.ArgumentParser(), argparse.ArgumentParser()
    add_plan_argument(full)
    add_mission_outputs(full, "fly")
    add_mission_outputs(bare, "resume", log_dir=False, forward=False)
    args = full.parse_args(["--plan", "p.toml", "--json", "--no-tlog", "--out", "udp:127.0.0.1:14550"])
    assert (str(args.plan), args.json, args.no_tlog, args.log_dir) == ("p.toml", True, True, None)
    assert len(args.out) == 1
    log_dir = next(a for a in full._actions if "--log-dir" in a.option_strings)
    assert log_dir.help == "mission log and tlogs go here (default ./swarmseek-logs/fly-TIME)"
    assert sorted(vars(bare.parse_args([]))) == ["json", "no_tlog"]


def test_an_invalid_plan_is_one_report_and_exit_2(tmp_path, capsys):
    bad = tmp_path / "plan.toml"
    bad.write_text("version = 1\nbogus = 1\n")
    plan, status = load_plan_or_fail(bad, "swarmseek fly")
    assert (plan, status) == (None, 2)
    err = capsys.readouterr().err
    assert err.startswith("swarmseek fly: ") and "bogus" in err


@pytest.mark.parametrize("exc, status, words", [
    (zenoh.ZError("refused"), 1, "swarmseek fly: zenoh said refused"),
    (OSError(errno.ENOSPC, "No space left on device"), 1, "swarmseek fly: cannot write the mission log: "),
    (ZenohSecurityError("password file unreadable"), 2,
     "swarmseek fly: zenoh security settings: password file unreadable"),
])
def test_a_mission_that_cannot_run_is_one_line_with_its_status(exc, status, words, capsys):
    def run():
        raise exc

    assert run_or_fail("swarmseek fly", run, lambda e: f"zenoh said {e}") == (None, status)
    assert capsys.readouterr().err.startswith(words)


def test_a_mission_that_runs_returns_its_result():
    assert run_or_fail("swarmseek fly", lambda: "result", str) == ("result", None)
