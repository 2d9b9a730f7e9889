"""Shared by tests/mission/telemetry/test_ctl_processes.py (peers of the ground station) and
tests/mission/telemetry/test_ctl_processes_routed.py (through a zenoh router), both in the
wall-clock work unit (tests/conftest.py: one worker, one file after another): ``swarmseek mock``,
``swarmseek fly``, ``swarmseek watch`` and several ``swarmseek ctl`` in their own processes.

Everything runs on the wall clock in separate processes, so every wait is a condition poll with a
generous timeout (CI runs the suite with ``-n 4`` on 2 cores, possibly beside CPU-bound work):
``ctl`` waits :data:`CTL_WAIT_S` for the coordinator's answer, and the plan detects a vehicle's
loss after the longest link timeout it allows (1.4 s), so a starved mock process is less often
taken for a lost fleet."""
from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

from mission.core.plan_sections import LINK_TIMEOUT_MAX_S
from mission.sim.embedded import fleet_ports, free_port_block
from sitl_mock.fleet import DEFAULT_ORIGIN
from mission.telemetry.mission_log import read_mission_log
from tests.support.fly_helpers import summary_exit_status
from tests.support.fly_process import gradient_seek_plan, subprocess_env
from tests.support.wait_helpers import wait_until

ROOT = Path(__file__).resolve().parents[2]
#: wall seconds `ctl` waits to reach the ground station and for its answer (a cold process on a loaded host)
CTL_WAIT_S = 60.0
#: wall seconds for one condition seen through `watch` (snapshots, the hold, the next iteration)
WATCH_WAIT_S = 120.0


def free_port() -> int:
    """A loopback TCP port leased by :func:`mission.sim.embedded.free_port_block` (a port bound to 0
    and closed is in the ephemeral range: any process's next outgoing connection can take it)."""
    return free_port_block(1, kinds=("tcp",))


def swarmseek(*args, out: Path | None = None) -> subprocess.Popen:
    """Start `swarmseek ARGS`; its output goes to the file ``out`` (stdout piped when None)."""
    if out is None:
        return subprocess.Popen([sys.executable, "-m", "mission", *args], env=subprocess_env(), cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    with open(out, "w") as fh:
        return subprocess.Popen([sys.executable, "-m", "mission", *args], env=subprocess_env(), cwd=ROOT,
                                stdout=fh, stderr=subprocess.STDOUT, text=True)


def ctl(endpoint, *args, fleet="swarmseek", sender="tester", wait_s=CTL_WAIT_S):
    """Run `swarmseek ctl` (``--timeout-s wait_s``) to the end: (exit status, stdout + stderr)."""
    p = subprocess.run([sys.executable, "-m", "mission", "ctl", fleet, *args, "--sender", sender,
                        "--zenoh-connect", endpoint, "--timeout-s", str(wait_s)],
                       env=subprocess_env(), cwd=ROOT, capture_output=True, text=True, timeout=2 * wait_s + 60)
    return p.returncode, p.stdout + p.stderr


class Lines(threading.Thread):
    """Collects a process's stdout lines (JSON snapshots of `watch --json` are decoded)."""

    def __init__(self, stream):
        super().__init__(daemon=True)
        self.stream, self.lines, self.states = stream, [], []
        self.start()

    def run(self):
        for line in self.stream:
            self.lines.append(line)
            if line.startswith("{"):
                try:
                    self.states.append(json.loads(line))
                except ValueError:
                    pass

    def last(self):
        return self.states[-1] if self.states else {}


def _stop(*procs):
    for p in procs:
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def _operate(endpoint, watch: Lines, mission: subprocess.Popen, fleet: str):
    """Pause, check the hold, continue (twice: the second is refused), then land; returns the acks."""
    def seeking(k):
        s = watch.last()
        return s.get("phase") == "seek" and s.get("iteration", 0) >= k

    wait_until(lambda: seeking(2) or mission.poll() is not None, 240.0, "the seek (iteration 2)", poll_s=0.2)
    assert mission.poll() is None, "the mission ended before the seek (see its output file)"
    rc, out = ctl(endpoint, "pause", fleet=fleet, sender="alice")
    assert rc == 0 and "pause accepted" in out, out
    wait_until(lambda: (watch.last().get("control") or {}).get("holding"), WATCH_WAIT_S, "the hold", poll_s=0.1)
    n0 = len(watch.states)
    wait_until(lambda: len(watch.states) >= n0 + 4, WATCH_WAIT_S, "4 snapshots while paused", poll_s=0.1)
    held = [s for s in watch.states[n0 - 1:] if (s.get("control") or {}).get("holding")]
    assert len({s["iteration"] for s in held}) == 1 and len(held) >= 4      # no step while paused
    k = held[0]["iteration"]
    assert ctl(endpoint, "continue", fleet=fleet, sender="bob")[0] == 0
    rc, out = ctl(endpoint, "continue", fleet=fleet, sender="bob")
    assert rc == 1 and "REJECTED" in out and "not paused" in out, (out, mission.poll(), watch.last().get("phase"))
    wait_until(lambda: watch.last().get("iteration", 0) > k, WATCH_WAIT_S, "an iteration after continue", poll_s=0.1)
    rc, out = ctl(endpoint, "land", fleet=fleet, sender="carol")
    assert rc == 0 and "land accepted" in out, out


def _check_log(log_path: Path):
    commands = [(r["command"], r["sender"], r["accepted"]) for r in read_mission_log(log_path)
                if r["type"] == "command"]
    assert commands == [("pause", "alice", True), ("continue", "bob", True), ("continue", "bob", False),
                        ("land", "carol", True)]
    records = read_mission_log(log_path)
    landed = {r["sysid"] for r in records if r["type"] == "event" and r["message"].endswith(" landed")}
    assert landed == {1, 2, 3, 4}


def _plan_toml(path: Path, udp_base: int, zenoh_section: str, fleet: str) -> Path:
    """The plan of ``swarmseek fly``: four vehicles of ``swarmseek mock`` (its default origin), flying
    low (take-off and landing are most of the test's time); a loss is detected after the longest link
    timeout the plan allows (a starved mock process)."""
    return gradient_seek_plan(path, fleet=fleet, n=4, udp_base=udp_base, origin=DEFAULT_ORIGIN,
                              zenoh_section=zenoh_section, takeoff_alt_m=4.0, stagger_s=0.5, radius_m=3.0,
                              start_alt_m=7.0, fence_half_m=150.0, min_alt_m=2.0, max_alt_m=60.0,
                              link_timeout_s=LINK_TIMEOUT_MAX_S)


def _fly_and_operate(tmp_path, fleet: str, zenoh_section: str, endpoint: str):
    """`swarmseek mock` and `swarmseek fly` in their own processes, `watch` and `ctl` in others."""
    ports = fleet_ports(4, "px4")
    plan = _plan_toml(tmp_path / "plan.toml", ports["udp_base_port"], zenoh_section, fleet)
    # the source 33 m from the seek's start: the seek outlasts the cold `ctl` processes between the
    # continue and the land (at 11 m a starved CI host once saw it converge before the land arrived)
    mock = swarmseek("mock", "--vehicles", "4", "--personality", "px4", "--field", "sigma2", "--fleet", fleet,
                     "--source", "30,15,7", "--udp-base-port", str(ports["udp_base_port"]),
                     "--udp-bind-base-port", str(ports["udp_bind_base_port"]), "--tcp-base-port", "0",
                     "--zenoh-connect", endpoint, out=tmp_path / "mock.out")
    mission = swarmseek("fly", "--plan", str(plan), "--log-dir", str(tmp_path / "log"), "--no-tlog",
                        out=tmp_path / "fly.out")
    watch = swarmseek("watch", fleet, "--zenoh-connect", endpoint, "--json", "--wait-s", "120")
    lines = Lines(watch.stdout)
    try:
        _operate(endpoint, lines, mission, fleet)
        status = mission.wait(timeout=240)
        summary = next(r for r in read_mission_log(tmp_path / "log" / "mission.jsonl") if r["type"] == "summary")
        # ended by the operator: not converged (1; 4 if a starved mock process also cost a vehicle's link)
        assert status == summary_exit_status(summary) == (4 if summary["lost"] else 1), (status, summary["lost"])
        assert watch.wait(timeout=60) == status                     # the watcher ends with the mission, with its status
    finally:
        _stop(mission, watch, mock)
    assert lines.last().get("final") is True
    _check_log(tmp_path / "log" / "mission.jsonl")
