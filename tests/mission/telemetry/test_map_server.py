"""The live map's server without a browser: who may command (loopback, password, origin, CSRF), the
feed of snapshots to the pages, the replay of a mission log, and the ``map`` command's bad input
(one line, non-zero exit). The browser itself: tests/mission/telemetry/test_map_browser.py."""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import aiohttp
import pytest
from aiohttp.test_utils import TestClient, TestServer

from mission.cli import main as swarmseek
from mission.cli.cmd_map import bind_address, tile_url
from mission.telemetry.map_feed import MapFeed
from mission.telemetry.map_replay import MissionLogReplay, ReplayError, ReplayPlayer
from mission.telemetry.map_server import MapAccess, is_loopback, make_app

ROOT = Path(__file__).resolve().parents[3]


def test_bind_and_tile_url_options():
    assert bind_address("8470") == ("127.0.0.1", 8470)
    assert bind_address("0.0.0.0:0") == ("0.0.0.0", 0)
    assert bind_address("[::1]:9000") == ("::1", 9000)
    for bad in ("host:", "x", "1.2.3.4:70000", ":80"):
        with pytest.raises(argparse.ArgumentTypeError):
            bind_address(bad)
    assert tile_url("http://127.0.0.1:8080/{z}/{x}/{y}.png")
    for bad in ("ftp://x/{z}/{x}/{y}", "http://x/{z}/{x}.png", "http://x/{z}/{x}/{y}\"onload=1"):
        with pytest.raises(argparse.ArgumentTypeError):
            tile_url(bad)


def test_access_is_read_only_off_loopback_without_a_password():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10")
    assert not MapAccess("127.0.0.1").read_only
    off = MapAccess("0.0.0.0")
    assert off.read_only and "--password-file" in off.read_only_reason
    with_password = MapAccess("0.0.0.0", password=b"s3cret")
    assert not with_password.read_only
    assert with_password.login("wrong") is None and with_password.login("s3cret")


async def _client(access: MapAccess, sent: list, feed: MapFeed | None = None) -> TestClient:
    def send(command):
        sent.append(command)
        return {"command": command, "accepted": True, "reason": "ok", "phase": "seek"}
    app = make_app(feed or MapFeed({"fleet": "f"}), access, None if access.read_only else send)
    client = TestClient(TestServer(app))
    await client.start_server()
    return client


def _headers(client: TestClient, access: MapAccess, origin: str | None = None) -> dict:
    return {"Origin": origin or f"http://{client.host}:{client.port}", "X-CSRF-Token": access.csrf_token}


def test_a_command_needs_same_origin_csrf_and_a_login_when_there_is_a_password():
    async def body():
        sent: list = []
        access = MapAccess("127.0.0.1")
        client = await _client(access, sent)
        try:
            ok = await client.post("/api/command", json={"command": "pause"}, headers=_headers(client, access))
            assert ok.status == 200 and (await ok.json())["accepted"] and sent == ["pause"]
            cross = await client.post("/api/command", json={"command": "abort"},
                                      headers=_headers(client, access, origin="http://evil.example"))
            assert cross.status == 403 and "cross-origin" in (await cross.json())["reason"]
            no_token = await client.post("/api/command", json={"command": "abort"},
                                         headers={"Origin": f"http://{client.host}:{client.port}"})
            assert no_token.status == 403 and "CSRF" in (await no_token.json())["reason"]
            unknown = await client.post("/api/command", json={"command": "explode"}, headers=_headers(client, access))
            assert unknown.status == 400
            assert sent == ["pause"]
        finally:
            await client.close()

        sent.clear()
        access = MapAccess("0.0.0.0", password=b"s3cret")
        client = await _client(access, sent)
        try:
            before = await client.post("/api/command", json={"command": "pause"}, headers=_headers(client, access))
            assert before.status == 403 and "log in" in (await before.json())["reason"]
            bad = await client.post("/api/login", json={"password": "nope"}, headers=_headers(client, access))
            assert bad.status == 403
            good = await client.post("/api/login", json={"password": "s3cret"}, headers=_headers(client, access))
            assert good.status == 200
            after = await client.post("/api/command", json={"command": "pause"}, headers=_headers(client, access))
            assert after.status == 200 and sent == ["pause"]
        finally:
            await client.close()
    asyncio.run(body())


def test_a_read_only_map_refuses_every_command():
    async def body():
        sent: list = []
        access = MapAccess("0.0.0.0")
        client = await _client(access, sent)
        try:
            for command in ("pause", "abort", "land"):
                r = await client.post("/api/command", json={"command": command}, headers=_headers(client, access))
                assert r.status == 403 and "read-only" in (await r.json())["reason"]
            assert sent == []
        finally:
            await client.close()
    asyncio.run(body())


def _state(k: int, final: bool = False) -> dict:
    return {"schema": "swarmseek.mission_state.v1", "phase": "seek", "t_s": 100.0 + k, "elapsed_s": float(k),
            "centre_enu": [k, 0.0, 10.0], "vehicles": [{"sysid": 1, "position_enu": [k, 1.0, 10.0]}],
            "events": [{"seq": k, "t_s": 100.0 + k, "type": "event", "message": f"e{k}"}], "final": final}


def test_the_feed_streams_every_snapshot_and_sends_a_late_page_the_history():
    async def body():
        access = MapAccess("127.0.0.1")
        feed = MapFeed({"fleet": "f"})
        client = await _client(access, [], feed)
        try:
            feed.push(_state(1))
            resp = await client.get("/events")
            assert resp.headers["Content-Type"].startswith("text/event-stream")
            feed.push(_state(2))
            kinds, datas = [], []
            while len(datas) < 4:
                line = (await resp.content.readline()).decode().strip()
                if line.startswith("event: "):
                    kinds.append(line[7:])
                elif line.startswith("data: "):
                    datas.append(json.loads(line[6:]))
            assert kinds == ["config", "history", "state", "state"]
            assert datas[1]["tracks"]["1"] == [[1.0, 1.0, 10.0]] and datas[1]["events"][0]["message"] == "e1"
            assert datas[3]["t_s"] == 102.0
            resp.close()
        finally:
            await client.close()
    asyncio.run(body())


def test_stopping_the_server_ends_every_page_stream_open_or_abandoned():
    """A page still reading and a page that went away without a word: stopping the server ends
    both streams (the open page reads the end) instead of waiting for aiohttp's 60 s shutdown
    timeout, which held ``fly --map`` and ``run --map`` 20 s at exit (two 10 s thread joins)."""
    from mission.telemetry.map_server import MapServer

    async def body():
        feed = MapFeed({"fleet": "f"})
        server = MapServer(make_app(feed, MapAccess("127.0.0.1"), None), "127.0.0.1", 0)
        await server.start()
        async with aiohttp.ClientSession() as http:
            gone = await http.get(server.url + "events")
            assert (await gone.content.readline()).startswith(b"event: config")
            gone.close()                                         # the page went away
            page = await http.get(server.url + "events")
            feed.push(_state(1))
            await asyncio.wait_for(server.stop(), 30.0)          # not aiohttp's 60 s
            rest = await asyncio.wait_for(page.content.read(), 30.0)
            assert rest.count(b"event: ") == 3 and page.content.at_eof()  # config, history, state; then the end
            assert feed.pages == 0
    asyncio.run(body())


def test_a_slow_page_loses_its_oldest_snapshots_never_the_newest():
    async def body():
        feed = MapFeed({})
        q = feed.subscribe()
        for k in range(100):
            feed.push(_state(k))
        assert feed.dropped > 0
        last = None
        while not q.empty():
            last = q.get_nowait()
        assert b'"t_s":199.0' in last
    asyncio.run(body())


def _write_log(path, records):
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


def _flown_log(path):
    plan = {"fleet": "f", "origin": [45.0, 5.0, 200.0],
            "geofence": {"polygon_en_m": [[-50, -50], [50, -50], [50, 50], [-50, 50]], "min_alt_m": 2, "max_alt_m": 60}}
    veh = lambda e: [{"sysid": 1, "id": "a", "status": "in formation", "armed": True, "relative_alt_m": 10.0,  # noqa: E731
                      "position_enu": [e, 0.0, 10.0]}]
    _write_log(path, [
        {"t_s": 0.0, "type": "event", "message": "embedded mock fleet", "source_enu": [9.0, 1.0, 12.0]},
        {"t_s": 0.1, "type": "plan", "plan": plan}, {"t_s": 0.2, "type": "phase", "phase": "seek"},
        {"t_s": 1.0, "type": "status", "phase": "seek", "centre_enu": [0.0, 0.0, 10.0], "vehicles": veh(0.0)},
        {"t_s": 1.5, "type": "iteration", "k": 1, "estimate_enu": [5.0, 0.0, 10.0], "estimate_region95_m": 2.0,
         "estimate_map": {"east0_m": 3.0, "north0_m": -2.0, "cell_m": 1.0, "prob_e4": [[0, 10], [9990, 0]],
                          "outside": 0.0}},
        {"t_s": 2.0, "type": "status", "phase": "seek", "centre_enu": [2.0, 0.0, 10.0], "vehicles": veh(2.0)},
        {"t_s": 3.0, "type": "summary", "outcome": "converged", "message": "converged after 1 iteration"}])


def test_a_mission_log_replays_as_the_snapshots_the_mission_published(tmp_path):
    log = tmp_path / "mission.jsonl"
    _flown_log(log)
    replay = MissionLogReplay.load(log)
    assert replay.truth_enu == [9.0, 1.0, 12.0]
    first, second, last = replay.frames
    assert first["geometry"]["fence_en_m"][0] == [-50, -50] and first["estimate_enu"] is None
    assert first["vehicles"][0]["flight_state"] == "flying"
    assert second["estimate_enu"] == [5.0, 0.0, 10.0] and second["estimate_region95_m"] == 2.0
    assert second["estimate_map"]["prob_e4"][1][0] == 9990 and first["estimate_map"] is None
    assert last["final"] and last["ending"]["outcome"] == "converged"
    assert replay.index_at(1.7) == 0 and replay.index_at(2.0) == 1

    async def seek():
        feed = MapFeed({})
        player = ReplayPlayer(replay, feed, speed=1.0)
        player.control({"seek_s": 1.0})
        assert player.index == 1 and feed.latest["t_s"] == 2.0
        assert [p[0] for p in feed.tracks["1"].points] == [0.0, 2.0]
    asyncio.run(seek())


def test_a_log_that_cannot_be_replayed_is_one_line(tmp_path):
    with pytest.raises(ReplayError, match="cannot read"):
        MissionLogReplay.load(tmp_path / "missing.jsonl")
    empty = tmp_path / "phases.jsonl"
    _write_log(empty, [{"t_s": 0.0, "type": "phase", "phase": "connect"}])
    with pytest.raises(ReplayError, match="no status record"):
        MissionLogReplay.load(empty)


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_map_bad_input_is_one_line_and_a_non_zero_exit(tmp_path, capsys):
    assert swarmseek(["map", "--log", str(tmp_path / "none.jsonl")]) == 1
    assert "cannot read the mission log" in _one_line(capsys)
    assert swarmseek(["map"]) == 2
    assert "give the FLEET" in _one_line(capsys)
    assert swarmseek(["map", "f", "--zenoh-connect", "tcp/127.0.0.1:1", "--wait-s", "1"]) == 3
    assert "cannot reach tcp/127.0.0.1:1" in _one_line(capsys)
    empty = tmp_path / "pw"
    empty.write_text("\n")
    assert swarmseek(["map", "f", "--zenoh-connect", "tcp/127.0.0.1:1", "--password-file", str(empty)]) == 2
    assert "password file" in _one_line(capsys)
    with pytest.raises(SystemExit) as exc:
        swarmseek(["map", "f", "--tile-url", "http://x/{z}.png"])
    assert exc.value.code == 2


def test_a_port_in_use_is_one_line_before_anything_flies(tmp_path, capsys):
    log = tmp_path / "mission.jsonl"
    _flown_log(log)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert swarmseek(["map", "--log", str(log), "--bind", f"127.0.0.1:{port}"]) == 1
        assert "cannot serve the map" in _one_line(capsys)
        assert swarmseek(["run", "--map", f"127.0.0.1:{port}", "--log-dir", str(tmp_path / "run"), "--json"]) == 1
        line = capsys.readouterr().err
        assert "--map: cannot serve the map on 127.0.0.1" in line
        flown = tmp_path / "run" / "mission.jsonl"
        assert not flown.exists() or flown.read_text() == ""  # the log is only checked writable: nothing flew


def _normalised(path):
    out = []
    for line in open(path, encoding="utf-8"):
        line = re.sub(r"127\.0\.0\.1:\d+", "127.0.0.1:PORT", line)
        rec = json.loads(line.replace(", listening on tcp/127.0.0.1:PORT", ""))  # the preflight's zenoh line
        rec.pop("log_path", None)
        if rec["type"] == "plan":
            rec["plan"]["zenoh"].pop("listen")  # --map adds the endpoint its own zenoh session reaches
        out.append(rec)
    return out


class _Stream(threading.Thread):
    """Reads a map's event stream, counting the state snapshots."""

    def __init__(self, url):
        super().__init__(daemon=True)
        self.url, self.states, self.final = url, 0, False
        self.start()

    def run(self):
        with urllib.request.urlopen(self.url + "events", timeout=60) as resp:
            for raw in resp:
                line = raw.decode()
                if line.startswith("event: state"):
                    self.states += 1
                if line.startswith("data: ") and '"final":true' in line:
                    self.final = True
                    return


@pytest.mark.slow
def test_a_map_leaves_a_lockstep_mission_unchanged(tmp_path):
    """One seed flown lock-step without and with ``--map`` (a page reading its stream): the same
    mission log, record for record, but for the zenoh endpoint the map reaches."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    argv = [sys.executable, "-m", "mission", "run", "--n", "4", "--seed", "7", "--max-iterations", "6", "--json",
            "--no-tlog"]
    plain = subprocess.run(argv + ["--log-dir", str(tmp_path / "plain")], env=env, cwd=ROOT,
                           capture_output=True, text=True, timeout=300)
    proc = subprocess.Popen(argv + ["--log-dir", str(tmp_path / "map"), "--map", "127.0.0.1:0"], env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        url = re.search(r"live map at (http://\S+/)", proc.stderr.readline()).group(1)
        stream = _Stream(url)
        assert proc.wait(timeout=300) == plain.returncode
        stream.join(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert stream.states > 0 and stream.final  # it really watched, to the mission's end
    a, b = _normalised(tmp_path / "plain" / "mission.jsonl"), _normalised(tmp_path / "map" / "mission.jsonl")
    assert sum(r["type"] == "iteration" for r in a) == 6
    assert len(a) == len(b)
    for rec_a, rec_b in zip(a, b):
        assert rec_a == rec_b
