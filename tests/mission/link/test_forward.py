"""MAVLink forwarding (mission.link.forward): vehicle frames copied to UDP clients byte for byte;
client frames dropped and counted when read-only, relayed to the addressed vehicle only when the
plan allows; `--out` and `[forward]` checked; MAVProxy as the client of a whole mission sees every
vehicle, its position and its mode."""
from __future__ import annotations

import asyncio
import importlib.util
import os
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from mission.link.forward import Forwarder, plan_with_outs
from mission.telemetry.mission_log import read_mission_log
from tests.support.wait_helpers import wait_until, wait_until_async

pytestmark = pytest.mark.timeout(180)

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"


def _udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(5.0)
    return s


def _command_long(target: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    return mav.command_long_encode(target, 1, mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav)


class _Endpoint:
    """What the forwarder needs of a MavEndpoint: the system ids heard, send()."""

    def __init__(self, sysids):
        self.sysids, self.sent, self.forward = set(sysids), [], None

    def sysids_seen(self):
        return self.sysids

    def send(self, sysid, msg):
        self.sent.append((sysid, msg.get_type(), msg.command))
        return True


def _exchange(allow_commands: bool):
    """A vehicle frame out to a client, then the client's COMMAND_LONGs back (to 2, to 9, to all)."""
    client = _udp_socket()
    async def main():
        fwd = Forwarder([f"udp:127.0.0.1:{client.getsockname()[1]}"], allow_commands, vehicle_sysids=[1, 2])
        ep = _Endpoint([1, 2])
        fwd.start()
        fwd.attach(ep)
        assert ep.forward == fwd.copy
        heartbeat = mavlink.MAVLink(None, srcSystem=2, srcComponent=1).heartbeat_encode(
            2, 12, 0, 0, 4, 3).pack(mavlink.MAVLink(None, srcSystem=2, srcComponent=1))
        ep.forward(heartbeat)                                   # as the endpoint does for an accepted frame
        data, source = await asyncio.get_running_loop().run_in_executor(None, client.recvfrom, 4096)
        for target in (2, 9, 0):
            client.sendto(_command_long(target), source)
        client.sendto(b"\xfd\x09garbage", source)
        await wait_until_async(lambda: sum(fwd.counters[k] for k in ("dropped_read_only", "relayed",
                                                                     "dropped_no_target")) >= (4 if allow_commands else 3),
                               5.0, "the client's frames")
        await fwd.close()
        return data == heartbeat, dict(fwd.counters), ep.sent, fwd.summary()

    try:
        return asyncio.run(main())
    finally:
        client.close()


def test_read_only_by_default_client_frames_are_dropped_and_counted():
    same, counters, sent, summary = _exchange(allow_commands=False)
    assert same and counters["frames_out"] == 1
    assert sent == [] and counters["dropped_read_only"] == 3 and counters["relayed"] == 0
    assert "read-only" in summary and "dropped 3 (read-only)" in summary


def test_commands_are_relayed_to_the_addressed_vehicles_when_allowed():
    same, counters, sent, _ = _exchange(allow_commands=True)
    assert same
    land = mavlink.MAV_CMD_NAV_LAND
    assert sent == [(2, "COMMAND_LONG", land), (1, "COMMAND_LONG", land), (2, "COMMAND_LONG", land)]
    assert counters["relayed"] == 3 and counters["dropped_no_target"] == 1   # sysid 9 is no vehicle


def test_forward_plan_keys_and_out_addresses_are_checked():
    doc = tomllib.loads(SAMPLE.read_text())
    doc["forward"] = {"out": ["udp:10.0.0.5:14550", "tcp:1.2.3.4:5"], "allow_commands": "yes", "bogus": 1}
    with pytest.raises(PlanError) as err:
        parse_plan(doc)
    keys = [k for k, _ in err.value.problems]
    assert {"forward.out[1]", "forward.allow_commands", "forward.bogus"} <= set(keys)
    doc["forward"] = {"out": ["udp:10.0.0.5:14550"]}
    plan = plan_with_outs(parse_plan(doc), ["udp:127.0.0.1:14551"])
    assert plan.forward.out == ("udp:10.0.0.5:14550", "udp:127.0.0.1:14551") and not plan.forward.allow_commands


def test_bad_out_option_exits_2():
    p = subprocess.run([sys.executable, "-m", "mission", "run", "--out", "udp:nowhere"], cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "must look like udp:HOST:PORT" in p.stderr


# ------------------------------------------------------------------------------ MAVProxy
def _tlog_view(path: Path) -> dict:
    """Per system id: heartbeats, modes and positions in a MAVProxy telemetry log."""
    from pymavlink import mavutil

    seen: dict[int, dict] = {}
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    while (msg := log.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT"])) is not None:
        sysid = msg.get_srcSystem()
        if sysid == 255:
            continue
        v = seen.setdefault(sysid, {"heartbeats": 0, "modes": set(), "positions": []})
        if msg.get_type() == "HEARTBEAT":
            v["heartbeats"] += 1
            v["modes"].add(mavutil.mode_string_v10(msg))
        else:
            v["positions"].append((msg.lat * 1e-7, msg.lon * 1e-7, msg.relative_alt * 1e-3))
    log.close()
    return seen


@pytest.mark.slow
def test_mavproxy_sees_every_vehicle_its_position_and_mode(tmp_path):
    if importlib.util.find_spec("MAVProxy") is None:
        pytest.skip("MAVProxy is not installed (pip install '.[test]')")
    probe = _udp_socket()
    port = probe.getsockname()[1]
    probe.close()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with open(tmp_path / "mavproxy.out", "w") as out:
        # as a module of this interpreter: the ``mavproxy.py`` on PATH may be a pyenv shim (a shell script)
        mp = subprocess.Popen([sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpin:127.0.0.1:{port}", "--daemon",
                               "--non-interactive", "--logfile=mav.tlog", f"--state-basedir={tmp_path}"],
                              cwd=tmp_path, stdout=out, stderr=subprocess.STDOUT, env=env)
    try:
        wait_until(lambda: "Waiting for heartbeat" in (tmp_path / "mavproxy.out").read_text(), 60.0,
                   "MAVProxy to listen", poll_s=0.1)
        run = subprocess.run([sys.executable, "-m", "mission", "run", "--n", "4", "--out", f"udp:127.0.0.1:{port}",
                              "--log-dir", str(tmp_path / "run"), "--no-tlog", "--max-iterations", "20"],
                             cwd=ROOT, env=env, capture_output=True, text=True, timeout=150)
        assert run.returncode in (0, 1), run.stderr[-2000:]

        def everyone():
            view = _tlog_view(tmp_path / "mav.tlog")
            return view if all(view.get(s, {}).get("positions") and "LAND" in view[s]["modes"]
                               for s in (1, 2, 3, 4)) else None

        view = wait_until(everyone, 60.0, "MAVProxy's log to show all four vehicles", poll_s=0.5)
    finally:
        mp.terminate()
        try:
            mp.wait(timeout=20)
        except subprocess.TimeoutExpired:
            mp.kill()
    text = (tmp_path / "mavproxy.out").read_text()
    from mission.sim.embedded import DEFAULT_ORIGIN

    for sysid in (1, 2, 3, 4):
        assert f"Detected vehicle {sysid}:1" in text
        v = view[sysid]
        assert v["heartbeats"] >= 10 and {"OFFBOARD", "LAND"} <= v["modes"], v["modes"]
        lat, lon, _ = v["positions"][-1]
        assert abs(lat - DEFAULT_ORIGIN[0]) < 0.01 and abs(lon - DEFAULT_ORIGIN[1]) < 0.01
        assert max(p[2] for p in v["positions"]) > 5.0                 # it saw them fly
    forward = [r for r in read_mission_log(tmp_path / "run" / "mission.jsonl")
               if r["type"] == "event" and "forward" in r]
    counters = forward[-1]["forward"]
    first = [r for r in read_mission_log(tmp_path / "run" / "mission.jsonl")
             if r["type"] == "event" and "the forward is read-only" in r["message"]]
    assert len(first) == 1 and first[0]["level"] == "warning"
    assert counters["frames_out"] > 1000 and counters["relayed"] == 0
    assert counters["dropped_read_only"] > 0 and counters["dropped_read_only"] == counters["client_frames"]
