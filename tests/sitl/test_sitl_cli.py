"""``swarmseek sitl``: invalid options exit 2 with a specific message; a real PX4 SIH fleet started
in a subprocess prints its connection strings and a loadable plan, and SIGTERM stops every
instance (no process left, no PX4 lock file left)."""
from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mission.cli import main as cli_main
from tests.support.sitl_support import require_sitl


@pytest.mark.parametrize("argv, message", [
    (["--flavour", "inav"], "invalid choice: 'inav'"),
    (["--flavour", "px4", "--n", "0"], "--n must be 1..254, got 0"),
    (["--flavour", "px4", "--speedup", "-2"], "expected a positive number"),
    (["--flavour", "px4", "--param", "SDLOG_MODE"], "expected NAME=VALUE"),
    (["--flavour", "px4", "--param", "SDLOG_MODE=off"], "'off' is not a number"),
    (["--flavour", "px4", "--home", "91,0,0"], "latitude"),
])
def test_invalid_options_exit_2(capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        cli_main(["sitl", *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--flavour", "px4", "--n", "11"], "instances 0..10 asked for; instance numbers must stay below 10"),
    (["--flavour", "px4", "--n", "4", "--first-instance", "8"], "instance numbers must stay below 10"),
])
def test_impossible_px4_layout_exits_2(capsys, monkeypatch, tmp_path, argv, message):
    monkeypatch.setenv("SWARMSEEK_PX4_SITL", str(tmp_path))  # never reached: the layout is checked first
    assert cli_main(["sitl", *argv]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("flavour, var", [("px4", "SWARMSEEK_PX4_SITL"), ("ardupilot", "SWARMSEEK_ARDUPILOT_SITL")])
def test_missing_setting_names_the_variable(capsys, monkeypatch, tmp_path, flavour, var):
    monkeypatch.delenv(var, raising=False)
    assert cli_main(["sitl", "--flavour", flavour, "--n", "1"]) == 2
    assert f"{var} is not set" in capsys.readouterr().err
    monkeypatch.setenv(var, str(tmp_path / "nowhere"))
    assert cli_main(["sitl", "--flavour", flavour, "--n", "1"]) == 2
    assert f"{var}=" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli_main(["sitl", "--flavour", flavour, "--n", "1", "--sitl-dir", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err
    assert "--sitl-dir=" in err and "missing bin/" in err


def _read_until(proc, pattern: str, timeout_s: float) -> str:
    """stdout of ``proc`` up to the first line matching ``pattern`` (fails on exit or timeout).

    A thread reads the lines (a buffered pipe and select() do not mix)."""
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    text = ""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        text += line
        if re.search(pattern, line):
            return text
    proc.kill()
    pytest.fail(f"no line matching {pattern!r} (exit {proc.wait()}); output:\n{text}\n{proc.stderr.read()}")


def _gone(pid: int) -> bool:
    try:
        os.killpg(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_px4_fleet_starts_prints_and_stops_cleanly_on_sigterm(tmp_path):
    require_sitl("px4")
    plan_path = tmp_path / "plan.toml"
    proc = subprocess.Popen([sys.executable, "-m", "mission", "sitl", "--flavour", "px4", "--n", "2", "--free-layout",
                             "--plan-out", str(plan_path), "--zenoh-port", "17447"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out = _read_until(proc, r"^ready: 2 vehicles up", 120.0)
        rows = re.findall(r"sysid +(\d+) +instance +(\d+) +pid +(\d+) +ground station (udpin:\S+) +sensor (udpin:\S+)", out)
        assert len(rows) == 2, out
        # 2 vehicles: no plan (a formation needs 4; the plan itself: test_sitl_launch, test_sitl_px4)
        assert "no plan written: a mission needs at least 4 vehicles" in out and not plan_path.exists()
        assert [int(r[0]) for r in rows] == [int(r[1]) + 1 for r in rows]
        assert out.count("swarmseek sensor --connect udpin:127.0.0.1:") == 2
        for _sysid, _inst, _pid, gcs, sensor in rows:
            assert f"--connect {sensor} " in out and gcs != sensor
        pids = [int(r[2]) for r in rows]
        instances = [int(r[1]) for r in rows]
        assert all(Path(f"/tmp/px4_lock-{i}").exists() for i in instances)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        assert "stopped every instance" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert all(_gone(pid) for pid in pids), pids
    assert not [i for i in instances if Path(f"/tmp/px4_lock-{i}").exists() or Path(f"/tmp/px4-sock-{i}").exists()]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_killed_launcher_leaves_no_orphan(tmp_path):
    """SIGKILL (no clean-up possible): each instance still gets SIGTERM (PR_SET_PDEATHSIG) and exits."""
    require_sitl("px4")
    from mission.sim.sitl_launch import px4_instance_free
    from mission.sim.sitl_procs import cleanup_px4_files

    proc = subprocess.Popen([sys.executable, "-m", "mission", "sitl", "--flavour", "px4", "--n", "1", "--free-layout",
                             "--plan-out", str(tmp_path / "plan.toml")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out = _read_until(proc, r"^ready: 1 vehicles up", 90.0)
        assert "no plan written: a mission needs at least 4 vehicles" in out
        instance, pid = (int(x) for x in re.search(r"instance +(\d+) +pid +(\d+)", out).groups())
        assert not _gone(pid)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 20.0
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _gone(pid), f"PX4 instance {instance} (pid {pid}) outlived its killed launcher"
    # the instance's ports are free again, unless another test's fleet (xdist) took the block at once:
    # its lowest free instance is this one; then its files are that fleet's and stay
    if px4_instance_free(instance):
        cleanup_px4_files([instance])  # PX4 leaves its socket file when nobody cleans up after it
