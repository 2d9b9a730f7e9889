"""Shared by tests/mission/flight/test_gcs_faults_output.py and tests/mission/flight/test_gcs_faults_signals.py (split in two files
so that the two pytest-xdist workers each take a part). The ground station's own faults never
abandon a vehicle: a ``swarmseek fly`` process
whose stdout or stderr is a closed pipe, that gets SIGHUP or a SIGPIPE sent by another process
mid-seek, whose mission log hits a file size limit, or whose zenoh router dies mid-mission.

The mock fleet runs in this process (on its thread, wall clock: ``fly`` flies on the wall clock),
so that every vehicle's final state is read from the fleet itself; ``fly`` runs in its own
process. After each fault every vehicle must end disarmed on the ground (the test waits for it),
the exit status must be the one docs/faults.md gives, and the mission log (or, when the log is
what failed, standard error) must say what happened.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from mission.core.plan_sections import LINK_TIMEOUT_MAX_S
from mission.sim.embedded import DEFAULT_ORIGIN, fleet_ports, free_port_block
from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import summary_exit_status
from tests.support.invariants import abandoned
from tests.support.fly_process import gradient_seek_plan, subprocess_env
from tests.support.wait_helpers import wait_until

ROOT = Path(__file__).resolve().parents[2]
SOURCE = np.array([6.0, 4.0, 6.0])
N = 4
#: the mission log's size limit of the size-limited case: above what connect, preflight, takeoff
#: and assembly write, below what the seek has written when it ends (measured with 12 iterations:
#: the seek from about 32 kB to about 70 kB, a whole mission about 100 kB; 8 iterations here)
FSIZE_LIMIT_B = 48 * 1024
#: the mock fleet's airframe for the wall-clock ``fly`` missions: a position loop twice as stiff,
#: take-off at 3 m/s, LAND at 2 m/s (PX4's MPC_LAND_SPEED, default 0.7) and down at 3 m/s. The
#: ground station's handling of its own faults is the same; assembly and landing, most of the
#: wall-clock minute these missions took, about halve
NIMBLE = DynamicsParams(kp_pos_per_s=2.0, land_speed_m_s=2.0, takeoff_speed_m_s=3.0, max_speed_down_m_s=3.0)


def _plan_toml(path: Path, udp_base: int, zenoh_section: str, max_iterations: int = 8) -> Path:
    """The plan of the ``fly`` process: :data:`N` vehicles of the in-process mock fleet, flying low
    (take-off and landing are most of the test's time); a vehicle's loss is detected after the
    longest link timeout the plan allows (a starved host once cost all four in one CI-like run)."""
    return gradient_seek_plan(path, fleet="gcsfaults", n=N, udp_base=udp_base, origin=DEFAULT_ORIGIN,
                              zenoh_section=zenoh_section, takeoff_alt_m=3.0, stagger_s=0.3, radius_m=3.0,
                              start_alt_m=6.0, fence_half_m=100.0, min_alt_m=2.0, max_alt_m=40.0,
                              max_iterations=max_iterations, link_timeout_s=LINK_TIMEOUT_MAX_S)


def records(log: Path) -> list[dict]:
    """The complete records of a mission log being written (a partial last line is left out)."""
    if not log.exists():
        return []
    out = []
    for line in log.read_text(errors="replace").splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            break
    return out


def _seeking(log: Path):
    return lambda: any(r["type"] == "iteration" for r in records(log))


class _Drain(threading.Thread):
    """Reads a pipe to its end (what the process wrote there)."""

    def __init__(self, fd: int):
        super().__init__(daemon=True)
        self.fd, self.data = fd, bytearray()
        self.start()

    def run(self) -> None:
        with os.fdopen(self.fd, "rb") as fh:
            for chunk in iter(lambda: fh.read1(65536), b""):
                self.data += chunk

    def text(self) -> str:
        self.join(timeout=30)
        return self.data.decode(errors="replace")


def _as_from_a_terminal(preexec_fn=None):
    """A ``preexec_fn`` that gives the child SIGHUP's default disposition (then runs ``preexec_fn``).

    The child is an operator's ``fly`` started from a terminal. A test session started under
    ``nohup`` (or by a runner that ignores SIGHUP) would hand its ignored SIGHUP down, and a
    ground station keeps an inherited ignored SIGHUP ignored on purpose (docs/faults.md): the
    SIGHUP case would then test ``nohup`` instead of a closed terminal."""
    def preexec() -> None:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        if preexec_fn is not None:
            preexec_fn()
    return preexec


def _output_fds(runner, stdout, stderr) -> dict:
    """The child's ``stdout``/``stderr`` file descriptors: the one given, or the write end of a pipe
    that ``runner.out`` / ``runner.err`` (a :class:`_Drain`) reads."""
    fds = {}
    for name, given in (("stdout", stdout), ("stderr", stderr)):
        if given is None:
            r, w = os.pipe()
            setattr(runner, name[3:], _Drain(r))
            given = w
        fds[name] = given
    return fds


def _dead_pipe() -> int:
    """The write end of a pipe whose read end is closed (any write: EPIPE)."""
    r, w = os.pipe()
    os.close(r)
    return w


def _router(endpoint: str) -> subprocess.Popen:
    """A zenoh router in its own process (killed to make the router vanish)."""
    code = ("import json, sys, zenoh\n"
            "c = zenoh.Config()\n"
            "c.insert_json5('mode', '\"router\"')\n"
            "c.insert_json5('scouting/multicast/enabled', 'false')\n"
            f"c.insert_json5('listen/endpoints', json.dumps([{endpoint!r}]))\n"
            "s = zenoh.open(c)\n"
            "print('ready', flush=True)\n"
            "sys.stdin.read()\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=subprocess_env())
    assert proc.stdout.readline().strip() == "ready"
    return proc


def _file_size_limit(limit_b: int):
    """preexec_fn of the size-limited case: files of at most ``limit_b`` bytes."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_b, limit_b))
    return limit


class _Fly:
    """The mock fleet (here) and ``swarmseek fly`` (its own process) for one fault."""

    def __init__(self, tmp_path: Path, routed: bool):
        ports = fleet_ports(N, "px4")
        zport = free_port_block(1, kinds=("tcp",))
        endpoint = f"tcp/127.0.0.1:{zport}"
        self.router = _router(endpoint) if routed else None
        section = (f'mode = "client"\nconnect = ["{endpoint}"]' if routed
                   else f'mode = "peer"\nlisten = ["{endpoint}"]')
        # without readings an iteration waits 6 s for them: a shorter seek when the router dies (killed
        # once iteration 1 is logged: iterations 2 and 3 go blind)
        self.plan = _plan_toml(tmp_path / "plan.toml", ports["udp_base_port"], section, 3 if routed else 8)
        self.log = tmp_path / "log" / "mission.jsonl"
        self.fleet = MockFleet(n=N, personality="px4", field=sigma2(SOURCE), origin=DEFAULT_ORIGIN, seed=2,
                               udp_base_port=ports["udp_base_port"],
                               udp_bind_base_port=ports["udp_bind_base_port"], tcp_base_port=0,
                               fleet_name="gcsfaults", zenoh_connect=[endpoint], dynamics=NIMBLE)
        self.proc = None
        self.out = self.err = None

    def start(self, stdout=None, stderr=None, preexec_fn=None, as_json: bool = True) -> None:
        """Start the fleet and ``fly``; ``stdout``/``stderr``: a file descriptor (default: a pipe read
        here); ``as_json``: ``--json`` (nothing on stdout before the end), else the live display."""
        self.fleet.start()
        fds = _output_fds(self, stdout, stderr)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mission", "fly", "--plan", str(self.plan), "--log-dir", str(self.log.parent),
             "--no-tlog", *(["--json"] if as_json else [])], stdout=fds["stdout"], stderr=fds["stderr"], env=subprocess_env(), cwd=ROOT,
            preexec_fn=_as_from_a_terminal(preexec_fn))
        for fd in fds.values():
            os.close(fd)

    def wait_for(self, predicate, what: str, timeout_s: float = 150.0) -> None:
        wait_until(lambda: predicate() or self.proc.poll() is not None, timeout_s, what, poll_s=0.05)
        assert self.proc.poll() is None, f"fly exited ({self.proc.returncode}) before {what}"

    def finish(self) -> int:
        """Wait for ``fly`` to exit, then for every vehicle to be disarmed; returns the exit status."""
        status = self.proc.wait(timeout=200)
        at_exit = abandoned(self.fleet, self.log if self.log.exists() else None)
        assert not at_exit, f"at fly's exit: {at_exit}"  # down, or under LAND/RTL
        wait_until(lambda: not any(v.autopilot.armed for v in self.fleet.vehicles), 90.0,
                   "every vehicle disarmed on the ground", poll_s=0.1)
        assert all(v.autopilot.mc.on_ground for v in self.fleet.vehicles)
        return status

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=30)
        self.fleet.stop()
        if self.router is not None and self.router.poll() is None:
            self.router.kill()
            self.router.wait(timeout=30)


class _Run:
    """``swarmseek run --n 4`` (lock-step, its own embedded mock fleet) in its own process, for the
    faults whose handling ``run`` shares with ``fly`` (the same terminal, stop handlers and mission
    log): seconds instead of a minute of wall-clock flight. The fleet lives in that process, so the
    vehicles' end is read from the mission log: the summary names none left airborne or still
    armed, and every vehicle's status became ``landed`` (the ground station saw it down)."""

    #: the mission log's size limit of the size-limited case: ``run --n 4 --seed 1 --no-tlog`` writes
    #: about 42 kB before its first iteration and 176 kB by the end of its seek (220 kB in all)
    FSIZE_LIMIT_B = 96 * 1024

    def __init__(self, tmp_path: Path, routed: bool = False):
        assert not routed, "run has no external zenoh router"
        self.log = tmp_path / "log" / "mission.jsonl"
        self.proc = None
        self.out = self.err = None

    def start(self, stdout=None, stderr=None, preexec_fn=None, as_json: bool = True) -> None:
        """Start ``run``; ``stdout``/``stderr``: a file descriptor (default: a pipe read here)."""
        fds = _output_fds(self, stdout, stderr)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mission", "run", "--n", str(N), "--seed", "1", "--no-tlog",
             "--log-dir", str(self.log.parent), *(["--json"] if as_json else [])],
            stdout=fds["stdout"], stderr=fds["stderr"], env=subprocess_env(), cwd=ROOT,
            preexec_fn=_as_from_a_terminal(preexec_fn))
        for fd in fds.values():
            os.close(fd)

    wait_for = _Fly.wait_for

    def finish(self) -> int:
        """Wait for ``run`` to exit; every vehicle down, per its summary (the ``--json`` one on stdout
        when the log could not take it) and, when the log is whole, per its statuses."""
        status = self.proc.wait(timeout=200)
        recs = records(self.log)
        logged = [r for r in recs if r["type"] == "summary"]
        summary = logged[-1] if logged else json.loads(self.out.text())
        assert summary["airborne_left"] == [] and summary.get("still_armed", []) == [], summary
        if logged:
            last = {}
            for r in recs:
                if r["type"] == "status_change":
                    last[r["sysid"]] = r["status"]
            assert last == {s: "landed" for s in range(1, N + 1)}, last
        return status

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=30)


def _summary(log: Path) -> dict:
    summaries = [r for r in records(log) if r["type"] == "summary"]
    assert len(summaries) == 1, "one summary record"
    return summaries[0]


def _events(log: Path) -> list[str]:
    return [r.get("message", "") for r in records(log) if r["type"] == "event"]


def _closed_stdout(m: _Fly) -> None:
    m.start(stdout=_dead_pipe(), as_json=False)  # the live display writes from the start
    status = m.finish()
    summary = _summary(m.log)
    assert status == summary_exit_status(summary), (status, summary["outcome"], m.err.text())
    assert summary["outcome"] in ("converged", "max_iterations") and summary["airborne_left"] == [], \
        (summary["outcome"], summary.get("message"), summary["airborne_left"], _events(m.log)[-12:])
    lost = [r for r in records(m.log) if r.get("terminal_lost") == "stdout"]
    assert len(lost) == 1 and "BrokenPipeError" in lost[0]["message"]
    assert "Traceback" not in m.err.text() and "Exception ignored" not in m.err.text()


def _closed_stderr_then_sigterm(m: _Fly) -> None:
    m.start(stderr=_dead_pipe())
    m.wait_for(_seeking(m.log), "the seek")
    m.proc.send_signal(signal.SIGTERM)  # its message goes to the dead stderr
    assert m.finish() == 143
    summary = _summary(m.log)
    assert summary["outcome"] == "interrupted" and summary["interrupted_by"] == ["SIGTERM"]
    lost = [r for r in records(m.log) if r.get("terminal_lost") == "stderr"]
    assert len(lost) == 1 and "BrokenPipeError" in lost[0]["message"]
    assert json.loads(m.out.text())["outcome"] == "interrupted"  # stdout still works


def _signal_mid_seek(sig: signal.Signals, status: int):
    def case(m: _Fly) -> None:
        m.start()
        m.wait_for(_seeking(m.log), "the seek")
        m.proc.send_signal(sig)
        got = m.finish()
        assert got == status, (f"exit {got}, not {status}; stderr: {m.err.text()[-1500:]}; stdout: "
                               f"{m.out.text()[-1000:]}; last events: {_events(m.log)[-8:]}")
        summary = _summary(m.log)
        assert summary["outcome"] == "interrupted" and summary["interrupted_by"] == [sig.name]
        assert summary["airborne_left"] == []
        assert any(f"interrupted ({sig.name})" in e for e in _events(m.log))
        assert f"swarmseek: {sig.name}: stopping the mission" in m.err.text()
        landed = {r["sysid"] for r in records(m.log) if r["type"] == "status_change" and r["status"] == "landed"}
        assert landed == set(range(1, N + 1))
    return case


def _log_size_limit(m: _Fly) -> None:
    limit_b = getattr(m, "FSIZE_LIMIT_B", FSIZE_LIMIT_B)
    m.start(preexec_fn=_file_size_limit(limit_b))
    status = m.finish()
    err = m.err.text()
    assert status == 74, err[-2000:]
    assert "cannot write the mission log" in err and "File too large" in err, err[-2000:]
    assert "bringing every vehicle home" in err
    assert m.log.stat().st_size <= limit_b
    phases = [r["phase"] for r in records(m.log) if r["type"] == "phase"]
    assert "seek" in phases  # the limit tripped mid-mission, with vehicles in the air


def _router_gone(m: _Fly) -> None:
    m.start()
    m.wait_for(_seeking(m.log), "the seek")
    m.router.kill()
    m.router.wait(timeout=30)
    status = m.finish()
    summary = _summary(m.log)
    assert summary["outcome"] in ("aborted", "max_iterations") and summary["airborne_left"] == []
    # not converged: the seek went on blind, then home (1; 4 when a loaded host also cost a vehicle's
    # link for over the plan's link timeout: that vehicle is in the summary's lost)
    assert status == summary_exit_status(summary) == (4 if summary["lost"] else 1), (status, m.err.text()[-2000:])
    assert any("no fresh reading from vehicles [1, 2, 3, 4]" in e for e in _events(m.log))


