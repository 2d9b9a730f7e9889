"""The safety gate (mission.safety.gate) is the one speed limiter: what reaches the wire, datagram
after datagram, never moves faster than ``max_speed_m_s`` over the time between the two."""
import asyncio

import numpy as np
import pytest

from mission.safety.envelope import SafetyEnvelope
from mission.safety.fence import Geofence
from mission.safety.gate import SafetyGate
from mission.vehicle.streamer import SetpointStreamer


class _LateClock:
    """A mission clock whose sleeps wake late by a random amount (a loaded or stalled loop)."""

    speedup = 1.0

    def __init__(self, rng, max_late_s):
        self.t, self.rng, self.max_late_s = 100.0, rng, max_late_s

    def time(self):
        return self.t

    async def sleep(self, dt_s):
        self.t += dt_s + float(self.rng.uniform(0.0, self.max_late_s))
        await asyncio.sleep(0)


class _Vehicle:
    """Records every datagram with the clock time it was sent at; a send takes up to
    ``send_cost_s`` of clock time (a slow host on the wall clock, ten times worse at 10x)."""

    def __init__(self, sysid, clock, send_cost_s=0.0):
        self.sysid, self.clock, self.sent, self.send_cost_s = sysid, clock, [], send_cost_s

    def send_position_enu(self, position, yaw):
        self.clock.t += float(self.clock.rng.uniform(0.0, self.send_cost_s))
        self.sent.append((self.clock.time(), np.array(position, dtype=float)))
        self.clock.t += float(self.clock.rng.uniform(0.0, self.send_cost_s))


class _SlowEnvelope(SafetyEnvelope):
    """An envelope whose check takes up to ``cost_s`` of clock time."""

    def __init__(self, clock, cost_s, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._clock, self._cost_s = clock, cost_s

    def clamp_setpoints(self, prev_positions, new_positions, dt_s):
        self._clock.t += float(self._clock.rng.uniform(0.0, self._cost_s))
        return super().clamp_setpoints(prev_positions, new_positions, dt_s)


def _fly(max_speed, max_late_s, envelope=None, ticks=300, seed=3, goal=None, send_cost_s=0.0):
    """Goals jump far every tick (or all are ``goal``); returns the vehicles (their datagrams),
    the streamer and the gate. ``envelope``: None or a function of the clock."""
    rng = np.random.default_rng(seed)
    clock = _LateClock(rng, max_late_s)
    envelope = envelope(clock) if envelope is not None else None
    vehicles = [_Vehicle(s, clock, send_cost_s) for s in (1, 2, 3)]
    streamer = SetpointStreamer(vehicles, rate_hz=10.0, clock=clock)
    gate = SafetyGate(streamer, clock, max_speed, envelope=envelope, max_vertical_speed_m_s=max_speed)
    for i, v in enumerate(vehicles):
        gate.add(v.sysid, [10.0 * i, 0.0, 20.0])

    async def main():
        gate.start()
        while len(vehicles[0].sent) < ticks:
            gate.set_goals({v.sysid: np.array([*rng.normal(0.0, 40.0, 2), rng.uniform(10.0, 40.0)])
                            if goal is None else np.asarray(goal, dtype=float) for v in vehicles})
            await asyncio.sleep(0)
        await gate.stop()

    asyncio.run(main())
    return vehicles, streamer, gate


def _wire_speeds(vehicle):
    t = np.array([s[0] for s in vehicle.sent])
    p = np.array([s[1] for s in vehicle.sent])
    dist, dt = np.linalg.norm(np.diff(p, axis=0), axis=1), np.diff(t)
    assert (dt > 0).all()
    return dist, dt


@pytest.mark.parametrize("max_speed, max_late_s, send_cost_s", [(1.0, 0.0, 0.0), (3.0, 0.05, 0.0),
                                                                (7.5, 0.8, 0.0), (3.0, 0.05, 0.02)])
def test_no_datagram_step_exceeds_the_speed_limit_whatever_the_goals_and_the_loop_do(max_speed, max_late_s,
                                                                                      send_cost_s):
    vehicles, streamer, gate = _fly(max_speed, max_late_s, send_cost_s=send_cost_s)
    moved = 0
    for v in vehicles:
        dist, dt = _wire_speeds(v)
        assert (dist <= max_speed * dt + 1e-9).all(), float(np.max(dist / dt))
        moved += int(np.sum(dist > 0.5 * max_speed * 0.1))
    assert moved > 100  # the vehicles really moved (the goals were never reached)
    assert gate.batches > 100 and streamer.ticks == len(vehicles[0].sent)


def test_what_is_sent_is_what_the_envelope_returned_tick_for_tick():
    fence = Geofence(np.array([[-30.0, -30], [30, -30], [30, 30], [-30, 30]]), 5.0, 35.0)
    # the envelope and the sends take time: the next step's time base is still the time between sends
    env = lambda clock: _SlowEnvelope(clock, 0.08, fence, max_speed_m_s=3.0, min_separation_m=2.0,  # noqa: E731
                                      formation_radius_m=2.0)
    # all three sent to one point beyond the fence: clamped at the fence, held apart near it
    vehicles, _, gate = _fly(3.0, 0.05, envelope=env, ticks=300, goal=[50.0, 0.0, 20.0], send_cost_s=0.01)
    for v in vehicles:
        dist, dt = _wire_speeds(v)
        assert (dist <= 3.0 * dt + 1e-9).all()
        p = np.array([s[1] for s in v.sent])
        assert fence.contains(p, 1e-6).all()
        assert np.allclose(p[-1], gate.setpoint(v.sysid))  # the last batch is the last datagram
    assert gate.clamped_batches > 0 and gate.separation_interventions > 0  # the envelope really acted
    final = np.array([gate.setpoint(v.sysid) for v in vehicles])
    assert min(np.linalg.norm(final[i] - final[j]) for i in range(3) for j in range(i)) >= 2.0 - 1e-6


def test_the_gate_sends_at_the_streamers_rate_by_default():
    streamer = SetpointStreamer([], rate_hz=25.0)
    gate = SafetyGate(streamer, streamer.clock, 3.0)
    assert gate.period_s == pytest.approx(1 / 25.0)


def test_the_streamer_limits_nothing():
    with pytest.raises(TypeError):
        SetpointStreamer([], max_speed_m_s=3.0)  # the gate is the one speed limiter
