"""The monitor's side: the state watcher (invalid snapshots counted, in order), `swarmseek watch`
drawing the table of a publication until its final snapshot, the operator keys in a terminal
(a pseudo-terminal here) and the control lines of the live table."""
from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from mission.telemetry.display import format_line, format_table
from mission.telemetry.state_pub import STATE_SCHEMA, StatePublisher, state_key
from mission.telemetry.watch import StateWatcher
from mission.telemetry.watch_keys import KeyDecoder, TerminalKeys
from tests.support.wait_helpers import wait_until, wait_until_async

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[3]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session(listen=(), connect=()):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return zenoh.open(conf)


def test_watcher_counts_invalid_snapshots_and_keeps_the_order():
    ep = f"tcp/127.0.0.1:{_port()}"
    pub_s, sub_s = _session(listen=[ep]), _session(connect=[ep])
    try:
        watcher = StateWatcher(sub_s, "f")
        pub = pub_s.declare_publisher(state_key("f"))

        def send_all():
            for payload in (b"not json", json.dumps({"schema": "other"}).encode(),
                            json.dumps({"schema": STATE_SCHEMA, "phase": "seek", "iteration": 1}).encode(),
                            json.dumps({"schema": STATE_SCHEMA, "phase": "seek", "iteration": 2}).encode()):
                pub.put(payload)
            return watcher.received >= 2

        wait_until(send_all, 20.0, "two valid snapshots", poll_s=0.3)
        got = [watcher.get(1.0) for _ in range(2)]
        assert [g["iteration"] for g in got] == [1, 2] and watcher.invalid >= 2
        watcher.close()
    finally:
        pub_s.close()
        sub_s.close()


def test_watch_command_draws_until_the_final_snapshot(tmp_path):
    port = _port()
    ep = f"tcp/127.0.0.1:{port}"
    session = _session(listen=[ep])
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    watch = subprocess.Popen([sys.executable, "-m", "mission", "watch", "demo", "--zenoh-connect", ep,
                              "--wait-s", "60"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    state = {"fleet": "demo", "phase": "seek", "iteration": 3, "elapsed_s": 12.0, "vehicles": [],
             "control": {"paused": True, "paused_by": "alice", "holding": True, "stop": None}}

    async def publish():
        pub = StatePublisher(session, "demo", lambda: dict(state), rate_hz=5.0)
        pub.start()
        await wait_until_async(lambda: watch.poll() is not None or pub.published > 25, 60.0, "some snapshots")
        state["ending"] = {"outcome": "converged", "message": "m", "exit_status": 4}  # a vehicle was lost
        await pub.stop()                                   # the final snapshot ends the watcher

    try:
        asyncio.run(publish())
        out, err = watch.communicate(timeout=30)
    finally:
        if watch.poll() is None:
            watch.kill()
        session.close()
    assert watch.returncode == 4, err                      # the mission's own exit status
    assert "seek" in out and "[PAUSED by alice]" in out
    assert "the mission of fleet 'demo' ended: converged, exit status 4" in out


def test_watch_without_endpoint_is_a_usage_error():
    p = subprocess.run([sys.executable, "-m", "mission", "watch", "demo"], cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "give --zenoh-connect" in p.stderr


def test_table_shows_the_operator_state():
    paused = {"phase": "seek", "control": {"paused": True, "paused_by": "bob", "holding": False, "stop": None}}
    assert any("PAUSED by bob" in line for line in format_table(paused))
    stopping = {"phase": "seek", "control": {"paused": False, "stop": "rtl"}}
    assert any("OPERATOR RTL ordered" in line for line in format_table(stopping))
    assert "[operator RTL ordered]" in format_line(stopping)
    assert not any("OPERATOR" in line or "PAUSED" in line for line in format_table({"phase": "seek"}))


def test_stops_need_the_key_twice_within_the_confirmation_time():
    now = [0.0]
    keys = KeyDecoder(confirm_s=3.0, clock=lambda: now[0])
    assert keys.press("p") == ("pause", None) and keys.press("C") == ("continue", None)
    command, hint = keys.press("l")
    assert command is None and "press l again" in hint
    now[0] = 2.0
    assert keys.press("l") == ("land", None)
    keys.press("a")
    now[0] = 6.0                                            # too late: asks again
    assert keys.press("a")[0] is None
    keys.press("r")
    assert keys.press("a")[0] is None                       # another key in between: asks again
    assert keys.press("x") == (None, None)


def test_terminal_keys_send_commands_from_a_pseudo_terminal():
    import termios

    master, slave = os.openpty()
    sent, said = [], []
    stream = os.fdopen(slave, "r")
    before = termios.tcgetattr(slave)

    async def main():
        keys = TerminalKeys(lambda c, s: sent.append((c, s)) or {}, said.append, stream=stream)
        assert keys.start()
        os.write(master, b"p")
        await wait_until_async(lambda: sent, 5.0, "the pause")
        os.write(master, b"ll")
        await wait_until_async(lambda: len(sent) == 2, 5.0, "the land")
        keys.close()

    try:
        asyncio.run(main())
        assert termios.tcgetattr(slave) == before              # the terminal is restored
    finally:
        stream.close()
        os.close(master)
    assert [c for c, _ in sent] == ["pause", "land"] and all(s.startswith("terminal:") for _, s in sent)
    assert said[0].startswith("keys:") and any("press l again" in x for x in said)


def test_terminal_keys_do_nothing_without_a_terminal(tmp_path):
    async def main():
        with open(tmp_path / "f", "w+") as fh:
            return TerminalKeys(lambda c, s: {}, print, stream=fh).start()
    assert asyncio.run(main()) is False
