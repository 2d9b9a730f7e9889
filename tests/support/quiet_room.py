"""A test that runs alone: the other pytest-xdist workers wait while it runs (tests/conftest.py).

A real PX4 SIH fleet of four at three times real time needs about 1.4 of CI's 2 cores. Beside three
workers running mock missions it was starved twice in CI runs (a mission ended at its takeoff, a
vehicle lost in the seek), its higher CPU priority (tests/support/priority.py) notwithstanding. So the
few files of :data:`tests.conftest.ALONE_FILES` run with the machine to themselves: when one starts,
the other workers finish the test they are running and wait before their next one until it ends.

The room is a reader-writer lock across processes made of two ``flock`` files in a directory that
every worker of one session shares:

* an ordinary test passes the *turnstile* (takes it and lets it go at once), then holds the *room*
  shared while it runs;
* a test that runs alone holds the turnstile (the next tests wait at it) and then takes the room
  exclusively, which waits until the tests already in it have ended.

``flock`` locks go with the process: a worker that dies releases what it held.
"""
from __future__ import annotations

import contextlib
import fcntl
import time
from pathlib import Path

__all__ = ["QuietRoom"]


class QuietRoom:
    """The lock files of one test session.

    Parameters
    ----------
    directory : Path
        Shared by every worker of the session (created if missing).
    """

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._turnstile = self.directory / "turnstile.lock"
        self._room = self.directory / "room.lock"

    @contextlib.contextmanager
    def shared(self):
        """Run an ordinary test: wait while a test runs alone (or waits to), then share the room."""
        with open(self._turnstile, "a") as turnstile:
            fcntl.flock(turnstile, fcntl.LOCK_EX)
            fcntl.flock(turnstile, fcntl.LOCK_UN)
        with open(self._room, "a") as room:
            fcntl.flock(room, fcntl.LOCK_SH)
            try:
                yield
            finally:
                fcntl.flock(room, fcntl.LOCK_UN)

    @contextlib.contextmanager
    def alone(self):
        """Run a test alone: hold the turnstile, wait for the room to empty, hold it.

        Yields
        ------
        float
            Wall seconds waited for the tests that were running to end.
        """
        with open(self._turnstile, "a") as turnstile, open(self._room, "a") as room:
            fcntl.flock(turnstile, fcntl.LOCK_EX)
            t0 = time.monotonic()
            fcntl.flock(room, fcntl.LOCK_EX)
            try:
                yield time.monotonic() - t0
            finally:
                fcntl.flock(room, fcntl.LOCK_UN)
                fcntl.flock(turnstile, fcntl.LOCK_UN)
