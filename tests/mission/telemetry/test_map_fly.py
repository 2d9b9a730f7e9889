"""``fly --map`` and ``resume --map``: the live map beside a mission flown against a mock fleet.

The mock fleet runs in this process (its thread, wall clock); ``fly`` and ``resume`` run in their
own processes with ``--map 127.0.0.1:0``. The page is read as a browser would, without one: the
event stream (``GET /events``, server-sent events, with the aiohttp client) and the command API
(``POST /api/command`` with the page's CSRF token and a same-origin ``Origin``). The map reads the
mission's own zenoh session: the plan's endpoints are all the mission has (checked in its log).
"""
from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from tests.support.fly_process import subprocess_env
from tests.support.fly_helpers import summary_exit_status
from tests.support.gcs_fault_support import N, NIMBLE, _plan_toml
from tests.support.invariants import abandoned
from mission.cli import main as cli_main
from mission.flight.coordinator import _plan_json
from mission.sim.embedded import DEFAULT_ORIGIN, fleet_ports, free_port_block
from mission.telemetry.mission_log import read_mission_log
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet
from tests.support.wait_helpers import wait_until

pytestmark = pytest.mark.timeout(500)

ROOT = Path(__file__).resolve().parents[3]
#: wall seconds for one condition seen on the page (takeoff and assembly of 4 vehicles on a loaded host)
PAGE_WAIT_S = 180.0
#: far from the start (0, 0, 6) for 1 m steps: the seek goes on until the page's commands end it
SOURCE = np.array([40.0, 30.0, 6.0])


class _Process:
    """``swarmseek ARGS`` in its own process; its standard error collected line by line."""

    def __init__(self, *args: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "mission", *args], env=subprocess_env(), cwd=ROOT,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def map_url(self) -> str:
        """The page's URL, once the process printed it."""
        line = wait_until(lambda: next((x for x in self.lines if "live map at " in x), None)
                          or self.proc.poll() is not None, 120.0, "the live map's URL")
        assert isinstance(line, str), f"exited {self.proc.returncode} before serving the map: {self.lines}"
        return line.split("live map at ", 1)[1].strip()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=30)


async def _events(resp):
    """``(event, data)`` of a server-sent event stream, until it ends."""
    event = None
    async for raw in resp.content:
        line = raw.decode().rstrip("\n")
        if line.startswith("event: "):
            event = line[len("event: "):]
        elif line.startswith("data: "):
            yield event, json.loads(line[len("data: "):])


async def _state_until(events, predicate, what: str) -> dict:
    """The first state snapshot for which ``predicate`` holds (the stream must not end first)."""
    async def scan():
        async for event, data in events:
            if event == "state" and predicate(data):
                return data
        raise AssertionError(f"the page's stream ended before {what}")
    return await asyncio.wait_for(scan(), PAGE_WAIT_S)


def _sysids(state: dict) -> set:
    return {v.get("sysid") for v in state.get("vehicles") or ()}


async def _command(http, url: str, config: dict, command: str) -> dict:
    """Press a button: ``POST /api/command`` as the page does (CSRF token, same origin)."""
    headers = {"Origin": url.rstrip("/"), "X-CSRF-Token": config["csrf_token"]}
    async with http.post(url + "api/command", json={"command": command}, headers=headers) as resp:
        ack = await resp.json()
        assert resp.status == 200, ack
        return ack


async def _operate_page(url: str) -> dict:
    """Watch until the seek with every vehicle on the page, Pause, see the hold, Land; the final snapshot."""
    timeout = aiohttp.ClientTimeout(total=None, sock_read=PAGE_WAIT_S)
    async with aiohttp.ClientSession(timeout=timeout, read_bufsize=1 << 20) as http:
        async with http.get(url + "events") as resp:
            assert resp.status == 200 and resp.headers["Content-Type"].startswith("text/event-stream")
            events = _events(resp)
            event, config = await asyncio.wait_for(events.__anext__(), PAGE_WAIT_S)
            assert event == "config" and not config["read_only"] and config["csrf_token"]
            seek = await _state_until(events, lambda s: s.get("phase") == "seek" and _sysids(s) == set(range(1, N + 1)),
                                      "the seek with every vehicle")
            assert all(len(v["position_enu"]) == 3 for v in seek["vehicles"])
            ack = await _command(http, url, config, "pause")
            assert ack["accepted"] and ack["command"] == "pause" and ack["sender"].startswith("map:"), ack
            held = await _state_until(events, lambda s: (s.get("control") or {}).get("holding"), "the hold")
            assert _sysids(held) == set(range(1, N + 1))
            ack = await _command(http, url, config, "land")
            assert ack["accepted"], ack
            return await _state_until(events, lambda s: s.get("final"), "the final snapshot")


async def _watch_to_the_end(url: str) -> dict:
    """The final snapshot of the page's stream."""
    timeout = aiohttp.ClientTimeout(total=None, sock_read=PAGE_WAIT_S)
    async with aiohttp.ClientSession(timeout=timeout, read_bufsize=1 << 20) as http:
        async with http.get(url + "events") as resp:
            return await _state_until(_events(resp), lambda s: s.get("final"), "the final snapshot")


def _fleet_and_plan(tmp_path: Path):
    ports = fleet_ports(N, "px4")
    endpoint = f"tcp/127.0.0.1:{free_port_block(1, kinds=('tcp',))}"
    plan = _plan_toml(tmp_path / "plan.toml", ports["udp_base_port"], f'mode = "peer"\nlisten = ["{endpoint}"]', 40)
    fleet = MockFleet(n=N, personality="px4", field=sigma2(SOURCE), origin=DEFAULT_ORIGIN, seed=3,
                      udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, fleet_name="gcsfaults", zenoh_connect=[endpoint], dynamics=NIMBLE)
    return fleet, plan, endpoint


@pytest.mark.slow
def test_fly_map_streams_every_vehicle_pauses_from_the_page_and_resume_serves_it(tmp_path):
    fleet, plan, endpoint = _fleet_and_plan(tmp_path)
    log = tmp_path / "log" / "mission.jsonl"
    fleet.start()
    fly = resume = None
    try:
        fly = _Process("fly", "--plan", str(plan), "--log-dir", str(log.parent), "--no-tlog", "--json",
                       "--map", "127.0.0.1:0")
        final = asyncio.run(_operate_page(fly.map_url()))
        assert final["ending"]["outcome"] != "converged" and final["ending"]["message"]  # the page's outcome
        status = fly.proc.wait(timeout=200)                                      # ended by the operator:
        summary = next(r for r in read_mission_log(log) if r["type"] == "summary")  # 1 (4: a vehicle lost on a loaded host)
        assert status == summary_exit_status(summary) == (4 if summary["lost"] else 1), fly.lines
        assert not abandoned(fleet, log)
        wait_until(lambda: not any(v.autopilot.armed for v in fleet.vehicles), 90.0, "every vehicle disarmed", 0.1)
        records = read_mission_log(log)
        commands = [(r["command"], r["sender"][:4], r["accepted"]) for r in records if r["type"] == "command"]
        assert commands == [("pause", "map:", True), ("land", "map:", True)]
        plan_record = next(r for r in records if r["type"] == "plan")
        assert plan_record["plan"]["zenoh"]["listen"] == [endpoint]  # --map added no endpoint

        resume = _Process("resume", str(log), "--no-tlog", "--json", "--map", "127.0.0.1:0")
        final = asyncio.run(_watch_to_the_end(resume.map_url()))
        assert final["ending"]["outcome"] == "recovered" and _sysids(final) == set(range(1, N + 1)), final
        assert resume.proc.wait(timeout=200) == 0, resume.lines
    finally:
        for p in (fly, resume):
            if p is not None:
                p.stop()
        fleet.stop()


def _log_with_a_plan(tmp_path: Path) -> Path:
    from mission.sim.embedded import embedded_plan

    log = tmp_path / "stopped" / "mission.jsonl"
    log.parent.mkdir()
    plan = embedded_plan(4, {"udp_base_port": 15000, "zenoh_port": 7447})
    log.write_text("\n".join(json.dumps(r) for r in (
        {"t_s": 0, "type": "plan", "plan": _plan_json(plan)},
        {"t_s": 1, "type": "phase", "phase": "seek"})) + "\n")
    return log


def test_fly_and_resume_refuse_a_map_port_in_use_before_anything_is_armed(tmp_path, capsys):
    ports = fleet_ports(N, "px4")
    plan = _plan_toml(tmp_path / "plan.toml", ports["udp_base_port"], 'mode = "peer"\nlisten = ["tcp/127.0.0.1:0"]')
    stopped = _log_with_a_plan(tmp_path)
    before = stopped.read_text()
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert cli_main(["fly", "--plan", str(plan), "--log-dir", str(tmp_path / "fly"), "--json",
                         "--map", f"127.0.0.1:{port}"]) == 1
        err = [x for x in capsys.readouterr().err.splitlines() if "--map" in x]
        assert len(err) == 1 and err[0].startswith(f"swarmseek fly: --map: cannot serve the map on 127.0.0.1:{port}: ") \
            and "in use" in err[0].lower(), err
        flown = tmp_path / "fly" / "mission.jsonl"
        assert not flown.exists() or flown.read_text() == ""        # nothing connected, nothing armed
        assert cli_main(["resume", str(stopped), "--json", "--map", f"127.0.0.1:{port}"]) == 1
        err = capsys.readouterr().err
        assert f"swarmseek resume: --map: cannot serve the map on 127.0.0.1:{port}" in err, err
        assert stopped.read_text() == before                         # nothing re-engaged


async def _page_commands_through(url: str, put_state) -> tuple[dict, dict]:
    """Read the page's stream until a state arrives (``put_state()`` publishes one every 0.1 s
    meanwhile: the map subscribes once attached), then press Pause; the state and the answer."""
    timeout = aiohttp.ClientTimeout(total=None, sock_read=60)
    async with aiohttp.ClientSession(timeout=timeout) as http:
        async with http.get(url + "events") as resp:
            events = _events(resp)
            event, config = await asyncio.wait_for(events.__anext__(), 60)
            assert event == "config"

            async def publish():
                while True:
                    put_state()
                    await asyncio.sleep(0.1)
            publisher = asyncio.create_task(publish())
            try:
                state = await _state_until(events, lambda s: True, "a state published on the mission's session")
            finally:
                publisher.cancel()
            return state, await _command(http, url, config, "pause")


def test_the_map_reads_and_commands_through_the_missions_own_session_under_access_control(tmp_path):
    """A plan with authentication and access control (only ``ops`` may command): the map attached
    to the coordinator's own session receives its state and its Pause reaches the coordinator,
    with no endpoint or credential of its own; the session is the mission's to close."""
    from mission.telemetry.map_live import MapThread
    from mission.telemetry.map_server import MapAccess
    from mission.telemetry.state_pub import STATE_SCHEMA, state_key
    from tests.mission.telemetry.test_ctl_access import _free_port, _plan
    from tests.support.control_peer import ControlPeer

    plan = _plan(tmp_path, _free_port(), {"sensor_usernames": ["sensor1"], "monitor_usernames": ["viewer", "ops"],
                                          "commander_usernames": ["ops"]})
    coord = ControlPeer(plan)
    thread = MapThread(plan.fleet, "127.0.0.1", 0, access=MapAccess("127.0.0.1"), sender="map:tester",
                       config={"tile_url": None, "truth_enu": None, "replay": None})
    try:
        url = thread.start()
        thread.attach(coord.session)
        state = {"schema": STATE_SCHEMA, "phase": "seek", "vehicles": [{"sysid": 1, "position_enu": [1.0, 2.0, 9.0]}]}
        seen, ack = asyncio.run(_page_commands_through(
            url, lambda: coord.session.put(state_key(plan.fleet), json.dumps(state).encode())))
        assert seen["vehicles"] == state["vehicles"] and ack["accepted"], ack
        assert coord.commands == [("pause", "map:tester")]
        coord.session.put(state_key(plan.fleet), json.dumps({**state, "final": True}).encode())
        thread.stop()
        assert thread.got_final() and not coord.session.is_closed()  # the mission closes its own session
    finally:
        thread.stop()
        coord.close()
