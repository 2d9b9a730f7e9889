"""``swarmseek simulate | head -1`` and ``swarmseek paper | head -1``: a reader that goes away ends
the command quietly (status 141, as a program SIGPIPE ended; no traceback), as the flying
commands' best-effort terminal does (they fly on). Deterministic: the command's stdout is a pipe
whose read end is already closed, so its first write fails."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from mission.telemetry.terminal import SIGPIPE_STATUS

pytestmark = pytest.mark.timeout(300)

ROOT = Path(__file__).resolve().parents[2]
#: ``swarmseek paper`` with its figures' computation (minutes) replaced by a summary of the same
#: shape: what is under test is the command's printing of it to a reader that went away
_PAPER = """
import sys
import experiments.paper as paper
paper.generate = lambda out, quick: {"note": "", "elapsed_s": 0.1, "fig4_final": {"sigma2": {"final_mean_m": 0.87}},
                                     "table1": [{"n": 4, "symmetric_d_min": 1.0, "cvt_d_min": 1.1}]}
from mission.cli import main
sys.exit(main(["paper", "--out", sys.argv[1]]))
"""


def _run_into_a_closed_pipe(argv: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r, w = os.pipe()
    os.close(r)
    try:
        return subprocess.run([sys.executable, *argv], stdout=w, stderr=subprocess.PIPE, env=env, cwd=ROOT,
                              text=True, timeout=240)
    finally:
        os.close(w)


@pytest.mark.parametrize("extra", [[], ["--json"]])
def test_simulate_into_a_closed_pipe_ends_quietly(extra):
    done = _run_into_a_closed_pipe(["-m", "mission", "simulate", "--iterations", "5", *extra])
    assert done.returncode == SIGPIPE_STATUS == 141, done.stderr
    assert "Traceback" not in done.stderr and "BrokenPipeError" not in done.stderr, done.stderr


def test_paper_into_a_closed_pipe_ends_quietly(tmp_path):
    done = _run_into_a_closed_pipe(["-c", _PAPER, str(tmp_path / "out")])
    assert done.returncode == SIGPIPE_STATUS, done.stderr
    assert "Traceback" not in done.stderr and "BrokenPipeError" not in done.stderr, done.stderr


def test_a_broken_pipe_that_is_not_the_terminal_is_still_shown(tmp_path):
    """A BrokenPipeError of the command's own (here raised by it, stdout fine) is a fault: shown."""
    code = ("import sys\nimport experiments.paper as paper\n"
            "def boom(out, quick):\n    raise BrokenPipeError(32, 'a socket of the command')\n"
            "paper.generate = boom\nfrom mission.cli import main\nsys.exit(main(['paper', '--out', sys.argv[1]]))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "out")], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=240)
    assert done.returncode == 1 and "BrokenPipeError" in done.stderr and "a socket of the command" in done.stderr
