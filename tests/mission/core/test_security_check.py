"""The plan's security check (``mission.core.plan_security``, ``docs/security.md``).

Each configuration of the threat model as a plan: refused where it must be (the plan error, and
``dry-run`` / ``fly`` exit 2 with the line), accepted where who commands is authenticated, warned
where the plan allows an open network explicitly. "Is this loopback" is injectable: the checks
take the rule, so 127.0.0.1 stands in for a network address where a real one is not needed; the
command-line tests use this machine's own network address when it has one. Attackers are other
processes (``swarmseek ctl``) or sessions without the certificate or login.
"""
from __future__ import annotations

import asyncio
import ipaddress
import json
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from mission.core.plan import load_plan, parse_plan
from mission.core.plan_security import PlanSecurityError, check_security, refusals
from mission.core.plan_types import PlanError
from tests.support.fly_process import subprocess_env
from tests.support.control_peer import ControlPeer
from tests.support.tls_helpers import make_pki, write_private
from wire.loopback import host_is_loopback, zenoh_endpoint_host, zenoh_endpoint_is_loopback
from wire.zenoh_flags import plain_network_warning

pytestmark = pytest.mark.timeout(180)

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"


def _everything_is_network(host: str) -> bool:
    """A loopback rule under which 127.0.0.1 stands for an address of the network."""
    return False


def _free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _network_ipv4() -> str | None:
    """This machine's own IPv4 address on its default route (no packet sent), or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.254", 9))
        except OSError:
            return None
        ip = s.getsockname()[0]
    return None if ipaddress.ip_address(ip).is_loopback or ip == "0.0.0.0" else ip


@pytest.fixture()
def net_host() -> str:
    ip = _network_ipv4()
    if ip is None:
        pytest.skip("this machine has no non-loopback IPv4 address to stand for the network")
    return ip


def _doc(zenoh: dict | None = None, **sections) -> dict:
    doc = tomllib.loads(SAMPLE.read_text())
    if zenoh is not None:
        doc["zenoh"] = zenoh
    doc.update(sections)
    return doc


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict:
    return make_pki(tmp_path_factory.mktemp("pki"), (("coordinator", "coordinator", "ca"), ("ops", "ops", "ca"),
                                                     ("rogue", "ops", "other_ca")))


def _users(tmp_path: Path) -> str:
    return write_private(tmp_path / "users.txt", b"sensor1:s3cret\nops:0ps\nviewer:v1ew\n")


# --------------------------------------------------------------------------- the loopback rule
@pytest.mark.parametrize("host, local", [
    ("127.0.0.1", True), ("127.0.0.2", True), ("::1", True), ("[::1]", True), ("localhost", True),
    ("LOCALHOST", True), ("0.0.0.0", False), ("::", False), ("192.168.1.10", False), ("10.0.0.5", False),
    ("fd00::2", False), ("gcs.local", False), ("", False)])
def test_the_loopback_rule(host, local):
    assert host_is_loopback(host) is local


@pytest.mark.parametrize("endpoint, host, local", [
    ("tcp/127.0.0.1:7447", "127.0.0.1", True), ("tls/[::1]:7447", "[::1]", True),
    ("tcp/0.0.0.0:7447", "0.0.0.0", False), ("udp/192.168.1.10:7447#iface=eth0", "192.168.1.10", False),
    ("tls/gcs.example:7447?prio=1", "gcs.example", False), ("unixsock-stream//tmp/z.sock", None, True)])
def test_zenoh_endpoint_hosts(endpoint, host, local):
    assert zenoh_endpoint_host(endpoint) == host
    assert zenoh_endpoint_is_loopback(endpoint) is local


# --------------------------------------------------------------------------- plans: zenoh
def test_the_sample_plan_and_loopback_plans_have_no_finding():
    assert check_security(load_plan(SAMPLE)) == []
    plan = parse_plan(_doc({"listen": ["tcp/127.0.0.1:7447"], "connect": ["tcp/localhost:7448"]},
                           forward={"out": ["udp:127.0.0.1:14550"], "allow_commands": True}))
    assert check_security(plan) == []


@pytest.mark.parametrize("zenoh", [
    {"listen": ["tcp/0.0.0.0:7447"]},                       # every interface: open to the network
    {"listen": ["tcp/127.0.0.1:7447", "tcp/192.168.1.10:7447"]},
    {"connect": ["tcp/192.168.1.20:7447"]},                 # a peer it connects to
    {"mode": "client", "connect": ["tcp/router.example:7447"]},  # through a router
    {"listen": ["udp/[fd00::2]:7447"]},
])
def test_an_open_command_channel_on_the_network_is_refused(zenoh):
    with pytest.raises(PlanSecurityError, match=r"could command the fleet \(swarmseek ctl sitl land") as err:
        parse_plan(_doc(zenoh), source="plan.toml")
    assert [k for k, _ in err.value.problems] == ["zenoh.connect" if "listen" not in zenoh else "zenoh.listen"]
    assert isinstance(err.value, PlanError) and "allow_unauthenticated_network = true" in str(err.value)
    assert len(str(err.value).splitlines()) == 1  # one line


def test_logins_without_a_commander_rule_are_refused(tmp_path):
    zen = {"listen": ["tcp/0.0.0.0:7447"], "auth": {"dictionary_file": _users(tmp_path)}}
    with pytest.raises(PlanSecurityError, match="commander_usernames"):
        parse_plan(_doc(zen))


def test_the_loopback_rule_is_injectable():
    doc = _doc({"listen": ["tcp/127.0.0.1:7447"]})
    assert check_security(parse_plan(doc)) == []
    with pytest.raises(PlanSecurityError, match="tcp/127.0.0.1:7447 can be reached from the network"):
        parse_plan(doc, is_loopback=_everything_is_network)


def test_an_explicitly_allowed_open_network_is_flown_with_warnings():
    plan = parse_plan(_doc({"listen": ["tcp/0.0.0.0:7447"], "allow_unauthenticated_network": True}))
    findings = check_security(plan)
    assert [(f.level, f.key) for f in findings] == [("warn", "zenoh.allow_unauthenticated_network"),
                                                    ("warn", "zenoh.access_control")]
    assert "anyone who reaches tcp/0.0.0.0:7447 can command the fleet" in findings[0].text
    assert "put readings for any vehicle and so steer the formation anywhere within the geofence" in findings[1].text


def test_commands_off_leaves_the_readings_warning():
    plan = parse_plan(_doc({"listen": ["tcp/0.0.0.0:7447"]}, control={"remote": False}))
    assert [(f.level, f.key) for f in check_security(plan)] == [("warn", "zenoh.access_control")]


def test_allowing_on_loopback_is_stated_as_needless():
    plan = parse_plan(_doc({"listen": ["tcp/127.0.0.1:7447"], "allow_unauthenticated_network": True}))
    assert [(f.level, f.text) for f in check_security(plan)] == [
        ("info", "set, but every zenoh endpoint is loopback: nothing to allow")]


@pytest.mark.parametrize("value", ["yes", 1])
def test_allow_unauthenticated_network_must_be_a_bool(value):
    with pytest.raises(PlanError, match=r"zenoh.allow_unauthenticated_network: must be true or false") as err:
        parse_plan(_doc({"listen": ["tcp/127.0.0.1:7447"], "allow_unauthenticated_network": value}))
    assert not isinstance(err.value, PlanSecurityError)


def _mtls(pki) -> dict:
    cert, key = pki["coordinator"]
    return {"root_ca_certificate": pki["ca"], "listen_certificate": cert, "listen_private_key": key,
            "enable_mtls": True}


def test_tls_client_certificates_authenticate_who_commands(pki):
    plan = parse_plan(_doc({"listen": ["tls/0.0.0.0:7447"], "tls": _mtls(pki)}))
    assert [(f.level, f.key) for f in check_security(plan)] == [("info", "zenoh.tls.enable_mtls")]


def test_tls_without_client_certificates_is_refused(pki):
    tls = {k: v for k, v in _mtls(pki).items() if k != "enable_mtls"}
    with pytest.raises(PlanSecurityError, match="tls/0.0.0.0:7447 can be reached"):
        parse_plan(_doc({"listen": ["tls/0.0.0.0:7447"], "tls": tls}))


def test_a_plain_endpoint_next_to_mtls_is_refused(pki):
    with pytest.raises(PlanSecurityError, match=r"^refused: zenoh.listen: tcp/0.0.0.0:7448 can"):
        parse_plan(_doc({"listen": ["tls/0.0.0.0:7447", "tcp/0.0.0.0:7448"], "tls": _mtls(pki)}))


@pytest.mark.parametrize("commanders, who", [(["ops"], "only from ops"),
                                             ([], "from no zenoh peer (the terminal's keys only)")])
def test_logins_with_access_control_name_the_commanders(tmp_path, commanders, who):
    acl = {"sensor_usernames": ["sensor1"], "commander_usernames": commanders}
    plan = parse_plan(_doc({"listen": ["tcp/0.0.0.0:7447"], "auth": {"dictionary_file": _users(tmp_path)},
                            "access_control": acl}))
    assert [(f.level, f.text) for f in check_security(plan)] == [("info", f"commands over zenoh {who}")]


def test_a_routed_plan_states_that_the_router_decides(pki):
    cert, key = pki["coordinator"]
    tls = {"root_ca_certificate": pki["ca"], "connect_certificate": cert, "connect_private_key": key,
           "enable_mtls": True}
    plan = parse_plan(_doc({"mode": "client", "connect": ["tls/router.example:7447"], "tls": tls,
                            "access_control": {"sensor_cert_common_names": ["router"],
                                               "commander_cert_common_names": ["router"]}}))
    findings = check_security(plan)
    assert [(f.level, f.key) for f in findings] == [("info", "zenoh.access_control"), ("info", "zenoh.mode")]
    assert "routed through tls/router.example:7447" in findings[1].text


# --------------------------------------------------------------------------- plans: MAVLink, forward
def _vehicles(connection: str) -> list[dict]:
    return [{"id": f"copter{i}", "sysid": i, "connection": connection.format(i=i)} for i in range(1, 5)]


def _key_file(tmp_path: Path) -> str:
    return write_private(tmp_path / "signing.key", bytes(range(1, 33)).hex().encode())


@pytest.mark.parametrize("connection", ["serial:/dev/ttyUSB{i}:57600", "udpin:0.0.0.0:1455{i}",
                                        "tcp:192.168.1.{i}:5760"])
def test_an_unsigned_vehicle_link_off_loopback_is_warned(connection):
    findings = check_security(parse_plan(_doc(vehicles=_vehicles(connection))))
    assert [(f.level, f.key) for f in findings] == [("warn", f"vehicles[{j}].connection") for j in range(4)]
    assert "its MAVLink is not signed" in findings[0].text and "can command it" in findings[0].text


@pytest.mark.parametrize("connection", ["serial:/dev/ttyUSB{i}:57600", "udpin:0.0.0.0:1455{i}"])
def test_require_signing_refuses_an_unsigned_link_off_loopback(connection):
    doc = _doc(vehicles=_vehicles(connection), security={"require_signing": True})
    with pytest.raises(PlanSecurityError, match=r"vehicles\[0\].connection: vehicle copter1 .* require_signing = true"):
        parse_plan(doc)


def test_require_signing_accepts_loopback_links_and_signed_ones(tmp_path):
    assert check_security(parse_plan(_doc(security={"require_signing": True}))) == []
    doc = _doc(vehicles=_vehicles("udpin:0.0.0.0:1455{i}"),
               security={"require_signing": True, "signing_key_file": _key_file(tmp_path)})
    plan = parse_plan(doc)
    assert plan.require_signing and check_security(plan) == []


def test_signing_that_accepts_every_unsigned_frame_is_not_signing(tmp_path):
    doc = _doc(vehicles=_vehicles("udpin:0.0.0.0:1455{i}"),
               security={"signing_key_file": _key_file(tmp_path), "allow_unsigned": ["*"]})
    findings = check_security(parse_plan(doc))
    assert len(findings) == 4 and "migration mode" in findings[0].text


def test_require_signing_must_be_a_bool():
    with pytest.raises(PlanError, match=r"security.require_signing: expected true or false"):
        parse_plan(_doc(security={"require_signing": "yes"}))


@pytest.mark.parametrize("allow, level, words", [
    (False, "info", "read-only: its frames reach the vehicles only with [forward] allow_commands = true"),
    (True, "warn", "whoever sends from that address commands them")])
def test_forwarding_off_the_machine_is_stated(allow, level, words):
    plan = parse_plan(_doc(forward={"out": ["udp:127.0.0.1:14550", "udp:192.168.1.30:14550"],
                                    "allow_commands": allow}))
    findings = check_security(plan)
    assert [(f.level, f.key) for f in findings] == [(level, "forward.out[1]")]
    assert "telemetry leaves this machine to udp:192.168.1.30:14550" in findings[0].text and words in findings[0].text


# --------------------------------------------------------------------------- the commands
def _swarmseek(*argv, timeout_s: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mission", *argv], env=subprocess_env(), cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout_s)


def _write_plan(tmp_path: Path, doc: dict, name: str = "plan.toml") -> Path:
    lines = []
    path = tmp_path / name
    # the sample plan's text with its [zenoh] section replaced: the rest stays as the operator has it
    text = SAMPLE.read_text().split("[zenoh]")[0]
    for key, value in doc.items():
        lines.append(f"{key} = {json.dumps(value)}")
    path.write_text(text + "[zenoh]\n" + "\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("command", [["dry-run", "--timeout", "1"], ["fly", "--no-tlog"]])
def test_the_commands_refuse_a_plan_listening_on_every_interface_with_one_line(tmp_path, command):
    plan = _write_plan(tmp_path, {"mode": "peer", "listen": ["tcp/0.0.0.0:7447"]})
    log_dir = ["--log-dir", str(tmp_path / "logs")] if command[0] == "fly" else []
    p = _swarmseek(*command, "--plan", str(plan), *log_dir)
    assert p.returncode == 2, p.stdout + p.stderr
    assert p.stdout == "" and len(p.stderr.splitlines()) == 1
    assert p.stderr.startswith(f"swarmseek {command[0]}: refused ({plan}): zenoh.listen: tcp/0.0.0.0:7447 can be "
                               "reached from the network and any peer there could command the fleet")
    assert not (tmp_path / "logs").exists()  # nothing started


def _ctl(endpoint: str, sender: str, *flags: str, command: str = "land", timeout_s: str = "6"):
    p = _swarmseek("ctl", "sitl", command, "--sender", sender, "--zenoh-connect", endpoint,
                   "--timeout-s", timeout_s, *flags)
    return p.returncode, p.stdout, p.stderr


def test_an_allowed_open_network_warns_and_an_attacker_can_command_it(tmp_path, net_host):
    """What the warning says, shown: the plan is flown (dry-run prints the warnings first), and a
    process with no credentials on the network side commands the fleet (its ctl warns too)."""
    port = _free_port(net_host)
    endpoint = f"tcp/{net_host}:{port}"
    zen = {"mode": "peer", "listen": [endpoint], "allow_unauthenticated_network": True}
    path = _write_plan(tmp_path, zen)
    p = _swarmseek("dry-run", "--plan", str(path), "--timeout", "1", "--ready-timeout", "1")
    assert p.returncode == 1, p.stdout + p.stderr  # not ready (no vehicles), not refused
    first = p.stdout.splitlines()[:2]
    assert first[0].startswith(f"security warn   zenoh.allow_unauthenticated_network: true: anyone who reaches "
                               f"{endpoint} can command the fleet"), p.stdout
    assert first[1].startswith("security warn   zenoh.access_control: readings are accepted"), p.stdout
    coordinator = ControlPeer(load_plan(path))
    try:
        rc, out, err = _ctl(endpoint, "attacker")
    finally:
        coordinator.close()
    assert rc == 0 and "land accepted" in out, out + err
    assert f"swarmseek ctl: warning: {endpoint} is not loopback and not TLS" in err
    assert coordinator.commands == [("land", "attacker")]


def test_logins_and_a_commander_rule_keep_an_attacker_out(tmp_path):
    """Authenticated on the network (127.0.0.1 declared a network address): the plan is accepted;
    an attacker without a login, with a wrong one, or a monitor's, cannot command; the commander can."""
    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    zen = {"listen": [endpoint], "auth": {"dictionary_file": _users(tmp_path)},
           "access_control": {"sensor_usernames": ["sensor1"], "monitor_usernames": ["viewer"],
                              "commander_usernames": ["ops"]}}
    with pytest.raises(PlanSecurityError):  # the same endpoint without logins and ACL: refused
        parse_plan(_doc({"listen": [endpoint]}), is_loopback=_everything_is_network)
    plan = parse_plan(_doc(zen), is_loopback=_everything_is_network)
    findings = check_security(plan, is_loopback=_everything_is_network)
    assert [(f.level, f.key) for f in findings if f.key.startswith("zenoh")] == [("info", "zenoh.access_control")]
    coordinator = ControlPeer(plan)
    try:
        attempts = {"no login": [], "wrong password": ("ops", "guess"), "monitor": ("viewer", "v1ew")}
        results = {}
        for what, cred in attempts.items():
            flags = []
            if cred:
                flags = ["--zenoh-user", cred[0], "--zenoh-password-file",
                         write_private(tmp_path / f"{what}.pw".replace(" ", "_"), f"{cred[1]}\n".encode())]
            results[what] = _ctl(endpoint, "attacker", *flags, timeout_s="3")[0]
        ok = _ctl(endpoint, "ops", "--zenoh-user", "ops", "--zenoh-password-file",
                  write_private(tmp_path / "ops.pw", b"0ps\n"), command="pause")
    finally:
        coordinator.close()
    assert results == {"no login": 3, "wrong password": 3, "monitor": 3}  # no coordinator answered them
    assert ok[0] == 0 and "pause accepted" in ok[1], ok
    assert coordinator.commands == [("pause", "ops")]


def test_tls_client_certificates_keep_an_attacker_out(tmp_path, pki):
    """mTLS on the network (127.0.0.1 declared a network address): a plain tcp/ attacker and one
    with a certificate from another CA cannot command; the holder of a certificate of the CA can."""
    port = _free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    plan = parse_plan(_doc({"listen": [endpoint], "tls": _mtls(pki)}), is_loopback=_everything_is_network)
    coordinator = ControlPeer(plan)
    try:
        plain = _ctl(f"tcp/127.0.0.1:{port}", "attacker", timeout_s="3")
        rogue = _ctl(endpoint, "attacker", "--zenoh-mtls", "--zenoh-tls-ca", pki["ca"], "--zenoh-tls-cert",
                     pki["rogue"][0], "--zenoh-tls-key", pki["rogue"][1], timeout_s="3")
        ops = _ctl(endpoint, "ops", "--zenoh-mtls", "--zenoh-tls-ca", pki["ca"], "--zenoh-tls-cert",
                   pki["ops"][0], "--zenoh-tls-key", pki["ops"][1], command="pause")
    finally:
        coordinator.close()
    assert plain[0] == 3 and rogue[0] == 3, (plain, rogue)
    assert ops[0] == 0 and "pause accepted" in ops[1], ops
    assert coordinator.commands == [("pause", "ops")]


# --------------------------------------------------------------------------- the clients' warning
@pytest.mark.parametrize("listen, connect, warned", [
    ((), ("tcp/192.168.1.10:7447",), "tcp/192.168.1.10:7447"),
    (("tcp/0.0.0.0:7447",), ("tls/192.168.1.10:7447",), "tcp/0.0.0.0:7447"),
    ((), ("tls/192.168.1.10:7447",), None), ((), ("tcp/127.0.0.1:7447",), None), (None, None, None)])
def test_the_clients_warning_names_plain_network_endpoints(listen, connect, warned):
    warning = plain_network_warning("swarmseek ctl", listen, connect)
    if warned is None:
        assert warning is None
    else:
        assert warning.startswith(f"swarmseek ctl: warning: {warned} is not loopback and not TLS")


def test_the_sensor_warns_about_a_plain_network_endpoint(net_host):
    port = _free_port(net_host)
    p = subprocess.run([sys.executable, "-m", "mission", "sensor", "--connect", "tcp:127.0.0.1:1",
                        "--field", "sigma1", "--origin", "45.19,5.72,230", "--fleet", "sitl", "--timeout", "1",
                        "--zenoh-connect", f"tcp/{net_host}:{port}"],
                       env=subprocess_env(), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert f"swarmseek sensor: warning: tcp/{net_host}:{port} is not loopback and not TLS" in p.stderr, p.stderr


def test_watch_warns_about_the_plan_and_the_endpoint(net_host):
    """The coordinator's state carries its plan's warnings; watch prints them when it starts."""
    import zenoh

    from mission.core.clock import WallClock
    from mission.flight.coordinator import Coordinator
    from mission.telemetry.state_pub import StatePublisher

    endpoint = f"tcp/{net_host}:{_free_port(net_host)}"
    plan = parse_plan(_doc({"listen": [endpoint], "allow_unauthenticated_network": True}))
    session = zenoh.open(plan.zenoh.to_config())
    co = Coordinator(plan, clock=WallClock(), zenoh_session=session)
    snapshot = co.snapshot()
    assert [w["key"] for w in snapshot["security_warnings"]] == ["zenoh.allow_unauthenticated_network",
                                                                 "zenoh.access_control"]
    watch = subprocess.Popen([sys.executable, "-m", "mission", "watch", "sitl", "--zenoh-connect", endpoint,
                              "--json", "--wait-s", "60"], env=subprocess_env(), cwd=ROOT, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)

    async def publish():
        pub = StatePublisher(session, "sitl", lambda: {**snapshot, "final": watch.poll() is not None},
                             rate_hz=5.0)
        pub.start()
        while watch.poll() is None:
            await asyncio.sleep(0.1)
        await pub.stop()

    try:
        # the watcher ends at the first snapshot with phase done or final: the publication's stop
        snapshot["phase"] = "done"
        asyncio.run(asyncio.wait_for(publish(), 60))
        out, err = watch.communicate(timeout=30)
    finally:
        if watch.poll() is None:
            watch.kill()
        session.close()
    assert watch.returncode == 0, err
    assert f"swarmseek watch: warning: {endpoint} is not loopback and not TLS" in err
    assert ("swarmseek watch: warning: fleet 'sitl': zenoh.allow_unauthenticated_network: true: anyone who "
            f"reaches {endpoint} can command the fleet") in err


# --------------------------------------------------------------------------- the mission log
def test_the_plan_record_carries_the_findings(tmp_path):
    from mission.core.clock import WallClock
    from mission.flight.coordinator import Coordinator
    from mission.telemetry.mission_log import MissionLog, iter_mission_log

    doc = _doc({"listen": ["tcp/0.0.0.0:7447"], "allow_unauthenticated_network": True},
               forward={"out": ["udp:192.168.1.30:14550"]}, preflight={"readings_timeout_s": 0.5},
               vehicles=_vehicles(f"tcp:127.0.0.1:{_free_port()}"))
    doc["heartbeat_timeout_s"] = 0.5
    plan = parse_plan(doc)
    log_path = tmp_path / "mission.jsonl"
    clock = WallClock()
    co = Coordinator(plan, clock=clock, log=MissionLog(log_path, clock))
    asyncio.run(co.dry_run())
    co.log.close()
    record = next(r for r in iter_mission_log(log_path) if r["type"] == "plan")
    assert [(f["level"], f["key"]) for f in record["security_check"]] == [
        ("warn", "zenoh.allow_unauthenticated_network"), ("warn", "zenoh.access_control"),
        ("info", "forward.out[0]")]
    assert refusals(check_security(plan)) == []


# --------------------------------------------------------------------------- docs/security.md
def _snippets() -> list[str]:
    text = (ROOT / "docs" / "security.md").read_text()
    return [block.split("```", 1)[0] for block in text.split("```toml\n")[1:]]


def _files_for(doc: dict, base: Path) -> None:
    """Create every file a snippet names (certificates, keys, secrets) under ``base``."""
    zen = doc.get("zenoh", {})
    paths = list(zen.get("tls", {}).values()) + list(zen.get("auth", {}).values())
    for rel in [p for p in paths if isinstance(p, str)]:
        (base / rel).parent.mkdir(parents=True, exist_ok=True)
        write_private(base / rel, b"sensor1:x\n" if rel.endswith(".txt") else b"-----BEGIN-----\n")
    key = doc.get("security", {}).get("signing_key_file")
    if key:
        (base / key).parent.mkdir(parents=True, exist_ok=True)
        write_private(base / key, bytes(range(1, 33)).hex().encode())


@pytest.mark.parametrize("index, levels", [
    (0, []), (1, ["info"]), (2, ["info"]), (3, ["info", "info"]), (4, ["warn", "warn"]), (5, [])])
def test_the_plans_to_copy_in_docs_security_are_accepted(tmp_path, index, levels):
    snippets = _snippets()
    assert len(snippets) == 6
    block = tomllib.loads(snippets[index])
    doc = _doc(block.get("zenoh"), **{k: v for k, v in block.items() if k not in ("zenoh", "vehicles")})
    if "vehicles" in block:  # the radio plan: every vehicle on the snippet's radio
        doc["vehicles"] = [dict(v, connection=block["vehicles"][0]["connection"]) for v in doc["vehicles"]]
    _files_for(doc, tmp_path)
    plan = parse_plan(doc, base_dir=tmp_path)
    assert [f.level for f in check_security(plan)] == levels


def test_resume_refuses_an_open_plan_read_back_from_a_log(tmp_path):
    """A log written before the check existed (or by hand) does not bypass it."""
    import dataclasses

    from mission.telemetry.mission_log import to_jsonable

    plan = load_plan(SAMPLE)
    plan = dataclasses.replace(plan, zenoh=dataclasses.replace(plan.zenoh, listen=("tcp/0.0.0.0:7447",)))
    log = tmp_path / "mission.jsonl"
    log.write_text(json.dumps({"t_s": 1.0, "type": "plan", "plan": to_jsonable(plan), "resumed": False}) + "\n")
    before = log.read_bytes()
    p = _swarmseek("resume", str(log), "--no-tlog")
    assert p.returncode == 2, p.stdout + p.stderr
    assert p.stderr.startswith("swarmseek resume: refused: zenoh.listen: tcp/0.0.0.0:7447 can be reached from the "
                               "network") and len(p.stderr.splitlines()) == 1, p.stderr
    assert log.read_bytes() == before  # nothing appended: nothing re-engaged
