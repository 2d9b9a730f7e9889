"""zenoh security from the plan: TLS, user/password authentication and access control.

Validation errors are reported with their dotted keys, all at once; then real zenoh sessions on
127.0.0.1 show that only the intended peers can deliver readings to the coordinator's
:class:`~mission.telemetry.readings.ReadingStore`.
"""
from __future__ import annotations

import json
import os
import socket
import threading
import time
from pathlib import Path

import pytest

from mission.core.clock import WallClock
from mission.core.plan_types import PlanError
from mission.core.plan import parse_plan
from mission.core.zenoh_config import acl_config
from mission.telemetry.readings import ReadingStore, ReadingSubscriber
from mission.telemetry.reading_format import sensor_key
from wire.zenoh_config import zenoh_config
from wire.zenoh_secrets import ZenohSecurityError, read_password_file

import zenoh  # noqa: E402  (a project dependency)

from tests.support.tls_helpers import make_pki, write_private  # noqa: E402  (cryptography: the [test] extra)

DELIVER_TIMEOUT_S = 20.0
REFUSED_WINDOW_S = 2.0


# --------------------------------------------------------------------------- certificates
@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict:
    """Two CAs; leaf certificates (ECDSA P-256) ``<name>.pem`` / ``<name>.key`` per subject."""
    return make_pki(tmp_path_factory.mktemp("pki"), (("coordinator", "coordinator", "ca"), ("vehicle1", "vehicle-1", "ca"),
                     ("intruder", "intruder", "ca"), ("rogue", "vehicle-1", "other_ca")))


# --------------------------------------------------------------------------- helpers
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _keys(exc: PlanError) -> list[str]:
    return [k for k, _ in exc.problems]


def _secrets(tmp_path: Path) -> dict:
    """A password file and a user dictionary, mode 600."""
    return {"password_file": write_private(tmp_path / "coordinator.pw", b"coord-pass\n"),
            "dictionary_file": write_private(
                tmp_path / "users.txt", b"sensor1:s3cret\nmonitor1:m0n\ncoordinator:coord-pass\n")}


def _reading(fleet: str, sysid: int, seq: int) -> bytes:
    return json.dumps({"schema": "swarmseek.sensor.v1", "fleet": fleet, "sysid": sysid, "seq": seq,
                       "time_s": time.time(), "lat_deg": 45.19, "lon_deg": 5.72, "alt_m": 230.0,
                       "value": 0.5}).encode()


def _poll(condition, timeout_s: float, step_s: float = 0.05) -> bool:
    """True as soon as ``condition()`` holds, False after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    idle = threading.Event()
    while time.monotonic() < deadline:
        if condition():
            return True
        idle.wait(step_s)
    return condition()


def _try_deliver(sender_conf, store: ReadingStore, sysid: int, timeout_s: float) -> bool:
    """Open a sender, put readings of ``sysid`` until the store accepted one or time is up."""
    try:
        sender = zenoh.open(sender_conf)
    except zenoh.ZError:
        return False
    try:
        pub = sender.declare_publisher(sensor_key(store.fleet, sysid),
                                       congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + timeout_s
        seq = 0
        while time.monotonic() < deadline:
            seq += 1
            pub.put(_reading(store.fleet, sysid, seq))
            if _poll(lambda: store.latest(sysid) is not None, 0.2):
                return True
        return False
    finally:
        sender.close()


class _Coordinator:
    """A coordinator-side session from a plan, with a reading store on the fleet's keys."""

    def __init__(self, plan):
        self.session = zenoh.open(plan.zenoh.to_config())
        self.store = ReadingStore(plan.fleet, [v.sysid for v in plan.vehicles], plan.origin,
                                  WallClock(), max_position_error_m=1e9)
        self.sub = ReadingSubscriber(self.session, self.store)

    def received(self) -> int:
        return self.store.accepted + sum(self.store.rejected.values())

    def close(self):
        self.sub.close()
        self.session.close()


@pytest.fixture()
def coordinator():
    made = []

    def make(plan):
        made.append(_Coordinator(plan))
        return made[-1]

    yield make
    for c in made:
        c.close()


def _tls_plan(doc, pki, port, **extra):
    doc["zenoh"] = {"mode": "peer", "listen": [f"tls/127.0.0.1:{port}"],
                    "tls": {"root_ca_certificate": pki["ca"],
                            "listen_certificate": pki["coordinator"][0],
                            "listen_private_key": pki["coordinator"][1], "enable_mtls": True},
                    **extra}
    return parse_plan(doc)


def _client_tls(pki, stem, ca="ca") -> dict:
    return {"root_ca_certificate": pki[ca], "connect_certificate": pki[stem][0],
            "connect_private_key": pki[stem][1]}


# --------------------------------------------------------------------------- validation
def test_full_security_plan_reaches_the_zenoh_config(doc, pki, tmp_path):
    secrets = _secrets(tmp_path)
    plan = _tls_plan(doc, pki, 7447, auth={"username": "coordinator", **secrets},
                     access_control={"default": "deny", "sensor_cert_common_names": ["vehicle-1"],
                                     "sensor_usernames": ["sensor1"],
                                     "monitor_usernames": ["monitor1"]})
    conf = plan.zenoh.to_config()
    assert conf.get_json("transport/link/tls/enable_mtls") == "true"
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) == pki["coordinator"][0]
    usrpwd = json.loads(conf.get_json("transport/auth/usrpwd"))
    assert (usrpwd["user"], usrpwd["password"]) == ("coordinator", "coord-pass")
    assert "coord-pass" not in repr(plan)
    acl = json.loads(conf.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert {r["key_exprs"][0] for r in acl["rules"]} == {
        f"swarmseek/{plan.fleet}/vehicle/*/sensor", f"swarmseek/{plan.fleet}/mission/**"}
    assert conf.get_json("scouting/multicast/enabled") == "false"


def _world_readable(tmp_path: Path) -> str:
    p = tmp_path / "open.pw"
    p.write_text("pw\n")
    os.chmod(p, 0o644)
    return str(p)


@pytest.mark.parametrize("section, value, key, why", [
    ("tls", {"enable_mtls": "yes"}, "zenoh.tls.enable_mtls", "true or false"),
    ("tls", {"enable_mtls": True}, "zenoh.tls.root_ca_certificate", "enable_mtls"),
    ("tls", {"listen_certificate": "CERT"}, "zenoh.tls.listen_private_key", "required with"),
    ("tls", {"connect_private_key": "OPEN"}, "zenoh.tls.connect_private_key", "world-readable"),
    ("tls", {"verify": True}, "zenoh.tls.verify", "unknown key"),
    ("auth", {"username": "u", "password": "x"}, "zenoh.auth.password", "never put a password"),
    ("auth", {"username": "u"}, "zenoh.auth.password_file", "go together"),
    ("auth", {"username": "u", "password_file": "OPEN"}, "zenoh.auth.password_file", "world-readable"),
    ("auth", {"username": "a:b", "password_file": "PW"}, "zenoh.auth.username", "must not contain"),
    ("auth", {"dictionary_file": "BADDICT"}, "zenoh.auth.dictionary_file", "user:password"),
    ("auth", {"dictionary_file": "missing.txt"}, "zenoh.auth.dictionary_file", "not found"),
    ("access_control", {"default": "allow", "sensor_usernames": ["s"]},
     "zenoh.access_control.default", "only \"deny\""),
    ("access_control", {"default": "deny"}, "zenoh.access_control", "sensor_cert_common_names"),
    ("access_control", {"sensor_cert_common_names": ["v"]},
     "zenoh.access_control.sensor_cert_common_names", "enable_mtls"),
    ("access_control", {"sensor_usernames": ["s"]}, "zenoh.access_control.sensor_usernames",
     "dictionary_file"),
    ("access_control", {"sensor_usernames": "s"}, "zenoh.access_control.sensor_usernames",
     "list of non-empty strings"),
    ("access_control_connect", {"sensor_usernames": ["s"]}, "zenoh.access_control.sensor_usernames",
     "only peers that connect"),
])
def test_invalid_security_keys_are_reported_with_their_path(doc, pki, tmp_path, section, value, key, why):
    names = {"OPEN": _world_readable(tmp_path), "PW": _secrets(tmp_path)["password_file"],
             "CERT": pki["coordinator"][0],
             "BADDICT": write_private(tmp_path / "bad.txt", b"no-colon-here\n")}
    value = {k: names.get(v, v) if isinstance(v, str) else v for k, v in value.items()}
    if section == "access_control_connect":
        doc["zenoh"] = {"connect": ["tcp/127.0.0.1:7447"], "auth": {"dictionary_file": _secrets(tmp_path)["dictionary_file"]}}
        section = "access_control"
    doc["zenoh"][section] = value
    with pytest.raises(PlanError, match=why) as info:
        parse_plan(doc, base_dir=tmp_path)
    assert key in _keys(info.value)


def test_every_zenoh_problem_is_reported_at_once(doc, tmp_path):
    doc["zenoh"]["listen"] = ["tls/127.0.0.1:7447"]
    doc["zenoh"]["tls"] = {"enable_mtls": 1}
    doc["zenoh"]["auth"] = {"password": "x"}
    doc["zenoh"]["access_control"] = {"default": "allow"}
    with pytest.raises(PlanError) as info:
        parse_plan(doc, base_dir=tmp_path)
    keys = set(_keys(info.value))
    assert {"zenoh.tls.enable_mtls", "zenoh.tls.listen_certificate", "zenoh.tls.listen_private_key",
            "zenoh.auth.password", "zenoh.access_control.default", "zenoh.access_control"} <= keys


@pytest.mark.parametrize("content, mode, match", [
    (b"", 0o600, "empty"), (b"pw\n", 0o604, "world-readable"), (b"\xff\n", 0o600, "cannot read")])
def test_password_file_must_be_private_and_non_empty(tmp_path, content, mode, match):
    p = tmp_path / "pw"
    p.write_bytes(content)
    os.chmod(p, mode)
    with pytest.raises(ZenohSecurityError, match=match):
        read_password_file(p)


def test_zenoh_config_helper_rejects_half_credentials_and_missing_files(tmp_path):
    with pytest.raises(ValueError, match="both username and password"):
        zenoh_config(listen="tcp/127.0.0.1:7447", username="u")
    with pytest.raises(ValueError, match="file not found"):
        zenoh_config(listen="tls/127.0.0.1:7447", tls={"root_ca_certificate": str(tmp_path / "x")})
    with pytest.raises(ValueError, match="unknown zenoh TLS key"):
        zenoh_config(listen="tls/127.0.0.1:7447", tls={"ca": str(tmp_path)})


# --------------------------------------------------------------------------- real sessions
@pytest.mark.parametrize("client, sysid, delivered", [
    ("right_ca", 1, True), ("other_ca", 2, False), ("plain_tcp", 3, False)])
def test_tls_listener_accepts_readings_only_over_tls_with_the_right_ca(doc, pki, coordinator, client,
                                                                       sysid, delivered):
    port = _free_port()
    coord = coordinator(_tls_plan(doc, pki, port))
    if client == "plain_tcp":
        conf = zenoh_config(connect=f"tcp/127.0.0.1:{port}")
    else:
        stem = "vehicle1" if client == "right_ca" else "rogue"
        ca = "ca" if client == "right_ca" else "other_ca"
        conf = zenoh_config(connect=f"tls/127.0.0.1:{port}", tls=_client_tls(pki, stem, ca),
                            enable_mtls=True)
    ok = _try_deliver(conf, coord.store, sysid, DELIVER_TIMEOUT_S if delivered else REFUSED_WINDOW_S)
    assert ok is delivered
    assert coord.received() == (coord.store.accepted if delivered else 0)


@pytest.mark.parametrize("coordinator_listens", [True, False])
@pytest.mark.parametrize("stem, delivered", [("vehicle1", True), ("intruder", False)])
def test_access_control_by_certificate_common_name(doc, pki, coordinator, stem, delivered,
                                                   coordinator_listens):
    port = _free_port()
    acl = {"default": "deny", "sensor_cert_common_names": ["vehicle-1"]}
    if coordinator_listens:
        coord = coordinator(_tls_plan(doc, pki, port, access_control=acl))
        conf = zenoh_config(connect=f"tls/127.0.0.1:{port}", tls=_client_tls(pki, stem),
                            enable_mtls=True)
    else:  # the sensor listens with its certificate, the coordinator connects
        doc["zenoh"] = {"mode": "peer", "connect": [f"tls/127.0.0.1:{port}"], "access_control": acl,
                        "tls": {**_client_tls(pki, "coordinator"), "enable_mtls": True}}
        coord = coordinator(parse_plan(doc))
        conf = zenoh_config(listen=f"tls/127.0.0.1:{port}", enable_mtls=True, tls={
            "root_ca_certificate": pki["ca"], "listen_certificate": pki[stem][0],
            "listen_private_key": pki[stem][1]})
    ok = _try_deliver(conf, coord.store, 1, DELIVER_TIMEOUT_S if delivered else REFUSED_WINDOW_S)
    assert ok is delivered
    if not delivered:
        assert coord.received() == 0  # dropped by zenoh: the coordinator never sees it


def _usrpwd_plan(doc, tmp_path, port):
    doc["zenoh"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"],
                    "auth": {"dictionary_file": _secrets(tmp_path)["dictionary_file"]},
                    "access_control": {"sensor_usernames": ["sensor1"],
                                       "monitor_usernames": ["monitor1"]}}
    return parse_plan(doc)


@pytest.mark.parametrize("user, password, delivered", [
    ("sensor1", "s3cret", True), ("sensor1", "wrong", False), ("monitor1", "m0n", False),
    (None, None, False)])
def test_access_control_by_user_name(doc, tmp_path, coordinator, user, password, delivered):
    port = _free_port()
    coord = coordinator(_usrpwd_plan(doc, tmp_path, port))
    conf = zenoh_config(connect=f"tcp/127.0.0.1:{port}", username=user, password=password)
    ok = _try_deliver(conf, coord.store, 2, DELIVER_TIMEOUT_S if delivered else REFUSED_WINDOW_S)
    assert ok is delivered
    if not delivered:
        assert coord.received() == 0


@pytest.mark.parametrize("user, password, delivered", [("monitor1", "m0n", True),
                                                       ("sensor1", "s3cret", False)])
def test_state_reaches_only_monitors(doc, tmp_path, coordinator, user, password, delivered):
    port = _free_port()
    plan = _usrpwd_plan(doc, tmp_path, port)
    coord = coordinator(plan)
    got = threading.Event()
    watcher = zenoh.open(zenoh_config(connect=f"tcp/127.0.0.1:{port}", username=user, password=password))
    try:
        watcher.declare_subscriber(f"swarmseek/{plan.fleet}/mission/state", lambda sample: got.set())
        pub = coord.session.declare_publisher(f"swarmseek/{plan.fleet}/mission/state",
                                              congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + (DELIVER_TIMEOUT_S if delivered else REFUSED_WINDOW_S)
        while time.monotonic() < deadline and not got.is_set():
            pub.put(b'{"phase": "seeking"}')
            got.wait(0.2)
        assert got.is_set() is delivered
    finally:
        watcher.close()


def test_acl_config_lists_only_the_given_subjects():
    from mission.core.zenoh_config import ZenohAclPlan

    conf = acl_config(ZenohAclPlan("swarmseek/f/vehicle/*/sensor", "swarmseek/f/mission/**",
                                   sensor_cert_common_names=("v1", "v2")))
    assert conf["subjects"] == [{"id": "sensor-cert_common_names", "cert_common_names": ["v1", "v2"]}]
    assert [p["subjects"] for p in conf["policies"]] == [["sensor-cert_common_names"]]
    assert all(r["permission"] == "allow" for r in conf["rules"])


def test_security_plan_survives_the_mission_log_round_trip(doc, pki, tmp_path):
    from dataclasses import asdict

    from mission.telemetry.mission_log import to_jsonable
    from mission.flight.phases.resume import plan_from_json

    plan = _tls_plan(doc, pki, 7447, auth={"username": "coordinator", **_secrets(tmp_path)},
                     access_control={"sensor_cert_common_names": ["vehicle-1"]})
    record = json.loads(json.dumps(to_jsonable(asdict(plan))))
    assert "coord-pass" not in json.dumps(record)
    back = plan_from_json(record)
    assert back.zenoh.auth == plan.zenoh.auth
    assert back.zenoh.access_control == plan.zenoh.access_control
    assert back.zenoh.to_config().get_json("access_control") == plan.zenoh.to_config().get_json(
        "access_control")
