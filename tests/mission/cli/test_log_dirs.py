"""Mission log directories never collide (``mission.cli.paths``): two missions started in the same
second get distinct default directories (exclusive ``os.mkdir``, a ``-k`` counter when the name is
taken), and an explicit ``--log-dir`` that already holds another mission's log is refused (exit 2).

Once, two ``run`` started in the same second shared ``run-YYYYMMDD-HHMMSS/``: one mission.jsonl
with two plans, and ``audit`` reported thousands of false speed violations. The clock is fixed
here (``now_s``), so "the same second" needs no sleep."""
from __future__ import annotations

import threading

import pytest

from mission.cli import main as cli_main
from mission.cli.paths import mission_log_dir, new_log_dir

NOW_S = 1_767_225_600.0


def test_two_calls_in_the_same_second_get_distinct_directories(tmp_path):
    a = new_log_dir(tmp_path, "run", NOW_S)
    b = new_log_dir(tmp_path, "run", NOW_S)
    c = new_log_dir(tmp_path, "fly", NOW_S)
    assert a != b and a.is_dir() and b.is_dir() and c.is_dir()
    assert b.name == a.name + "-2" and c.name.startswith("fly-")
    assert new_log_dir(tmp_path, "run", NOW_S + 1.0).name != a.name   # the next second: its own name


def test_concurrent_allocations_never_share_a_directory(tmp_path):
    got, barrier = [], threading.Barrier(8)

    def allocate():
        barrier.wait(timeout=30)
        got.append(new_log_dir(tmp_path, "run", NOW_S))

    threads = [threading.Thread(target=allocate) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert len(got) == 8 and len(set(got)) == 8


def test_default_directories_of_two_missions_in_one_second_differ(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (a, pa), (b, pb) = mission_log_dir(None, "run", NOW_S), mission_log_dir(None, "run", NOW_S)
    assert pa is None and pb is None and a != b
    assert a.parent.name == b.parent.name == "swarmseek-logs"
    assert (a / "mission.jsonl").is_file() and (b / "mission.jsonl").is_file()


def test_an_explicit_log_dir_holding_a_mission_log_is_refused(tmp_path):
    log_dir, problem = mission_log_dir(tmp_path / "mine", "run")
    assert problem is None and log_dir == tmp_path / "mine"
    again, problem = mission_log_dir(tmp_path / "mine", "run")   # nothing written yet: still ours to use
    assert problem is None and again == log_dir
    (log_dir / "mission.jsonl").write_text('{"t_s": 1, "type": "plan", "plan": {}}\n')
    again, problem = mission_log_dir(tmp_path / "mine", "run")
    assert again is None and "already holds a mission log" in problem and "swarmseek resume" in problem


@pytest.mark.parametrize("command", ["run", "fly"])
def test_run_and_fly_exit_2_on_a_log_dir_of_another_mission(tmp_path, capsys, command):
    from pathlib import Path

    (tmp_path / "mission.jsonl").write_text('{"t_s": 1, "type": "plan", "plan": {}}\n')
    plan = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"
    argv = ["run"] if command == "run" else ["fly", "--plan", str(plan)]
    assert cli_main(argv + ["--log-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"swarmseek {command}: error:" in err and "already holds a mission log" in err and "Traceback" not in err


def test_fly_says_where_its_log_is_at_the_start_and_in_the_summary(tmp_path, capsys):
    """``fly`` against vehicles that are not there (nothing listens on the plan's ports): it
    gives up after the heartbeat timeout, and says where its log is first and last, as ``run``."""
    import socket

    from tests.mission.cli.test_cli import _write_plan

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    plan = _write_plan(tmp_path / "p.toml", heartbeat_timeout_s=0.5, zenoh__listen=[f"tcp/127.0.0.1:{port}"])
    log = tmp_path / "log" / "mission.jsonl"
    assert cli_main(["fly", "--plan", str(plan), "--log-dir", str(log.parent)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"swarmseek fly: mission log: {log}"
    assert lines[-1].startswith(f"  mission log: {log}  (swarmseek plot {log} --out DIR")
    assert log.is_file() and '"type":"summary"' in log.read_text()
