"""Forward addresses (``--out``, ``[forward] out``) are checked and their host names resolved ONCE,
before any event loop starts: an invalid address or a name that does not resolve is exit status 2
with one line, before anything is contacted or armed (``run``, ``fly``, ``resume``, ``dry-run``);
the :class:`~mission.link.forward.Forwarder` itself only ever sends to numeric addresses (a
``sendto`` to a host name resolves it on every frame, inside the event loop: with a name that
did not resolve, ``run`` once flew 3 s of mission in 25 s of wall time).

Name resolution is made hermetic: ``socket.getaddrinfo`` fails, as a resolver does, for the
reserved ``.invalid`` domain (RFC 6761) and counts its calls; every other name goes to the real
resolver (``localhost`` only)."""
from __future__ import annotations

import asyncio
import json
import socket
import tomllib
from pathlib import Path

import pytest

from mission.cli import main as cli_main
from mission.core.plan_types import PlanError
from mission.core.plan import load_plan, parse_plan
from mission.core.plan_sections import parse_forward_out
from mission.link.forward import ForwardAddressError, Forwarder, forwarding, plan_with_outs, resolve_out, resolve_outs

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "mission" / "examples" / "sitl_plan.toml"
NOWHERE = "udp:qgc.swarmseek.invalid:14550"


@pytest.fixture
def lookups(monkeypatch):
    """Names looked up through ``socket.getaddrinfo``; ``*.invalid`` does not resolve."""
    real, seen = socket.getaddrinfo, []

    def getaddrinfo(host, *args, **kwargs):
        seen.append(host)
        if str(host).endswith(".invalid"):
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)
    return seen


@pytest.mark.parametrize("text, why", [
    ("udp:256.1.1.1:14550", "is not an IPv4 address"),
    ("udp:10.0.0:14550", "is not an IPv4 address"),
    ("udp::14550", "must look like udp:HOST:PORT"),
    ("udp:10.0.0.1:0", "port must be 1..65535"),
    ("udp:10.0.0.1:65536", "port must be 1..65535"),
    ("udp:qgc laptop:14550", "is not an IPv4 address or a host name"),
    ("udp:-qgc:14550", "is not an IPv4 address or a host name"),
    ("tcp:10.0.0.1:14550", "must look like udp:HOST:PORT"),
])
def test_invalid_forward_addresses_are_refused_with_the_reason(text, why):
    with pytest.raises(ValueError, match=why):
        parse_forward_out(text)
    doc = tomllib.loads(SAMPLE.read_text())
    doc["forward"] = {"out": [text]}
    with pytest.raises(PlanError, match=why):
        parse_plan(doc)


def test_valid_addresses_and_host_names_parse():
    assert parse_forward_out("udp:192.168.1.10:14550") == ("192.168.1.10", 14550)
    assert parse_forward_out("udpout:qgc-laptop.local:65535") == ("qgc-laptop.local", 65535)


def test_names_resolve_once_to_numeric_addresses(lookups):
    assert resolve_outs(["udp:localhost:14550", "udp:10.1.2.3:14551"]) == {
        "udp:localhost:14550": ("127.0.0.1", 14550), "udp:10.1.2.3:14551": ("10.1.2.3", 14551)}
    assert lookups == ["localhost", "10.1.2.3"]
    with pytest.raises(ForwardAddressError, match=r"'udp:qgc\.swarmseek\.invalid:14550': the host name does not "
                                                  r"resolve"):
        resolve_outs([NOWHERE])


def test_the_forwarder_never_looks_a_name_up(lookups):
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    client.settimeout(5.0)
    out = f"udp:localhost:{client.getsockname()[1]}"
    with pytest.raises(ForwardAddressError, match="a host name: resolve it first"):
        Forwarder([out])                                   # no resolution hidden in the constructor
    addresses = resolve_outs([out])
    del lookups[:]
    fwd = Forwarder([out], addresses=addresses)
    try:
        assert fwd.addresses == [("127.0.0.1", client.getsockname()[1])]
        for k in range(20):
            fwd.copy(bytes([0xFD, k]))
        assert [client.recvfrom(64)[0] for _ in range(20)] == [bytes([0xFD, k]) for k in range(20)]
        assert fwd.counters["frames_out"] == 20 and lookups == [] and out in fwd.summary()
    finally:
        asyncio.run(fwd.close())
        client.close()


def test_forwarding_resolves_before_the_work_starts(lookups):
    """A caller that did not resolve (a library user): ``forwarding`` resolves in a worker thread,
    before the mission's coroutine starts; a failure leaves it never started."""

    plan = plan_with_outs(load_plan(SAMPLE), [NOWHERE])
    events, watched = [], []
    started = []

    async def work():
        started.append(True)

    coro = work()
    with pytest.raises(ForwardAddressError, match="does not resolve"):
        asyncio.run(forwarding(coro, plan.forward, [v.sysid for v in plan.vehicles],
                               lambda text, **_kw: events.append(text), watched.append))
    assert started == [] and coro.cr_frame is None        # closed, never run (no "never awaited" warning)
    assert events == [] and watched == []                 # nothing started, nothing attached


def _plan_file(tmp_path, out: str) -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(SAMPLE.read_text() + f'\n[forward]\nout = ["{out}"]\n')
    return path


def _one_line_error(err: str, *words) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(w in lines[0] for w in words), err


def test_run_refuses_an_unresolvable_out_before_starting(tmp_path, capsys, lookups):
    log_dir = tmp_path / "run"
    assert cli_main(["run", "--out", NOWHERE, "--log-dir", str(log_dir)]) == 2
    _one_line_error(capsys.readouterr().err, "swarmseek run: error:", "does not resolve")
    assert not log_dir.exists()                            # nothing started, no log


@pytest.mark.parametrize("where", ["--out", "[forward]"])
def test_fly_refuses_an_unresolvable_out_before_connecting(tmp_path, capsys, lookups, where):
    log_dir = tmp_path / "fly"
    plan = _plan_file(tmp_path, NOWHERE) if where == "[forward]" else SAMPLE
    argv = ["fly", "--plan", str(plan), "--log-dir", str(log_dir)] + (["--out", NOWHERE] if where == "--out" else [])
    assert cli_main(argv) == 2
    _one_line_error(capsys.readouterr().err, "swarmseek fly: error:", "does not resolve", "nothing armed")
    assert not log_dir.exists()


def test_fly_refuses_an_invalid_ipv4_address(tmp_path, capsys):
    assert cli_main(["fly", "--plan", str(_plan_file(tmp_path, "udp:256.1.1.1:14550")),
                     "--log-dir", str(tmp_path / "fly")]) == 2
    assert "is not an IPv4 address" in capsys.readouterr().err and not (tmp_path / "fly").exists()


def test_dry_run_reports_an_unresolvable_forward_host(tmp_path, capsys, lookups):
    assert cli_main(["dry-run", "--plan", str(_plan_file(tmp_path, NOWHERE))]) == 2
    _one_line_error(capsys.readouterr().err, "swarmseek dry-run: error:", "does not resolve")


def test_resume_refuses_an_unresolvable_forward_host_of_the_log(tmp_path, capsys, lookups):
    from mission.telemetry.mission_log import to_jsonable

    plan = plan_with_outs(load_plan(SAMPLE), [NOWHERE])
    log = tmp_path / "mission.jsonl"
    log.write_text(json.dumps({"t_s": 1.0, "type": "plan", "plan": to_jsonable(plan), "resumed": False}) + "\n")
    before = log.read_bytes()
    assert cli_main(["resume", str(log)]) == 2
    _one_line_error(capsys.readouterr().err, "swarmseek resume: error:", "does not resolve", "nothing re-engaged")
    assert log.read_bytes() == before                      # nothing appended: nothing started
