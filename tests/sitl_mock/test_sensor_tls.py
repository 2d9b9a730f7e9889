"""zenoh TLS (mutual TLS) and user/password login for ``swarmseek sensor`` and ``swarmseek mock``.

A coordinator-side :class:`~mission.telemetry.readings.ReadingStore` behind a TLS (or login-protected)
listener on 127.0.0.1 receives the readings of ``swarmseek sensor`` (run in-process against the
project's mock autopilot) only when the sensor's certificate / password is the right one.
"""
from __future__ import annotations

import os
import threading
import time

import pytest

import zenoh  # noqa: E402  (a project dependency)

from tests.support.tls_helpers import make_pki, write_private  # noqa: E402  (cryptography: the [test] extra)

from mission.cli import main as swarmseek  # noqa: E402
from mission.core.clock import WallClock  # noqa: E402
from mission.telemetry.readings import ReadingStore, ReadingSubscriber  # noqa: E402
from sitl_mock.fleet import MockFleet  # noqa: E402
from wire.zenoh_config import zenoh_config  # noqa: E402
from wire.zenoh_secrets import ZenohSecurityError, read_password_file  # noqa: E402
from mission.sim.embedded import free_port_block  # noqa: E402

ORIGIN = (45.19, 5.72, 230.0)
FLEET = "dry"
DELIVER_TIMEOUT_S = 30.0
REFUSED_WAIT_S = "1"  # --wait-subscriber when no subscriber can ever match


# --------------------------------------------------------------------------- certificates
@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict:
    """Two CAs; leaf certificates ``(pem, key)`` per subject; ``rogue`` is signed by ``other_ca``."""
    return make_pki(tmp_path_factory.mktemp("pki"), (("coordinator", "coordinator", "ca"), ("vehicle1", "vehicle1", "ca"), ("rogue", "rogue", "other_ca")))


# --------------------------------------------------------------------------- helpers
def _free_port() -> int:
    return free_port_block(1, kinds=("tcp",))


def _poll(condition, timeout_s: float, step_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    idle = threading.Event()
    while time.monotonic() < deadline:
        if condition():
            return True
        idle.wait(step_s)
    return condition()


class _Coordinator:
    """A listening session with a reading store on the fleet's sensor keys."""

    def __init__(self, conf):
        self.session = zenoh.open(conf)
        self.store = ReadingStore(FLEET, [1], ORIGIN, WallClock(), max_position_error_m=1e9)
        self.sub = ReadingSubscriber(self.session, self.store)

    def close(self):
        self.sub.close()
        self.session.close()


@pytest.fixture()
def coordinator():
    made = []

    def make(conf):
        made.append(_Coordinator(conf))
        return made[-1]

    yield make
    for c in made:
        c.close()


@pytest.fixture()
def autopilot():
    """The project's mock autopilot, one vehicle serving MAVLink on TCP, no zenoh."""
    fleet = MockFleet(n=1, personality="ardupilot", field=None, origin=ORIGIN,
                      udp_base_port=0, udp_bind_base_port=0, tcp_base_port=_free_port(),
                      fleet_name=FLEET, zenoh=False)
    fleet.start()
    yield f"tcp:127.0.0.1:{fleet.vehicles[0].tcp_port}"
    fleet.stop()
    assert not fleet.errors


def _tls_listener(pki, port: int):
    return zenoh_config(listen=f"tls/127.0.0.1:{port}", enable_mtls=True,
                        tls={"root_ca_certificate": pki["ca"],
                             "listen_certificate": pki["coordinator"][0],
                             "listen_private_key": pki["coordinator"][1]})


def _sensor_argv(connection: str, *extra: str, wait_s: str = "20", quiet: bool = True) -> list[str]:
    return ["sensor", "--connect", connection, "--field", "sigma1", "--origin", ",".join(map(str, ORIGIN)),
            "--fleet", FLEET, "--rate", "10", "--count", "3", "--wait-subscriber", wait_s,
            "--timeout", "30", *(["--quiet"] if quiet else []), *extra]


def _exit_code(argv: list[str]) -> int:
    try:
        return swarmseek(argv)
    except SystemExit as exc:  # argparse errors
        return exc.code


# --------------------------------------------------------------------------- sensor over TLS
@pytest.mark.parametrize("leaf, ca, delivered", [
    ("vehicle1", "ca", True),       # certificate of the coordinator's CA
    ("rogue", "ca", False),         # certificate of another CA: refused by the listener (mTLS)
    ("vehicle1", "other_ca", False),  # the sensor does not trust the coordinator's certificate
])
def test_sensor_delivers_over_mutual_tls_only_with_the_right_ca(pki, coordinator, autopilot, leaf, ca,
                                                                delivered, capsys):
    port = _free_port()
    coord = coordinator(_tls_listener(pki, port))
    cert, key = pki[leaf]
    argv = _sensor_argv(autopilot, "--zenoh-connect", f"tls/127.0.0.1:{port}", "--zenoh-tls-ca", pki[ca],
                        "--zenoh-tls-cert", cert, "--zenoh-tls-key", key, "--zenoh-mtls",
                        wait_s="20" if delivered else REFUSED_WAIT_S, quiet=delivered)
    rc = swarmseek(argv)
    err = capsys.readouterr().err
    if delivered:
        assert rc == 0, err
        assert _poll(lambda: coord.store.accepted >= 3, DELIVER_TIMEOUT_S), coord.store.counts()
        assert [r.seq for r in coord.store.history(1)][:3] == [0, 1, 2]
    else:
        assert rc == 0, err  # zenoh (peer mode) opens anyway and retries: published into nothing
        assert "no zenoh subscriber matched" in err
        assert coord.store.accepted == 0 and not any(coord.store.rejected.values())


# --------------------------------------------------------------------------- sensor with a login
@pytest.mark.parametrize("password, delivered", [("s3cret", True), ("wrong", False)])
def test_sensor_delivers_with_user_password_only_when_right(tmp_path, coordinator, autopilot, password,
                                                            delivered, capsys):
    port = _free_port()
    users = write_private(tmp_path / "users.txt", b"sensor1:s3cret\n")
    coord = coordinator(zenoh_config(listen=f"tcp/127.0.0.1:{port}", dictionary_file=users))
    pw = write_private(tmp_path / "sensor.pw", f"{password}\n".encode())
    rc = swarmseek(_sensor_argv(autopilot, "--zenoh-connect", f"tcp/127.0.0.1:{port}",
                                "--zenoh-user", "sensor1", "--zenoh-password-file", pw,
                                wait_s="20" if delivered else REFUSED_WAIT_S, quiet=delivered))
    err = capsys.readouterr().err
    if delivered:
        assert rc == 0, err
        assert _poll(lambda: coord.store.accepted >= 3, DELIVER_TIMEOUT_S), coord.store.counts()
    else:
        assert rc == 0, err
        assert "no zenoh subscriber matched" in err
        assert coord.store.accepted == 0


# --------------------------------------------------------------------------- mock fleet over TLS
def test_mock_fleet_publishes_over_mutual_tls(pki, coordinator):
    from sitl_mock.fields_config import make_field

    port = _free_port()
    coord = coordinator(_tls_listener(pki, port))
    cert, key = pki["vehicle1"]
    fleet = MockFleet(n=1, field=make_field("sigma1", (0.0, 0.0, 0.0)), origin=ORIGIN,
                      udp_base_port=0, udp_bind_base_port=0, tcp_base_port=0, fleet_name=FLEET,
                      zenoh_connect=[f"tls/127.0.0.1:{port}"],
                      zenoh_security={"tls": {"root_ca_certificate": pki["ca"], "connect_certificate": cert,
                                              "connect_private_key": key}, "enable_mtls": True})
    fleet.start()
    try:
        assert _poll(lambda: coord.store.accepted >= 3, DELIVER_TIMEOUT_S), coord.store.counts()
    finally:
        fleet.stop()
    assert not fleet.errors


def test_mock_command_publishes_over_mutual_tls(pki, coordinator, capsys):
    port = _free_port()
    coord = coordinator(_tls_listener(pki, port))
    cert, key = pki["vehicle1"]
    rc = swarmseek(["mock", "--vehicles", "1", "--udp-base-port", "0", "--tcp-base-port", "0",
                    "--fleet", FLEET, "--origin", ",".join(map(str, ORIGIN)), "--duration", "2",
                    "--zenoh-connect", f"tls/127.0.0.1:{port}", "--zenoh-tls-ca", pki["ca"],
                    "--zenoh-tls-cert", cert, "--zenoh-tls-key", key, "--zenoh-mtls"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "zenoh tls on" in out
    assert _poll(lambda: coord.store.accepted >= 1, DELIVER_TIMEOUT_S), coord.store.counts()


def test_mock_fleet_rejects_unknown_security_keys():
    with pytest.raises(ValueError, match="unknown zenoh_security keys.*'passwd'"):
        MockFleet(n=1, zenoh=False, udp_base_port=0, udp_bind_base_port=0, tcp_base_port=0,
                  zenoh_security={"passwd": "x"})


# --------------------------------------------------------------------------- flag errors
def _bad_flag_cases(pki, tmp_path) -> list:
    cert, key = pki["vehicle1"]
    world = tmp_path / "world.pw"
    world.write_text("pw\n")
    os.chmod(world, 0o644)
    empty = write_private(tmp_path / "empty.pw", b"\n")
    tls = ["--zenoh-connect", "tls/127.0.0.1:7447"]
    return [
        (tls + ["--zenoh-tls-ca", str(tmp_path / "missing.pem")], "file not found"),
        (tls + ["--zenoh-tls-cert", cert], "go together"),
        (tls + ["--zenoh-tls-key", key], "go together"),
        (["--zenoh-connect", "tcp/127.0.0.1:7447", "--zenoh-tls-ca", pki["ca"]], "no tls/ endpoint"),
        (tls + ["--zenoh-mtls", "--zenoh-tls-ca", pki["ca"]], "--zenoh-mtls needs"),
        (["--zenoh-listen", "tls/127.0.0.1:7447", "--zenoh-tls-ca", pki["ca"]], "listen endpoint needs"),
        (tls + ["--zenoh-user", "sensor1"], "go together"),
        (tls + ["--zenoh-password-file", empty], "first line"),
        (tls + ["--zenoh-user", "a", "--zenoh-password-file", str(world)], "world-readable"),
    ]


@pytest.mark.parametrize("command", ["sensor", "mock"])
def test_bad_security_flags_exit_2_with_a_clear_message(pki, tmp_path, command, capsys):
    for flags, message in _bad_flag_cases(pki, tmp_path):
        if command == "sensor":
            argv = _sensor_argv("tcp:127.0.0.1:9", *flags)
        else:
            argv = ["mock", "--vehicles", "1", "--udp-base-port", "0", "--tcp-base-port", "0",
                    "--duration", "1", *flags]
        assert _exit_code(argv) == 2, flags
        err = capsys.readouterr().err
        assert message in err, (flags, err)
        assert "Traceback" not in err


def test_user_name_with_colon_is_refused(tmp_path, capsys):
    pw = write_private(tmp_path / "ok.pw", b"secret\n")
    argv = _sensor_argv("tcp:127.0.0.1:9", "--zenoh-connect", "tcp/127.0.0.1:7447",
                        "--zenoh-user", "a:b", "--zenoh-password-file", pw)
    assert _exit_code(argv) == 2
    assert "without ':'" in capsys.readouterr().err


@pytest.mark.parametrize("content, expected", [(b"pw\n", "pw"), (b"p w:x\nignored\n", "p w:x"), (b"solo", "solo")])
def test_read_password_file_takes_the_first_line(tmp_path, content, expected):
    assert read_password_file(write_private(tmp_path / "p", content)) == expected


def test_read_password_file_refuses_a_world_readable_file(tmp_path):
    path = tmp_path / "p"
    path.write_bytes(b"pw\n")
    os.chmod(path, 0o604)
    with pytest.raises(ZenohSecurityError, match="world-readable; run chmod 600"):
        read_password_file(path)
