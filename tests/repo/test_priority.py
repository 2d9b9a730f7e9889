"""The real-SITL unit's higher CPU priority (tests/support/priority.py, tests/conftest.py)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.support import priority
from tests.support.priority import BOOST, raised_priority


def _child_nice() -> int:
    out = subprocess.run([sys.executable, "-c", "import os; print(os.getpriority(os.PRIO_PROCESS, 0))"],
                         capture_output=True, text=True, timeout=60, check=True)
    return int(out.stdout)


@pytest.mark.skipif(os.geteuid() != 0, reason="lowering a nice value needs root (CAP_SYS_NICE), as on CI")
def test_the_block_and_the_processes_it_starts_run_higher_then_it_is_undone():
    before = os.getpriority(os.PRIO_PROCESS, 0)
    with raised_priority() as refused:
        assert refused is None
        assert os.getpriority(os.PRIO_PROCESS, 0) == before - BOOST
        assert _child_nice() == before - BOOST          # an autopilot started here inherits it
    assert os.getpriority(os.PRIO_PROCESS, 0) == before
    assert _child_nice() == before


def test_without_the_permission_nothing_changes_and_the_reason_is_given(monkeypatch):
    before = os.getpriority(os.PRIO_PROCESS, 0)
    calls = []

    def refuse(which, who, value):
        calls.append(value)
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(priority.os, "setpriority", refuse)
    with raised_priority() as refused:
        assert refused and "CAP_SYS_NICE" in refused and "normal priority" in refused
    assert calls == [before - BOOST]                      # asked once, nothing to undo
    assert os.getpriority(os.PRIO_PROCESS, 0) == before

