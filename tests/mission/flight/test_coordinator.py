"""Coordinator parts without the mock fleet: setpoint ramp, layered transfers, mission log,
display, state publication, and the seek loop with ideal fake vehicles vs the offline simulation."""
from __future__ import annotations

import asyncio
import io
import json
import time
from pathlib import Path

import numpy as np
import pytest

from mission.telemetry.display import Display, format_line, format_summary, format_table
from mission.telemetry.mission_log import MissionLog, read_mission_log
from mission.safety.gate import SafetyGate
from mission.flight.targets import assign_slots, layered_altitudes, layered_transfer


class _Clock:
    speedup = 1.0

    def __init__(self, t=1000.0):
        self.t = t

    def time(self):
        return self.t

    async def sleep(self, dt_s):
        self.t += dt_s
        await asyncio.sleep(0)


class _Streamer:
    rate_hz = 10.0

    def __init__(self):
        self.targets = {}
        self.history = []

    def set_target(self, sysid, p, yaw_rad=None):
        self.targets[sysid] = np.asarray(p, dtype=float).copy()
        self.history.append((sysid, self.targets[sysid]))

    def remove(self, sysid):
        self.targets.pop(sysid, None)

    def tick(self):
        return 0

    def stats(self, sysid):
        return {"rate_hz": 10.0}


# ------------------------------------------------------------------------------ ramp
@pytest.mark.parametrize("speed, vspeed", [(3.0, 1.0), (1.0, 1.0), (5.0, 0.5)])
def test_ramp_limits_speed_and_reaches_goal(speed, vspeed):
    st = _Streamer()
    ramp = SafetyGate(st, _Clock(), speed, rate_hz=10, max_vertical_speed_m_s=vspeed)
    ramp.add(1, [0, 0, 10])
    ramp.add(2, [5, 0, 10])
    ramp.set_goals({1: np.array([10.0, 0, 14]), 2: np.array([5.0, -3, 10])})
    prev = {1: ramp.setpoint(1), 2: ramp.setpoint(2)}
    for _ in range(200):
        ramp.step(0.1)
        for s in (1, 2):
            p = ramp.setpoint(s)
            d = p - prev[s]
            assert np.linalg.norm(d) <= speed * 0.1 + 1e-9
            assert abs(d[2]) <= vspeed * 0.1 + 1e-9
            prev[s] = p
    assert ramp.at_goal(1) and ramp.at_goal(2)
    assert np.allclose(st.targets[1], [10, 0, 14])


def test_ramp_passes_every_batch_through_the_safety_envelope():
    from mission.safety.fence import Geofence
    from mission.safety.envelope import SafetyEnvelope

    fence = Geofence(np.array([[-10.0, -10], [10, -10], [10, 10], [-10, 10]]), 2.0, 30.0)
    env = SafetyEnvelope(fence, max_speed_m_s=2.0, min_separation_m=1.0, formation_radius_m=1.0)
    messages = []
    st = _Streamer()
    ramp = SafetyGate(st, _Clock(), 5.0, rate_hz=10, envelope=env, on_violation=messages.append,
                      max_vertical_speed_m_s=5.0)
    ramp.add(1, [0, 0, 10])
    ramp.set_goal(1, [50.0, 0, 10])  # outside the fence, and faster than the envelope allows
    for _ in range(100):
        ramp.step(0.1)
    assert all(fence.contains(p) for _, p in st.history)
    steps = np.diff(np.array([p for _, p in st.history]), axis=0)
    assert np.max(np.linalg.norm(steps, axis=1)) <= 2.0 * 0.1 + 1e-6
    assert ramp.setpoint(1)[0] == pytest.approx(10.0, abs=1e-6)
    assert ramp.clamped_batches > 0 and messages


def test_ramp_rejects_goal_for_unknown_vehicle():
    ramp = SafetyGate(_Streamer(), _Clock(), 3.0)
    with pytest.raises(KeyError, match="no setpoint yet"):
        ramp.set_goal(7, [0, 0, 0])


def test_ramp_settles_then_wakes_on_a_new_goal_or_vehicle():
    """At its goals, with the batch passed by the envelope, the ramp stops re-sending and re-checking."""
    from mission.safety.fence import Geofence
    from mission.safety.envelope import SafetyEnvelope

    class _CountingEnvelope(SafetyEnvelope):
        calls = 0

        def clamp_setpoints(self, prev, new, dt_s):
            type(self).calls += 1
            return super().clamp_setpoints(prev, new, dt_s)

    fence = Geofence(np.array([[-50.0, -50], [50, -50], [50, 50], [-50, 50]]), 2.0, 30.0)
    env = _CountingEnvelope(fence, max_speed_m_s=5.0, min_separation_m=1.0, formation_radius_m=1.0)
    st = _Streamer()
    ramp = SafetyGate(st, _Clock(), 3.0, rate_hz=10, envelope=env, max_vertical_speed_m_s=3.0)
    ramp.add(1, [0, 0, 10])
    ramp.add(2, [5, 0, 10])
    ramp.set_goal(1, [1.0, 0, 10])
    for _ in range(20):
        ramp.step(0.1)
    assert ramp.at_goal(1) and ramp.idle_steps > 0
    calls, sent, idle = env.calls, len(st.history), ramp.idle_steps
    for _ in range(10):
        ramp.step(0.1)
    assert (env.calls, len(st.history)) == (calls, sent)  # nothing checked or re-sent
    assert ramp.idle_steps == idle + 10
    ramp.set_goal(2, [5.0, 0, 10])  # the same goal again: still settled
    ramp.step(0.1)
    assert env.calls == calls
    ramp.set_goal(2, [5.0, 2.0, 10])  # a new goal wakes it
    for _ in range(20):
        ramp.step(0.1)
    assert env.calls > calls and np.allclose(st.targets[2], [5, 2, 10]) and ramp.at_goal(2)
    calls = env.calls
    ramp.add(3, [-5, 0, 1.0])  # a new vehicle below the fence floor: checked (and lifted) at once
    ramp.step(0.1)
    assert env.calls == calls + 1 and st.targets[3][2] >= 2.0


def test_ramp_never_settles_while_the_envelope_holds_a_vehicle_short_of_its_goal():
    from mission.safety.fence import Geofence
    from mission.safety.envelope import SafetyEnvelope
    fence = Geofence(np.array([[-10.0, -10], [10, -10], [10, 10], [-10, 10]]), 2.0, 30.0)
    env = SafetyEnvelope(fence, max_speed_m_s=5.0, min_separation_m=1.0, formation_radius_m=1.0)
    ramp = SafetyGate(_Streamer(), _Clock(), 3.0, rate_hz=10, envelope=env)
    ramp.add(1, [0, 0, 10])
    ramp.set_goal(1, [50.0, 0, 10])  # outside the fence: clamped at its edge for ever
    for _ in range(60):
        ramp.step(0.1)
    assert ramp.idle_steps == 0 and ramp.setpoint(1)[0] == pytest.approx(10.0, abs=1e-6)


# ------------------------------------------------------------------------ layered transfer
def _simulate_ramp(batches, speed, vspeed, dt=0.05):
    """Positions over time when every vehicle follows ``batches`` with the ramp's speed limits."""
    st = _Streamer()
    ramp = SafetyGate(st, _Clock(), speed, rate_hz=1 / dt, max_vertical_speed_m_s=vspeed)
    for i, p in enumerate(batches[0]):
        ramp.add(i, p)
    track = []
    for batch in batches[1:]:
        ramp.set_goals({i: g for i, g in enumerate(batch)})
        while not all(ramp.at_goal(i) for i in range(len(batch))):
            ramp.step(dt)
            track.append(np.array([ramp.setpoint(i) for i in range(len(batch))]))
    return np.array(track)


@pytest.mark.parametrize("n, kind, seed", [(4, "cvt", 0), (7, "cvt", 1), (8, "cvt", 2), (8, "symmetric", 3),
                                           (12, "cvt", 4)])
def test_layered_assembly_and_return_keep_separation(n, kind, seed):
    from mission.flight.targets import formation_offsets
    from mission.safety.envelope import pairwise_path_separation

    rng = np.random.default_rng(seed)
    min_sep = 1.5
    offsets = formation_offsets(kind, n, 4.0)
    homes = np.column_stack([rng.permutation(n) * 3.0, rng.uniform(-1, 1, n), np.zeros(n)])
    centre = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), 12.0])
    perm = assign_slots(homes * [1, 1, 0], (centre + offsets) * [1, 1, 0])
    slots = centre + offsets[perm]
    order = np.argsort(slots[:, 2])
    layers = np.empty(n)
    layers[order] = layered_altitudes(n, 8.0, 80.0, min_sep)
    takeoff = np.column_stack([homes[:, :2], layers])
    for start, goal in ((takeoff, slots), (slots, np.column_stack([homes[:, :2], layers]))):
        batches = [start] + layered_transfer(start, goal, layers)
        track = _simulate_ramp(batches, 3.0, 1.0)
        assert np.allclose(track[-1], goal)
        seps = [pairwise_path_separation(a, b).min() for a, b in zip(track[:-1], track[1:])]
        assert min(seps) >= min_sep - 1e-6, min(seps)


def test_layered_altitudes_must_fit():
    assert np.allclose(np.diff(layered_altitudes(5, 10.0, 30.0, 2.0)), 2.5)
    with pytest.raises(ValueError, match="widen the geofence"):
        layered_altitudes(10, 10.0, 20.0, 2.0)


# ----------------------------------------------------------------------------- mission log
def test_mission_log_lines_are_on_disk_as_soon_as_written(tmp_path):
    clock = _Clock()
    path = tmp_path / "sub" / "mission.jsonl"
    log = MissionLog(path, clock)
    log.phase("connect")
    log.write("iteration", k=1, centre_enu=np.array([1.0, 2.0, 3.0]), gradient=np.array([np.nan, 0, 1]),
              readings={3: np.float64(0.5)})
    lines = path.read_text().splitlines()  # read while still open: already flushed
    assert len(lines) == 2
    rec = json.loads(lines[1])
    assert rec["centre_enu"] == [1.0, 2.0, 3.0] and rec["gradient"][0] is None
    assert rec["readings"] == {"3": 0.5} and rec["t_s"] == pytest.approx(1000.0)
    with open(path, "a") as fh:
        fh.write('{"t_s": 1, "type": "iter')  # a crash mid-line
    log.event("after crash", level="warning")
    log.close()
    records = read_mission_log(path)
    assert [r["type"] for r in records] == ["phase", "iteration"]
    (tmp_path / "empty.jsonl").write_text("garbage\n")
    with pytest.raises(ValueError, match="not a swarmseek mission log"):
        read_mission_log(tmp_path / "empty.jsonl")


# ----------------------------------------------------------------------------- display
def _state(phase="seek"):
    return {"fleet": "demo", "phase": phase, "elapsed_s": 12.5, "iteration": 7,
            "centre_enu": [1.0, 2.0, 3.0], "gradient": [1e-3, -2e-3, 0.0], "gradient_norm": 2.2e-3,
            "estimate_enu": None, "spread_m": None, "distance_flown_m": 4.2,
            "readings": {"accepted": 10, "rejected": {"late": 2, "malformed": 0}},
            "vehicles": [{"sysid": 1, "id": "v1", "flavour": "px4", "mode": "OFFBOARD", "armed": True,
                          "relative_alt_m": 10.2, "link_age_s": 0.1, "setpoint_rate_hz": 10.0,
                          "status": "in formation"}]}


def test_display_table_redraws_in_place_on_a_tty():
    out = io.StringIO()
    d = Display(stream=out, tty=True)
    d.update(_state())
    first = out.getvalue()
    d.update(_state("return"))
    second = out.getvalue()[len(first):]
    assert "OFFBOARD" in first and "SEEK" in first and "'late': 2" in first
    n_lines = len(format_table(_state()))
    assert second.startswith(f"\x1b[{n_lines}F") and "RETURN" in second


def test_display_plain_lines_when_not_a_tty():
    out = io.StringIO()
    d = Display(stream=out, tty=False, min_interval_s=3600)
    d.update(_state())
    d.update(_state())  # same phase, too soon: no line
    d.update(_state("finish"))
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and "\x1b" not in out.getvalue()
    assert lines[0] == format_line(_state()) and "finish" in lines[1]


def test_quiet_display_prints_nothing_and_summary_lines():
    out = io.StringIO()
    d = Display(stream=out, quiet=True)
    d.update(_state())
    d.message("x")
    d.summary({"outcome": "converged"})
    assert out.getvalue() == ""
    lines = format_summary({"outcome": "converged", "message": "ok", "estimate_enu": [1, 2, 3],
                            "spread_m": 0.1, "iterations": 5, "true_source_enu": [1, 2, 3.1], "error_m": 0.1})
    assert lines[0].startswith("mission converged") and any("true source" in line for line in lines)


# ------------------------------------------------------------------------- state publisher
def test_state_publisher_puts_json_snapshots_on_the_documented_key():
    import zenoh

    from mission.sim.embedded import free_port_block
    from mission.telemetry.state_pub import STATE_SCHEMA, StatePublisher, state_key

    port = free_port_block(1, kinds=("tcp",))

    def conf(**eps):
        c = zenoh.Config()
        c.insert_json5("scouting/multicast/enabled", "false")
        for k, v in eps.items():
            c.insert_json5(f"{k}/endpoints", json.dumps(v))
        return c

    a = zenoh.open(conf(listen=[f"tcp/127.0.0.1:{port}"]))
    b = zenoh.open(conf(connect=[f"tcp/127.0.0.1:{port}"]))
    got = []
    try:
        sub = b.declare_subscriber(state_key("demo"), lambda s: got.append(json.loads(s.payload.to_bytes())))
        seen = []

        async def main():
            pub = StatePublisher(a, "demo", lambda: _state(), rate_hz=20.0, on_snapshot=seen.append)
            pub.start()
            deadline = time.monotonic() + 30
            while not got and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            await pub.stop()

        asyncio.run(main())
        assert got, "no state received"
        assert got[0]["schema"] == STATE_SCHEMA and got[0]["phase"] == "seek"
        assert got[0]["vehicles"][0]["mode"] == "OFFBOARD"
        assert seen and seen[0]["iteration"] == 7
        sub.undeclare()
    finally:
        b.close()
        a.close()


def test_seek_load_runs_the_seek_work_until_cancelled(monkeypatch):
    """The benchmark load (benchmarks/seek_load.py): readings validated, setpoints ramped through
    the envelope, estimates."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[3] / "benchmarks"))
    from mission.core.clock import WallClock
    from seek_load import seek_load

    class _V:
        def __init__(self, i):
            self.sysid = i
            self.mission_origin = (45.19, 5.72, 230.0)

        def position_enu_m(self):
            return np.array([2.0 * self.sysid, 0.0, 20.0])

    st = _Streamer()
    st.rate_hz = 20.0

    async def main():
        task = asyncio.ensure_future(seek_load([_V(i + 1) for i in range(8)], st, WallClock(),
                                               estimate_rate_hz=10.0))
        deadline = time.monotonic() + 30
        while len(st.history) < 8 * 5 and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(main())
    assert set(st.targets) == set(range(1, 9))
    assert len(st.history) >= 40
