"""No secret in any log: a whole signed mission, then every file and message it wrote is searched.

The mission flies in lock-step against the embedded mock fleet (n = 4, a few iterations) with
MAVLink signing on (the key from a passphrase key file; the vehicles start without a key and
are provisioned with SETUP_SIGNING, so the key also travels on the link) and zenoh user/password
authentication (the fleet's session accepts the coordinator only with the password). Afterwards
the mission log, the ``--json`` summary, the printed summary and display lines, the ``.tlog``
files and every state publication received over zenoh are searched for the key (raw, hex,
base64, Python ``repr``, decimal list), the passphrase and the zenoh password.
"""
from __future__ import annotations

import base64
import hashlib
import io
import json
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from tests.support.fly_helpers import run_fleet
from tests.support.tls_helpers import write_private

from mission.core.plan_types import replace_plan
from mission.core.signing_config import signing_config_from_table
from mission.core.zenoh_config import ZenohAuthPlan, ZenohPlan
from mission.flight.coordinator import Coordinator
from mission.flight.phases.resume import plan_from_json
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.display import Display, format_summary
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.telemetry.state_pub import state_key
from sitl_mock.fields_config import make_field
from sitl_mock.fleet import MockFleet

PASSPHRASE = "swarmseek test passphrase: correct horse battery staple"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()
ZENOH_PASSWORD = "zen-Pa55-w0rd-7f3a9c"


def secret_forms(key: bytes = KEY, texts=(PASSPHRASE, ZENOH_PASSWORD)) -> dict[str, bytes]:
    """Every form a secret could take in a text or binary file, by name."""
    forms = {"raw key": key, "hex key": key.hex().encode(), "HEX key": key.hex().upper().encode(),
             "base64 key": base64.b64encode(key), "urlsafe base64 key": base64.urlsafe_b64encode(key),
             "base64 key (no padding)": base64.b64encode(key).rstrip(b"="),
             "repr key": repr(key)[2:-1].encode(),
             "JSON repr key": json.dumps(repr(key))[3:-2].encode(),
             "decimal list key": ", ".join(str(b) for b in key).encode(),
             "compact decimal list key": ",".join(str(b) for b in key).encode()}
    for i, text in enumerate(texts):
        forms[f"text secret {i}"] = text.encode()
    return forms


def leaks(blob: bytes, forms: dict[str, bytes] | None = None) -> list[str]:
    """Names of the secret forms found in ``blob``."""
    return [name for name, form in (forms or secret_forms()).items() if form in blob]


def _fly(tmp_path: Path, n: int = 4, max_iterations: int = 6, start_offset_m=(-3.0, 2.0, -1.0)):
    """Fly the signed, password-protected mission; returns what it wrote and published."""
    key_file = write_private(tmp_path / "signing.key", (PASSPHRASE + "\n").encode())
    pw_file = write_private(tmp_path / "gcs.pw", (ZENOH_PASSWORD + "\n").encode())
    users = write_private(tmp_path / "users.txt", f"gcs:{ZENOH_PASSWORD}\n".encode())
    source = np.array([6.0, -4.0, 13.0])
    start = source + np.asarray(start_offset_m, dtype=float)
    field = make_field("sigma2", source)
    ports = fleet_ports(n, "px4")
    plan = embedded_plan(n, ports, start_enu_m=start, eps=default_eps(field), max_iterations=max_iterations,
                         origin=DEFAULT_ORIGIN)
    plan = replace_plan(plan, security=signing_config_from_table({"signing_key_file": key_file}),
                        zenoh=ZenohPlan(mode="peer", connect=plan.zenoh.connect,
                                        auth=ZenohAuthPlan(username="gcs", password_file=pw_file)))
    fleet = MockFleet(n=n, personality="px4", field=field, origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=3, udp_base_port=ports["udp_base_port"],
                      udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0,
                      fleet_name=plan.fleet, sensor_noise_std=0.005,
                      zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"],
                      zenoh_security={"dictionary_file": users}, signing_key=None)
    states: list[bytes] = []
    screen = io.StringIO()
    out = {}

    async def main(world):
        session = zenoh.open(plan.zenoh.to_config())
        sub = session.declare_subscriber(state_key(plan.fleet),
                                         lambda s: states.append(bytes(s.payload.to_bytes())))
        log = MissionLog(tmp_path / "mission.jsonl", fleet.clock)
        try:
            co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log,
                             display=Display(stream=screen, tty=False, min_interval_s=0.0),
                             tlog_dir=tmp_path / "tlogs")
            world.store = co.store
            out["co"] = co
            return await co.run()
        finally:
            log.close()
            time.sleep(0.2)  # the last state publications reach the subscriber
            sub.undeclare()
            session.close()

    try:
        result = run_fleet(fleet, main)
        out["provisioned"] = all(v.autopilot.signing.enabled for v in fleet.vehicles)
    finally:
        fleet.stop()
    return result, out["co"], states, screen.getvalue(), out["provisioned"], plan


@pytest.fixture(scope="module")
def signed_mission(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("signed")
    return tmp_path, *_fly(tmp_path)


def test_the_signed_mission_flew_signed(signed_mission):
    tmp_path, result, co, states, screen, provisioned, plan = signed_mission
    assert result.outcome in ("converged", "max_iterations"), result.message
    assert provisioned
    assert sum(ep.counters["setup_signing_sent"] for ep in co.endpoints.values()) >= 4
    assert states, "no state publication received"


def test_no_secret_in_any_file_written(signed_mission):
    tmp_path, *_ = signed_mission
    files = [p for p in tmp_path.rglob("*") if p.is_file()
             and p.name not in ("signing.key", "gcs.pw", "users.txt")]
    assert any(p.suffix == ".tlog" for p in files) and any(p.name == "mission.jsonl" for p in files)
    found = {str(p.relative_to(tmp_path)): leaks(p.read_bytes()) for p in files}
    assert not {k: v for k, v in found.items() if v}


def test_no_secret_in_summary_display_or_state(signed_mission):
    tmp_path, result, co, states, screen, provisioned, plan = signed_mission
    summary = json.dumps(result.to_json(), indent=2)
    assert not leaks(summary.encode()), "--json summary"
    assert not leaks("\n".join(format_summary(result.to_json())).encode()), "printed summary"
    assert not leaks(screen.encode()), "display"
    assert not [i for i, s in enumerate(states) if leaks(s)], "state publication"
    for text in (repr(plan), str(plan), repr(plan.security), repr(plan.zenoh)):
        assert not leaks(text.encode())


def test_log_says_signing_is_on_with_the_fingerprint(signed_mission):
    tmp_path, result, co, states, screen, provisioned, plan = signed_mission
    rec = next(r for r in read_mission_log(tmp_path / "mission.jsonl") if r["type"] == "plan")
    sec = rec["plan"]["security"]
    assert sec["signing"] is True
    assert sec["fingerprint"] == plan.security.fingerprint
    assert sec["key_file"] == plan.security.key_file
    assert rec["plan"]["zenoh"]["auth"]["password_file"] == plan.zenoh.auth.password_file


def test_a_resumed_plan_reads_the_key_file_again(signed_mission):
    tmp_path, result, co, states, screen, provisioned, plan = signed_mission
    rec = next(r for r in read_mission_log(tmp_path / "mission.jsonl") if r["type"] == "plan")
    back = plan_from_json(rec["plan"])
    assert back.security is not None and back.security.key == plan.security.key
    assert back.security.link_id == plan.security.link_id
    assert back.security.allow_unsigned == plan.security.allow_unsigned


# --------------------------------------------------------------------------- the serialiser
def test_the_serialiser_never_writes_bytes_secret_fields_or_unknown_objects():
    from dataclasses import dataclass

    from pymavlink.dialects.v20 import ardupilotmega as mav

    from mission.core.redaction import REDACTED, secret_field
    from mission.link.signing import setup_signing_message
    from mission.telemetry.mission_log import to_jsonable

    @dataclass
    class Login:
        user: str
        token: str = secret_field(default="")

    setup = setup_signing_message(1, KEY, 1234)
    out = to_jsonable({"key": KEY, "login": Login("gcs", ZENOH_PASSWORD), "msg": setup,
                       "parser": mav.MAVLink(None), "path": Path("/tmp/x"), "err": ValueError("bad")})
    assert out["key"] == "<32 bytes>"
    assert out["login"] == {"user": "gcs", "token": REDACTED}
    assert out["msg"]["mavpackettype"] == "SETUP_SIGNING" and out["msg"]["secret_key"] == REDACTED
    assert out["parser"] == "<MAVLink>"
    assert to_jsonable({"usrpwd": {"user": "gcs", "password": ZENOH_PASSWORD}})["usrpwd"]["password"] == REDACTED
    assert out["path"] == "/tmp/x" and out["err"] == "ValueError: bad"
    assert not leaks(json.dumps(out).encode())
    assert "token" not in repr(Login("gcs", ZENOH_PASSWORD))


def test_resume_refuses_a_key_file_that_now_holds_another_key(tmp_path):
    from mission.core.signing_config import SigningConfig
    from mission.flight.phases.resume import ResumeError, _signing_from_json

    key_file = write_private(tmp_path / "k", (PASSPHRASE + "\n").encode())
    logged = SigningConfig.from_key_file(key_file, link_id=3).to_json()
    assert _signing_from_json(logged).key == KEY
    write_private(tmp_path / "k", b"another passphrase\n")
    with pytest.raises(ResumeError, match="another signing key") as err:
        _signing_from_json(logged)
    assert not leaks(str(err.value).encode())
    with pytest.raises(ResumeError, match="not read from a file"):
        _signing_from_json(SigningConfig(KEY).to_json())
