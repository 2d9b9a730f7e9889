"""Who may command: the plan's zenoh access control (``commander_usernames``) lets a commander's
`swarmseek ctl` reach the coordinator's control queryable and refuses a monitor's (zenoh drops
it: ctl says no coordinator answered, status 3); the control channel rejects malformed requests."""
from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from mission.sim.embedded import free_port_block
from mission.telemetry.control_channel import control_key, parse_request
from tests.support.control_peer import ControlPeer
from tests.support.tls_helpers import write_private
from tests.support.wait_helpers import wait_until

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"


def _free_port() -> int:
    return free_port_block(1, kinds=("tcp",))


def _plan(tmp_path, port, access_control):
    doc = tomllib.loads(SAMPLE.read_text())
    users = write_private(tmp_path / "users.txt", b"sensor1:s3cret\nviewer:v1ew\nops:0ps\n")
    doc["zenoh"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"], "auth": {"dictionary_file": users},
                    "access_control": access_control}
    return parse_plan(doc)


def _ctl(tmp_path, port, user, password, command="pause", timeout_s="6"):
    pw = write_private(tmp_path / f"{user}.pw", (password + "\n").encode())
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-m", "mission", "ctl", "sitl", command, "--sender", user,
                        "--zenoh-connect", f"tcp/127.0.0.1:{port}", "--zenoh-user", user,
                        "--zenoh-password-file", pw, "--timeout-s", timeout_s],
                       env=env, cwd=ROOT, capture_output=True, text=True, timeout=60)
    return p.returncode, p.stdout + p.stderr


def test_a_commander_is_answered_and_a_monitor_is_refused(tmp_path):
    port = _free_port()
    plan = _plan(tmp_path, port, {"sensor_usernames": ["sensor1"], "monitor_usernames": ["viewer", "ops"],
                                  "commander_usernames": ["ops"]})
    acl = plan.zenoh.access_control
    assert acl.commander_usernames == ("ops",) and acl.control_key_expr == control_key("sitl")
    coord = ControlPeer(plan)
    try:
        rc, out = _ctl(tmp_path, port, "ops", "0ps")
        assert rc == 0 and "pause accepted" in out, out
        rc, out = _ctl(tmp_path, port, "viewer", "v1ew", command="land")
        assert rc == 3 and "no coordinator of fleet 'sitl' answers" in out, out
    finally:
        coord.close()
    assert coord.commands == [("pause", "ops")]          # the monitor's land never reached it


def test_commander_names_need_authentication(tmp_path):
    doc = tomllib.loads(SAMPLE.read_text())
    doc["zenoh"] = {"listen": ["tcp/127.0.0.1:7447"],
                    "access_control": {"sensor_usernames": ["s"], "commander_usernames": ["ops"]}}
    with pytest.raises(PlanError) as err:
        parse_plan(doc)
    assert "zenoh.access_control.commander_usernames" in [k for k, _ in err.value.problems]


@pytest.mark.parametrize("payload, why", [
    (b"\xff\xfe", "not UTF-8 JSON"), (b"[1]", "not a JSON object"),
    (json.dumps({"schema": "x", "command": "pause", "sender": "a"}).encode(), "schema"),
    (json.dumps({"schema": "swarmseek.command.v1", "command": 3, "sender": "a"}).encode(), "string fields"),
    (b"{" + b" " * 5000 + b"}", "more than"),
])
def test_malformed_requests_are_rejected_with_a_reason(payload, why):
    with pytest.raises(ValueError, match=why):
        parse_request(payload)


def test_the_channel_answers_a_malformed_query_and_counts_it(tmp_path):
    import zenoh

    port = _free_port()
    plan = parse_plan({**tomllib.loads(SAMPLE.read_text()),
                       "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"]}})
    coord = ControlPeer(plan)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    client = zenoh.open(conf)
    try:
        querier = client.declare_querier(control_key("sitl"), timeout=5.0)
        wait_until(lambda: querier.matching_status.matching, 10.0, "the control queryable")
        replies = [json.loads(r.ok.payload.to_bytes()) for r in querier.get(payload=b"pause please") if r.ok]
    finally:
        client.close()
        coord.close()
    assert len(replies) == 1 and replies[0]["accepted"] is False and "bad request" in replies[0]["reason"]
    assert coord.channel.bad_requests == 1 and coord.commands == []
