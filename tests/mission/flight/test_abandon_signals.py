"""Ctrl-C and SIGTERM sent to a real ``swarmseek run`` process: the first brings the
vehicles home, a second lands them where they are; the process exits 130 / 143 with a closing
record and a summary in its mission log, and no vehicle left airborne unreported.

The process flies in lock-step (its default): on this shared 2-core host a ``--realtime`` fleet
can lose vehicles to scheduling delays alone, which would test the host, not the signals. The
signal handling is the same for both clocks (:mod:`mission.flight.operator_stop`)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(240)


def _records(log: Path) -> list[dict]:
    if not log.exists():
        return []
    out = []
    for line in log.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line being written
    return out


def _wait_for(proc, log: Path, predicate, what: str, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate(_records(log)):
        assert proc.poll() is None, f"swarmseek exited ({proc.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} within {timeout_s} s"
        time.sleep(0.01)


def _phase_is(name):
    return lambda records: any(r["type"] == "phase" and r["phase"] == name for r in records)


@pytest.mark.parametrize("signals, status", [(["SIGINT"], 130), (["SIGINT", "SIGINT"], 130),
                                             (["SIGTERM"], 143)])
def test_signals_to_a_running_mission(tmp_path, signals, status):
    log_dir = tmp_path / "logs"
    log = log_dir / "mission.jsonl"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[3]))
    proc = subprocess.Popen([sys.executable, "-m", "mission", "run", "--n", "4",
                             "--json", "--no-tlog", "--log-dir", str(log_dir), "--seed", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        _wait_for(proc, log, _phase_is("seek"), "the seek")
        for i, name in enumerate(signals):
            if i:
                _wait_for(proc, log, _phase_is("return"), "the return")
            proc.send_signal(getattr(signal, name))
        out, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == status, err[-2000:]
    records = _records(log)
    summary = [r for r in records if r["type"] == "summary"]
    assert len(summary) == 1 and summary[0]["outcome"] == "interrupted"
    assert summary[0]["interrupted_by"] == signals and summary[0]["airborne_left"] == []
    assert json.loads(out)["outcome"] == "interrupted"
    phases = [r["phase"] for r in records if r["type"] == "phase"]
    assert phases[-1] == "done" and "return" in phases
    messages = [r.get("message", "") for r in records if r["type"] == "event"]
    assert any(f"interrupted ({signals[0]})" in m for m in messages)
    landed_now = any("LANDING every airborne vehicle where it is" in m for m in messages)
    assert landed_now == (len(signals) == 2)
    assert f"swarmseek: {signals[0]}: stopping the mission" in err
    # every vehicle is down, or (after the emergency LAND) confirmed descending under LAND
    if len(signals) == 1:
        landed = {r["sysid"] for r in records if r["type"] == "status_change" and r["status"] == "landed"}
        assert landed == {1, 2, 3, 4}
    else:
        confirmed = {r["sysid"] for r in records if r["type"] == "event" and "confirmed by its autopilot"
                     in r.get("message", "")}
        landed = {r["sysid"] for r in records if r["type"] == "status_change" and r["status"] == "landed"}
        assert confirmed | landed == {1, 2, 3, 4}
