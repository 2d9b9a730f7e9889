"""The quiet room (tests/support/quiet_room.py): a test of ``ALONE_FILES`` runs with no other test beside
it, and the files it names are real, in the real-SITL unit, last."""
from __future__ import annotations

import threading

from tests.conftest import ALONE_FILES, ONE_SITL_AT_A_TIME, TESTS_DIR
from tests.support.quiet_room import QuietRoom

#: wall seconds any expected step gets (a loaded host)
WAIT_S = 30.0
#: wall seconds in which a step that must wait is seen not to happen
STILL_WAITING_S = 0.5


def _hold(ctx, entered: threading.Event, release: threading.Event) -> threading.Thread:
    """Enter ``ctx`` in a thread, set ``entered``, stay until ``release``."""
    def run():
        with ctx:
            entered.set()
            release.wait(WAIT_S)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_a_test_alone_waits_for_the_running_tests_and_the_next_wait_for_it(tmp_path):
    room = QuietRoom(tmp_path / "room")
    running, running_done = threading.Event(), threading.Event()
    first = _hold(room.shared(), running, running_done)
    assert running.wait(WAIT_S)

    alone, alone_done = threading.Event(), threading.Event()
    lone = _hold(room.alone(), alone, alone_done)
    assert not alone.wait(STILL_WAITING_S), "the test alone started beside a running test"

    nxt, nxt_done = threading.Event(), threading.Event()
    later = _hold(room.shared(), nxt, nxt_done)
    assert not nxt.wait(STILL_WAITING_S), "a test started while one waited to run alone"

    running_done.set()
    first.join(WAIT_S)
    assert alone.wait(WAIT_S), "the test alone did not start once the room was empty"
    assert not nxt.wait(STILL_WAITING_S), "a test started beside the test alone"

    alone_done.set()
    lone.join(WAIT_S)
    assert nxt.wait(WAIT_S), "the next test did not start after the test alone"
    nxt_done.set()
    later.join(WAIT_S)


def test_ordinary_tests_share_the_room(tmp_path):
    room = QuietRoom(tmp_path / "room")
    events = [(threading.Event(), threading.Event()) for _ in range(3)]
    threads = [_hold(room.shared(), entered, done) for entered, done in events]
    assert all(entered.wait(WAIT_S) for entered, _ in events)
    for (_, done), t in zip(events, threads):
        done.set()
        t.join(WAIT_S)


def test_the_files_alone_exist_and_end_the_real_sitl_unit():
    assert ALONE_FILES and all((TESTS_DIR / name).is_file() for name in ALONE_FILES)
    assert ONE_SITL_AT_A_TIME[-len(ALONE_FILES):] == ALONE_FILES
