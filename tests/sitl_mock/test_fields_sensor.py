"""Sensor response: first-order lag (63 % of a step in one time constant), detection floor
(below-floor readings report 0.0), and the field read at the sample's time."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sitl_mock.faults import FaultSet
from sitl_mock.sensor import SignalSensor
from sitl_mock.sensor_response import FirstOrderLag, set_fleet_response

T_STEP = 100.0


class _StepField:
    """0 before ``T_STEP``, ``level`` from it on (a time-dependent field)."""

    time_dependent = True

    def __init__(self, level=1.0):
        self.level = level

    def value(self, points, t_s=0.0):
        return np.full(np.shape(points)[:-1], self.level if t_s >= T_STEP else 0.0)


class _ConstField:
    def __init__(self, level):
        self.level = level

    def value(self, points, t_s=0.0):
        return np.full(np.shape(points)[:-1], self.level)


def _sensor(field, noise=0.0, seed=0):
    return SignalSensor(field, noise, np.random.default_rng(seed), FaultSet(), "test", 1)


def _run(sensor, times):
    return np.array([sensor.sample(t, (0.0, 0.0, 5.0), 45.0, 5.0, 200.0)["value"] for t in times])


@pytest.mark.parametrize("rate_hz", [10.0, 100.0])
def test_step_response_reaches_63_percent_at_one_time_constant(rate_hz):
    tau, dt = 2.0, 1.0 / rate_hz
    s = _sensor(_StepField())
    s.set_response(time_constant_s=tau)
    times = T_STEP - 5.0 + np.arange(int(round(5.0 / dt)) + int(round(10 * tau / dt)) + 1) * dt
    y = _run(s, times)
    at_tau = y[np.argmin(np.abs(times - (T_STEP + tau)))]
    # exact for the first-order hold: the step is seen as a ramp over the sample before it
    exact = 1.0 - (tau / dt) * (1.0 - math.exp(-dt / tau)) * math.exp(-1.0)
    assert at_tau == pytest.approx(exact, rel=1e-9)
    assert abs(at_tau - (1.0 - math.exp(-1.0))) <= math.exp(-1.0) * dt / (2.0 * tau) + 1e-9  # half a sample
    assert np.all(y[times < T_STEP - dt / 2] == 0.0) and np.all(np.diff(y) >= 0)
    assert y[-1] == pytest.approx(1.0, abs=math.exp(-9.0))  # ten time constants later


def test_first_sample_is_settled_and_zero_tau_is_instantaneous():
    lag = FirstOrderLag(3.0)
    assert lag(0.0, 0.7) == 0.7  # a sensor switched on settled
    assert lag(0.0, 5.0) == 0.7  # same time: no time to respond
    assert FirstOrderLag(0.0)(1.0, 0.3) == 0.3
    s = _sensor(_StepField())
    y = _run(s, [T_STEP - 0.1, T_STEP])
    assert list(y) == [0.0, 1.0]
    with pytest.raises(ValueError, match="time_constant_s"):
        FirstOrderLag(-1.0)
    with pytest.raises(ValueError, match="detection_floor"):
        s.set_response(detection_floor=-0.1)


def test_detection_floor_reports_zero_below_and_the_value_above():
    s = _sensor(_ConstField(0.5))
    s.set_response(detection_floor=0.6)
    assert list(_run(s, [1.0, 2.0])) == [0.0, 0.0]
    s.set_response(detection_floor=0.4)
    assert list(_run(s, [3.0])) == [0.5]
    plain = _sensor(_ConstField(0.0), noise=0.1, seed=1)  # no floor (default): noise keeps its sign
    y = _run(plain, np.arange(200.0))
    assert np.mean(y < 0.0) > 0.3 and np.all(y != 0.0)
    noisy = _sensor(_ConstField(0.5), noise=0.2, seed=3)
    noisy.set_response(detection_floor=0.5)
    y = _run(noisy, np.arange(2000.0))
    assert np.all((y == 0.0) | (y >= 0.5))
    assert 0.4 < np.mean(y == 0.0) < 0.6  # half the noisy readings fall below a floor at the mean


def test_sensor_reads_a_time_dependent_field_at_the_sample_time():
    from sitl_mock.fields_config import make_field

    f = make_field("intermittent", (0.0, 0.0, 10.0), seed=2)
    s = _sensor(f)
    times = 1767225600.0 + np.arange(50) * 0.5
    pos = f.steady.to_enu(15.0, 0.0, 10.0)
    y = np.array([s.sample(t, pos, 45.0, 5.0, 200.0)["value"] for t in times])
    assert np.allclose(y, f.value(np.broadcast_to(pos, (50, 3)), times), rtol=1e-12)


def test_set_fleet_response_sets_every_sensor():
    class _V:
        def __init__(self, sensor):
            self.sensor = sensor

    class _Fleet:
        vehicles = [_V(_sensor(_ConstField(1.0))), _V(None), _V(_sensor(_ConstField(1.0)))]

    assert set_fleet_response(_Fleet(), time_constant_s=1.5, detection_floor=0.01) == 2
    assert [v.sensor.time_constant_s for v in _Fleet.vehicles if v.sensor] == [1.5, 1.5]
    assert [v.sensor.detection_floor for v in _Fleet.vehicles if v.sensor] == [0.01, 0.01]
