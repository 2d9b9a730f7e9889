"""Short reservations shared by every process of a user: one JSON file of ``key -> until`` (epoch
seconds), read and written under an exclusive ``flock``, so that picks in every process take turns.

Used for loopback ports (:func:`mission.sim.embedded.free_port_block`) and PX4 instance numbers
(:func:`mission.sim.sitl_launch.pick_layout`): between the check that something is free and the
caller's own use of it, another process's check would find it free too.
"""
from __future__ import annotations

import fcntl
import json
import time
from pathlib import Path
from typing import Callable, TypeVar

__all__ = ["take_leases"]

T = TypeVar("T")


def take_leases(path: str | Path, choose: Callable[[dict[int, float]], tuple[T, list[int]]], lease_s: float) -> T:
    """Under the file's lock: ``choose(leases)`` (the unexpired leases, key -> until) picks a result
    and the keys it takes; those keys are leased for ``lease_s`` seconds; the result is returned.

    An exception from ``choose`` leaves the file as it was. A file cut short by a killed writer
    reads as no leases.
    """
    path = Path(path)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    with open(path, "a+", encoding="utf-8") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # released when the file closes
        now_s = time.time()
        fh.seek(0)
        try:
            leases = {int(k): float(t) for k, t in json.loads(fh.read() or "{}").items() if float(t) > now_s}
        except (ValueError, TypeError, AttributeError):
            leases = {}
        result, keys = choose(leases)
        leases.update({k: now_s + lease_s for k in keys})
        fh.seek(0)
        fh.truncate()
        json.dump({str(k): t for k, t in leases.items()}, fh)
    return result
