"""Stopping SITL process groups and removing what PX4 leaves in /tmp."""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from pathlib import Path

from mission.sim.sitl_launch import px4_instance_free

__all__ = ["stop_groups", "cleanup_px4_files", "group_alive"]


def group_alive(pgid: int) -> bool:
    """True while any process of process group ``pgid`` exists."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _signal_group(pgid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, sig)


def stop_groups(procs: list[subprocess.Popen], grace_s: float = 5.0) -> None:
    """SIGTERM each process's group, wait up to ``grace_s``, SIGKILL what is left, reap.

    Each process was started with ``start_new_session=True``: its pid is its group id, and the
    group holds every child it started.
    """
    for proc in procs:
        _signal_group(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for proc in procs:
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
    for proc in procs:
        if proc.poll() is None or group_alive(proc.pid):
            _signal_group(proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=2.0)
    stragglers = [p.pid for p in procs if group_alive(p.pid)]
    deadline = time.monotonic() + 2.0
    while stragglers and time.monotonic() < deadline:
        stragglers = [pid for pid in stragglers if group_alive(pid)]
        if stragglers:
            time.sleep(0.05)


def cleanup_px4_files(instances: list[int]) -> None:
    """Remove ``/tmp/px4_lock-<i>`` and ``/tmp/px4-sock-<i>`` of stopped instances.

    A file is left alone while a running PX4 still holds the instance's lock (another fleet
    started that instance meanwhile).
    """
    for inst in instances:
        if not px4_instance_free(inst):
            continue
        for path in (Path(f"/tmp/px4_lock-{inst}"), Path(f"/tmp/px4-sock-{inst}")):
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
