"""The setpoint streamer is the last speed gate before the wire."""
import numpy as np
import pytest

from mission.vehicle.streamer import SetpointStreamer


class _Clock:
    speedup = 1.0

    def __init__(self):
        self.t = 100.0

    def time(self):
        return self.t


class _Vehicle:
    def __init__(self, sysid):
        self.sysid = sysid
        self.sent = []

    def send_position_enu(self, position, yaw):
        self.sent.append(np.array(position, dtype=float))


@pytest.mark.parametrize("max_speed", [1.0, 3.0, 7.5])
def test_no_sent_step_exceeds_the_speed_limit_whatever_the_targets_do(max_speed):
    clock, v = _Clock(), _Vehicle(1)
    s = SetpointStreamer([v], rate_hz=10.0, clock=clock, max_speed_m_s=max_speed)
    rng = np.random.default_rng(3)
    times = [clock.t]
    s.set_target(1, (0.0, 0.0, 10.0))
    s.tick()
    for _ in range(300):
        # targets jump far and ticks come irregularly (a stalled loop, a fast ramp)
        clock.t += float(rng.uniform(0.01, 0.3))
        s.set_target(1, tuple(rng.normal(0.0, 20.0, 3)))
        s.tick()
        times.append(clock.t)
    steps = np.linalg.norm(np.diff(np.array(v.sent), axis=0), axis=1)
    speeds = steps / np.diff(times)
    assert speeds.max() <= max_speed * (1 + 1e-9)
    assert s.stats(1)["speed_limited"] > 100  # the gate really acted


def test_a_reachable_target_is_sent_exactly():
    clock, v = _Clock(), _Vehicle(1)
    s = SetpointStreamer([v], rate_hz=10.0, clock=clock, max_speed_m_s=3.0)
    s.set_target(1, (0.0, 0.0, 10.0))
    s.tick()
    clock.t += 0.1
    s.set_target(1, (0.2, 0.0, 10.0))  # 2 m/s
    s.tick()
    assert np.allclose(v.sent[-1], [0.2, 0.0, 10.0])
    clock.t += 0.1
    s.set_target(1, (10.0, 0.0, 10.0))  # far: moves 3 m/s * 0.1 s towards it
    s.tick()
    assert np.allclose(v.sent[-1], [0.2 + 0.3, 0.0, 10.0])
    assert s.stats(1)["speed_limited"] == 1


def test_bad_speed_limit_is_refused():
    with pytest.raises(ValueError, match="max_speed_m_s must be a positive number"):
        SetpointStreamer([], max_speed_m_s=0.0)
