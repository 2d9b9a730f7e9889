"""The ground station's own faults, piece by piece: a best-effort terminal, a mission log
that fails without raising, background tasks whose failure is told, a state publication and a live
display that never stop a mission. The whole ``fly`` process under these faults:
``tests/mission/flight/test_gcs_faults_output.py tests/mission/flight/test_gcs_faults_signals.py``."""
from __future__ import annotations

import asyncio
import errno
import os
import signal
import sys

import numpy as np

from mission.core.tasks import spawn, stop_watched, watch_task
from mission.sim.embedded import DEFAULT_ORIGIN, default_eps, embedded_plan, fleet_ports
from mission.sim.lockstep import VirtualClock
from mission.telemetry.display import Display
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.telemetry.state_pub import StatePublisher
from mission.telemetry.terminal import Terminal, alert, best_effort_terminal
from sitl_mock.fields_gaussian import sigma2
from sitl_mock.fleet import MockFleet

from tests.support.fly_helpers import run_fleet


class _Clock:
    def time(self):
        return 0.0


class _DeadStream:
    """A text stream whose every write fails as a closed pipe does."""

    def __init__(self, exc=BrokenPipeError(errno.EPIPE, "Broken pipe")):
        self.exc, self.writes = exc, 0

    def write(self, text):
        self.writes += 1
        raise self.exc

    def flush(self):
        raise self.exc

    def isatty(self):
        return False


def test_a_lost_stream_is_told_once_to_the_log_and_then_left_alone(tmp_path):
    dead = _DeadStream()
    term = Terminal(dead, _DeadStream(OSError(errno.EIO, "Input/output error")))
    assert term.out.write("before the log\n") == len("before the log\n")  # no exception
    term.out.write("again\n")
    assert dead.writes == 1 and isinstance(term.out.lost, BrokenPipeError)
    log = MissionLog(tmp_path / "m.jsonl", _Clock())
    with term.attach_log(log):  # the loss before the log is told when it is attached
        term.err.flush()
        term.err.write("x")
    log.close()
    lost = [r for r in read_mission_log(tmp_path / "m.jsonl") if r.get("terminal_lost")]
    assert [r["terminal_lost"] for r in lost] == ["stdout", "stderr"]
    assert "BrokenPipeError" in lost[0]["message"] and "the mission goes on" in lost[0]["message"]
    assert not term.out.isatty()


def test_a_dead_pipe_on_stdout_is_pointed_at_devnull_so_the_last_flush_cannot_fail():
    r, w = os.pipe()
    os.close(r)
    stream = os.fdopen(w, "w")
    term = Terminal(stream, sys.stderr)
    term.out.write("x" * 100)
    term.out.flush()  # EPIPE: lost; the descriptor now points at /dev/null
    assert term.out.lost is not None
    stream.write("what the interpreter would flush at exit")
    stream.flush()  # no BrokenPipeError any more ("Exception ignored ... BrokenPipeError")
    assert os.readlink(f"/proc/self/fd/{stream.fileno()}") == os.devnull
    stream.close()


def test_alert_falls_back_to_stdout_when_stderr_is_gone(capsys):
    with best_effort_terminal() as term:
        term.err.lost = BrokenPipeError()
        assert alert("swarmseek: ERROR: loud")
    assert capsys.readouterr().out == "swarmseek: ERROR: loud\n"
    assert sys.stdout is not term.out  # restored


def test_the_mission_log_never_raises_when_it_cannot_write(tmp_path):
    told = []
    log = MissionLog("/dev/full", _Clock())  # every write: ENOSPC
    log.on_error = told.append
    log.event("one")
    log.phase("two")
    log.close()
    assert isinstance(log.error, OSError) and log.error.errno == errno.ENOSPC
    assert told == [log.error] and log.dropped == 2 and log.records == 0


def test_a_failed_background_task_is_told_and_its_exception_retrieved():
    told = []

    async def fails():
        raise RuntimeError("boom")

    async def main():
        task = spawn(fails(), "the test task", told.append)
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        await stop_watched(task)  # does not raise again
        quiet = watch_task(asyncio.ensure_future(asyncio.sleep(10)), "sleeping", told.append)
        await stop_watched(quiet)  # a cancellation is no failure

    asyncio.run(main())
    assert told == ["background task the test task failed: RuntimeError: boom"]


def test_a_failing_display_never_stops_the_state_publication():
    told, shown = [], []

    def update(state):
        shown.append(state)
        raise TypeError("a bug in the display")

    async def main():
        pub = StatePublisher(None, "f", lambda: {"phase": "seek"}, rate_hz=100.0, on_snapshot=update,
                             report=told.append)
        pub.start()
        while len(shown) < 3:
            await asyncio.sleep(0.01)
        await pub.stop()
        return pub

    pub = asyncio.run(main())
    assert pub.errors >= 3 and len(told) == 1 and "showing the mission's state failed" in told[0]


def test_a_mission_whose_terminal_died_flies_to_the_end_and_lands_everyone(tmp_path):
    """``fly | head`` (stdout closed early), at the coordinator: a display on a dead pipe (without the
    command's best-effort terminal) is turned off; the mission goes on and every vehicle lands."""
    source = np.array([4.0, 3.0, 12.0])
    ports = fleet_ports(4, "px4")
    fleet = MockFleet(n=4, personality="px4", field=sigma2(source), origin=DEFAULT_ORIGIN, clock=VirtualClock(),
                      seed=3, udp_base_port=ports["udp_base_port"], udp_bind_base_port=ports["udp_bind_base_port"],
                      tcp_base_port=0, zenoh_listen=[f"tcp/127.0.0.1:{ports['zenoh_port']}"])
    plan = embedded_plan(4, ports, personality="px4", start_enu_m=(0.0, 0.0, 12.0),
                         eps=default_eps(sigma2(source)), max_iterations=3)
    display = Display(stream=_DeadStream(), tty=False, min_interval_s=0.0)
    log_path = tmp_path / "m.jsonl"

    async def main(world):
        from mission.flight.coordinator import Coordinator
        import zenoh

        session = zenoh.open(plan.zenoh.to_config())
        log = MissionLog(log_path, fleet.clock)
        try:
            co = Coordinator(plan, clock=fleet.clock, zenoh_session=session, log=log, display=display)
            world.store = co.store
            return await co.run()
        finally:
            log.close()
            session.close()

    try:
        result = run_fleet(fleet, main)  # checks the never-abandon invariant against the fleet
    finally:
        fleet.stop()
    assert result.outcome in ("converged", "max_iterations") and not result.airborne_left
    messages = [r["message"] for r in read_mission_log(log_path) if r["type"] == "event"]
    assert sum("the live display failed (BrokenPipeError" in m for m in messages) == 1
    landed = {r["sysid"] for r in read_mission_log(log_path)
              if r["type"] == "status_change" and r["status"] == "landed"}
    assert landed == {1, 2, 3, 4}


def test_best_effort_terminal_restores_the_signal_mask():
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    with best_effort_terminal():
        assert signal.SIGPIPE in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before
