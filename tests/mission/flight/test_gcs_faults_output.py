"""The ground station's own faults, output side: ``swarmseek fly`` with a closed stdout,
a closed stderr (then SIGTERM), a mission log on a size-limited file system; ``run`` under nohup.
Helpers and the cases' checks: tests/support/gcs_fault_support.py."""
from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from tests.support.fly_helpers import summary_exit_status
from tests.support.wait_helpers import wait_until
from tests.support.fly_process import subprocess_env
from tests.support.gcs_fault_support import _Fly, _Run, _closed_stderr_then_sigterm, _closed_stdout, _log_size_limit, _seeking

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]

#: fault -> (case, runner): ``fly`` against a mock fleet of this process (a minute of wall-clock flight,
#: the vehicles' end read from the fleet), or lock-step ``run`` (seconds; the same terminal, stop
#: handlers and mission log: the vehicles' end read from its log and summary)
CASES = {
    "closed-stdout": (_closed_stdout, _Fly),
    "closed-stderr": (_closed_stderr_then_sigterm, _Run),
    "log-size-limit": (_log_size_limit, _Run),
}


@pytest.mark.parametrize("fault", list(CASES))
def test_fly_survives_its_own_faults(tmp_path, fault):
    case, runner = CASES[fault]
    m = runner(tmp_path, False)
    try:
        case(m)
    finally:
        m.stop()


def _ignore_sighup() -> None:  # preexec_fn: what nohup does
    signal.signal(signal.SIGHUP, signal.SIG_IGN)


def test_under_nohup_a_hangup_changes_nothing(tmp_path):
    """A SIGHUP ignored from the start (``nohup``) stays ignored: the mission flies to its end
    (``run``, lock-step: its own mock fleet; the stop handlers are those of ``fly``)."""
    log = tmp_path / "log" / "mission.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "mission", "run", "--n", "4", "--json", "--no-tlog",
                             "--max-iterations", "5", "--log-dir", str(log.parent), "--seed", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=subprocess_env(),
                            preexec_fn=_ignore_sighup)
    try:
        wait_until(lambda: _seeking(log)() or proc.poll() is not None, 150.0, "the seek", poll_s=0.02)
        proc.send_signal(signal.SIGHUP)
        out, err = proc.communicate(timeout=150)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    summary = json.loads(out)
    assert summary["interrupted_by"] == [] and summary["outcome"] in ("converged", "max_iterations"), err[-2000:]
    assert proc.returncode == summary_exit_status(summary)
    assert "SIGHUP" not in err and summary["airborne_left"] == []
