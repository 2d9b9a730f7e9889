"""mission.sim.lockstep: simulated time on an asyncio loop, a world driven in lock-step, and
the reproducibility of a whole embedded mission."""
from __future__ import annotations

import asyncio
import json
import re
import socket
import threading

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.cli import main as cli_main
from mission.sim.lockstep import LOCKSTEP_T0_S, LockstepEventLoop, VirtualClock, run_lockstep


class _StepWorld:
    """A world with an event every ``period_s``; records what the loop asked of it."""

    def __init__(self, clock: VirtualClock, period_s: float = 0.02):
        self.clock = clock
        self.period_s = period_s
        self.next_s = clock.time() + period_s
        self.advanced_to: list[float] = []
        self.settles = 0

    def settle(self) -> None:
        self.settles += 1

    def next_event_s(self) -> float:
        return self.next_s

    def advance_to(self, t_s: float) -> None:
        assert t_s == pytest.approx(self.clock.time())
        self.advanced_to.append(t_s - self.clock.t0_s)
        while self.next_s <= t_s + 1e-9:
            self.next_s += self.period_s


def test_virtual_clock_starts_at_the_fixed_epoch_and_never_goes_back():
    clock = VirtualClock()
    assert clock.time() == LOCKSTEP_T0_S
    clock.advance_to(2.5)
    clock.advance_to(1.0)
    assert clock.elapsed_s == 2.5
    assert clock.time() == LOCKSTEP_T0_S + 2.5
    with pytest.raises(ValueError, match="finite"):
        VirtualClock(float("nan"))


def test_sleep_blocking_waits_for_the_loop_and_refuses_on_the_loops_own_thread():
    clock = VirtualClock()
    woke_at = []
    asleep = threading.Event()

    def nap():
        asleep.set()
        clock.sleep_blocking(2.0)
        woke_at.append(clock.elapsed_s)

    beside = threading.Thread(target=nap)
    stuck = threading.Thread(target=lambda: clock.sleep_blocking(1e6))  # longer than the run

    async def main():
        with pytest.raises(RuntimeError, match="own thread"):
            clock.sleep_blocking(1.0)
        beside.start()
        stuck.start()
        assert asleep.wait(10)
        for _ in range(40):
            await clock.sleep(0.1)

    run_lockstep(main, clock)
    beside.join(timeout=10)
    stuck.join(timeout=10)  # released when the run ends: nothing would move the clock any more
    assert not beside.is_alive() and not stuck.is_alive()
    # not before its 2 s (when exactly it runs after that depends on when it gets the GIL)
    assert woke_at and 2.0 <= woke_at[0] <= 4.0 + 1e-9


@pytest.mark.parametrize("dt_s", [0.0, 0.013, 5.0, 3600.0])
def test_sleep_takes_exactly_its_simulated_time(dt_s):
    clock = VirtualClock()

    async def main():
        await clock.sleep(dt_s)
        return clock.elapsed_s

    assert run_lockstep(main, clock) == pytest.approx(dt_s)


def test_timeouts_run_on_simulated_time():
    clock = VirtualClock()

    async def main():
        never = asyncio.Event()
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(never.wait(), timeout=7.0)
        return clock.elapsed_s

    assert run_lockstep(main, clock) == pytest.approx(7.0)


def test_run_in_executor_runs_at_once_in_zero_simulated_time():
    clock = VirtualClock()

    async def main():
        loop = asyncio.get_running_loop()
        value = await loop.run_in_executor(None, sum, [1, 2, 3])
        with pytest.raises(ZeroDivisionError):
            await loop.run_in_executor(None, divmod, 1, 0)
        return value, clock.elapsed_s

    assert run_lockstep(main, clock) == (6, 0.0)


def test_waiting_on_nothing_is_a_deadlock_not_a_hang():
    clock = VirtualClock()

    async def main():
        await asyncio.get_running_loop().create_future()

    with pytest.raises(RuntimeError, match="deadlock"):
        run_lockstep(main, clock)


def test_the_world_runs_every_event_up_to_the_sleepers_deadline():
    clock = VirtualClock()
    world = _StepWorld(clock, period_s=0.02)

    async def main():
        await clock.sleep(1.0)

    run_lockstep(main, clock, world)
    assert clock.elapsed_s == pytest.approx(1.0)
    # one advance per world event (50 in one second; epoch-second floats may split the last
    # one in two), none past the deadline
    assert 50 <= len(world.advanced_to) <= 51
    assert all(b > a for a, b in zip(world.advanced_to, world.advanced_to[1:]))
    assert world.advanced_to[0] == pytest.approx(0.02)
    assert world.advanced_to[-1] == pytest.approx(1.0)
    assert world.settles >= 2 * 50


def test_time_advances_only_when_the_loop_is_idle():
    clock = VirtualClock()
    world = _StepWorld(clock, period_s=0.5)
    seen = []

    async def busy(n):
        for _ in range(n):
            seen.append(clock.elapsed_s)
            await asyncio.sleep(0)  # ready again at once: time must not move

    async def main():
        await asyncio.gather(busy(100), busy(100))
        await clock.sleep(0.1)

    run_lockstep(main, clock, world)
    assert set(seen) == {0.0}
    assert clock.elapsed_s == pytest.approx(0.1)
    assert world.advanced_to == [pytest.approx(0.1)]


def test_loop_time_is_the_clock():
    clock = VirtualClock()
    loop = LockstepEventLoop(clock)
    try:
        clock.advance_to(12.0)
        assert loop.time() == 12.0
    finally:
        loop.close()


def _normalised_records(path):
    out = []
    for line in open(path, encoding="utf-8"):
        line = re.sub(r"127\.0\.0\.1:\d+", "127.0.0.1:PORT", line)  # ports are chosen at run time
        rec = json.loads(line)
        rec.pop("log_path", None)
        out.append(rec)
    return out


@pytest.mark.slow
def test_same_seed_same_mission_log(tmp_path, capsys):
    """Two lock-step runs of one seed write the same mission log, record for record."""
    argv = ["run", "--n", "4", "--seed", "13", "--max-iterations", "6", "--json", "--no-tlog"]
    codes = [cli_main(argv + ["--log-dir", str(tmp_path / name)]) for name in ("a", "b")]
    capsys.readouterr()
    assert codes[0] == codes[1]
    a = _normalised_records(tmp_path / "a" / "mission.jsonl")
    b = _normalised_records(tmp_path / "b" / "mission.jsonl")
    kinds = {r["type"] for r in a}
    assert {"plan", "phase", "iteration", "summary"} <= kinds
    assert sum(r["type"] == "iteration" for r in a) == 6
    assert a == b


class _ForwardClient:
    """A passive ``--out`` client on loopback: a UDP socket read by a thread until :meth:`stop`."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.address = f"udp:127.0.0.1:{self.sock.getsockname()[1]}"
        self.sysids: set[int] = set()
        self.frames = 0
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        while not self._stopping.is_set():
            try:
                data = self.sock.recv(65535)
            except socket.timeout:
                continue
            for msg in parser.parse_buffer(data) or ():
                if msg.get_type() != "BAD_DATA":
                    self.frames += 1
                    self.sysids.add(msg.get_srcSystem())

    def stop(self) -> None:
        self._stopping.set()
        self._thread.join(timeout=10)
        self.sock.close()


#: what a passive ``--out`` listener may legitimately change in the mission log, and nothing else:
#: the two events of the forwarding itself (its start, naming the address, and its counts at the
#: end), the plan's ``[forward] out`` (the address), the log's own path in the summary, and the
#: loopback ports chosen at run time (vehicles, zenoh, the client), normalised by _normalised_records.
#: A lock-step log has no wall-clock field (every ``t_s`` is simulated time).
_FORWARD_EVENT_KEYS = ("forward_out", "forward")


def _without_forwarding(records):
    """``records`` without what the forwarding legitimately adds; the dropped events, apart."""
    kept, dropped = [], []
    for rec in records:
        if rec["type"] == "event" and any(k in rec for k in _FORWARD_EVENT_KEYS):
            dropped.append(rec)
            continue
        if rec["type"] == "plan":
            rec["plan"]["forward"].pop("out")
        kept.append(rec)
    return kept, dropped


@pytest.mark.slow
def test_a_passive_forward_listener_does_not_change_a_lockstep_mission(tmp_path, capsys):
    """One seed flown without and with ``--out`` to a loopback client that only listens: the
    same mission log, record for record, but for what :data:`_FORWARD_EVENT_KEYS` and
    :func:`_without_forwarding` list."""
    argv = ["run", "--n", "4", "--seed", "7", "--max-iterations", "6", "--json", "--no-tlog"]
    client = _ForwardClient()
    try:
        plain = cli_main(argv + ["--log-dir", str(tmp_path / "plain")])
        forwarded = cli_main(argv + ["--log-dir", str(tmp_path / "out"), "--out", client.address])
    finally:
        client.stop()
    capsys.readouterr()
    assert plain == forwarded
    a, none = _without_forwarding(_normalised_records(tmp_path / "plain" / "mission.jsonl"))
    b, events = _without_forwarding(_normalised_records(tmp_path / "out" / "mission.jsonl"))
    assert none == [] and len(events) == 2
    frames_out = events[-1]["forward"]["frames_out"]
    assert 0 < client.frames <= frames_out and client.sysids <= {1, 2, 3, 4}  # it really listened
    assert sum(r["type"] == "iteration" for r in a) == 6
    assert len(a) == len(b)
    for rec_a, rec_b in zip(a, b):
        assert rec_a == rec_b


class _FakeFleet:
    def __init__(self):
        self.published_readings = 0
        self.matched = True
        self.serviced = 0
        self.next_step_s = 0.0

    def readings_matched(self):
        return self.matched

    def service_io(self):
        self.serviced += 1
        return 0

    def step_until(self, t_s):
        self.next_step_s = t_s + 0.02


class _FakeStore:
    def __init__(self):
        self.subscribers = 1
        self.accepted = 0

    def counts(self):
        return {"accepted": self.accepted, "rejected": {"late": 0}}


def test_embedded_world_waits_for_readings_and_writes_off_a_lost_one_once():
    from mission.sim.embedded_world import EmbeddedWorld

    fleet, store = _FakeFleet(), _FakeStore()
    world = EmbeddedWorld(fleet, store, settle_timeout_s=0.2)
    world.settle()                                   # nothing in flight
    assert (world.waits, world.stalls, fleet.serviced) == (0, 0, 1)
    fleet.published_readings = 2                     # two readings on their way...
    arrive = threading.Timer(0.02, lambda: setattr(store, "accepted", 2))
    arrive.start()
    world.settle()                                   # ... waited for, and they came
    arrive.join()
    assert (world.waits, world.stalls) == (1, 0)
    fleet.published_readings = 3                     # one that never comes
    world.settle()
    assert (world.waits, world.stalls) == (2, 1)
    world.settle()                                   # written off: not waited for again
    assert (world.waits, world.stalls) == (2, 1)
    fleet.published_readings = 4
    store.accepted = 3                               # the next one is counted as usual
    world.settle()
    assert (world.waits, world.stalls) == (2, 1)


def test_embedded_world_gives_up_on_a_subscription_that_never_matches_until_it_does():
    from mission.sim.embedded_world import EmbeddedWorld

    fleet, store = _FakeFleet(), _FakeStore()
    fleet.matched = False                            # zenoh connected elsewhere
    world = EmbeddedWorld(fleet, store, settle_timeout_s=0.1)
    world.settle()
    world.settle()
    assert (world.waits, world.stalls) == (1, 1)     # one bounded wait, then given up
    fleet.matched = True
    fleet.published_readings = 1                     # matched at last: waits again
    world.settle()
    assert (world.waits, world.stalls) == (2, 2)
    store.subscribers = 0                            # nobody listens: nothing to wait for
    world.settle()
    assert (world.waits, world.stalls) == (2, 2)
