"""Point-mass multicopter: convergence, limits, ground contact, takeoff/land, crash, battery."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from sitl_mock.dynamics_params import DynamicsParams
from sitl_mock.dynamics import Multicopter

DT_S = 0.02


def _vehicle(seed=0, **kw) -> Multicopter:
    return Multicopter(DynamicsParams(**kw), np.random.default_rng(seed))


def _airborne(alt_m=10.0, seed=0, **kw) -> Multicopter:
    m = _vehicle(seed, **kw)
    m.arm()
    m.command_takeoff(alt_m)
    _run(m, alt_m / m.params.takeoff_speed_m_s + 10.0)
    return m


def _run(m: Multicopter, duration_s: float, check=None) -> None:
    for _ in range(int(round(duration_s / DT_S))):
        m.step(DT_S)
        if check is not None:
            check(m)


def test_starts_disarmed_and_landed_at_home():
    m = _vehicle()
    assert not m.armed and m.landed and not m.crashed
    np.testing.assert_array_equal(m.position_ned_m, np.zeros(3))
    assert m.battery_remaining == 1.0
    assert m.battery_voltage_v == pytest.approx(4 * 4.2)


def test_disarmed_vehicle_ignores_commands():
    m = _vehicle()
    m.command_takeoff(10.0)
    m.command_position([5.0, 5.0, -5.0])
    m.command_velocity([1.0, 0.0, -1.0])
    _run(m, 3.0)
    np.testing.assert_array_equal(m.position_ned_m, np.zeros(3))
    assert m.landed


def test_armed_on_ground_stays_until_takeoff():
    m = _vehicle()
    m.arm()
    _run(m, 2.0)
    assert m.armed and m.landed
    np.testing.assert_array_equal(m.position_ned_m, np.zeros(3))


@pytest.mark.parametrize("alt_m", [2.0, 10.0, 30.0])
def test_takeoff_climbs_vertically_to_altitude_at_takeoff_speed(alt_m):
    m = _vehicle()
    m.arm()
    m.command_takeoff(alt_m)
    climb = []
    _run(m, alt_m / m.params.takeoff_speed_m_s + 8.0, check=lambda v: climb.append(-v.velocity_ned_m_s[2]))
    assert -m.position_ned_m[2] == pytest.approx(alt_m, abs=0.05)
    np.testing.assert_allclose(m.position_ned_m[:2], 0.0, atol=1e-9)
    assert not m.landed
    assert max(climb) <= m.params.takeoff_speed_m_s + 1e-9


@pytest.mark.parametrize("bad", [0.0, -5.0, math.nan])
def test_takeoff_rejects_bad_altitude(bad):
    m = _vehicle()
    m.arm()
    with pytest.raises(ValueError, match="takeoff altitude"):
        m.command_takeoff(bad)


@pytest.mark.parametrize("target", [(30.0, -20.0, -15.0), (-5.0, 3.0, -4.0), (0.0, 80.0, -40.0)])
def test_converges_to_position_target(target):
    m = _airborne()
    m.command_position(target)
    _run(m, 60.0)
    np.testing.assert_allclose(m.position_ned_m, target, atol=0.05)
    assert np.linalg.norm(m.velocity_ned_m_s) < 0.05


def test_converges_despite_constant_wind_and_is_pushed_by_gusts():
    m = _airborne(wind_ned_m_s=(4.0, -3.0, 0.0))
    m.command_position((10.0, 10.0, -12.0))
    _run(m, 60.0)
    np.testing.assert_allclose(m.position_ned_m, (10.0, 10.0, -12.0), atol=0.1)
    g = _airborne(wind_gust_std_m_s=2.0, seed=3)
    g.command_position((0.0, 0.0, -10.0))
    errors = []
    _run(g, 30.0, check=lambda v: errors.append(np.linalg.norm(v.position_ned_m - (0, 0, -10))))
    assert max(errors) > 0.05  # gusts move it
    assert np.mean(errors) < 3.0  # but the controller keeps it close


@settings(max_examples=20, deadline=None)
@given(
    target=st.tuples(st.floats(-200, 200), st.floats(-200, 200), st.floats(-80, 5)),
    ff=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-5, 5)),
    use_velocity=st.booleans(),
)
def test_speed_never_exceeds_limits_and_never_below_ground(target, ff, use_velocity):
    m = _airborne(alt_m=5.0)
    p = m.params
    if use_velocity:
        m.command_velocity(ff)
    else:
        m.command_position(target, velocity_ff_ned_m_s=ff)

    def check(v):
        vel = v.velocity_ned_m_s
        assert math.hypot(vel[0], vel[1]) <= p.max_speed_h_m_s + 1e-9
        assert -vel[2] <= p.max_speed_up_m_s + 1e-9
        assert vel[2] <= p.max_speed_down_m_s + 1e-9
        assert v.position_ned_m[2] <= 0.0

    _run(m, 15.0, check=check)


def test_velocity_command_into_ground_lands_and_stays():
    m = _airborne(alt_m=3.0)
    m.command_velocity((1.0, 0.0, 1.5))
    depths = []
    _run(m, 10.0, check=lambda v: depths.append(v.position_ned_m[2]))
    assert max(depths) <= 0.0
    assert m.landed
    assert np.linalg.norm(m.velocity_ned_m_s) == 0.0


@pytest.mark.parametrize("alt_m", [3.0, 15.0])
def test_land_descends_and_sets_landed(alt_m):
    m = _airborne(alt_m=alt_m)
    m.command_position((5.0, 5.0, -alt_m))
    _run(m, 15.0)
    m.command_land()
    assert not m.landed
    sink = []
    _run(m, alt_m / m.params.land_speed_m_s + 10.0, check=lambda v: sink.append(v.velocity_ned_m_s[2]))
    assert m.landed and m.armed and not m.crashed
    assert m.position_ned_m[2] == 0.0
    np.testing.assert_allclose(m.position_ned_m[:2], (5.0, 5.0), atol=0.05)
    assert max(sink) <= max(m.params.max_speed_down_m_s, m.params.land_speed_m_s) + 1e-9


def test_hold_brakes_and_stops_near_current_position():
    m = _airborne()
    m.command_velocity((10.0, 0.0, 0.0))
    _run(m, 5.0)
    where = m.position_ned_m
    m.command_hold()
    _run(m, 15.0)
    assert np.linalg.norm(m.velocity_ned_m_s) < 0.05
    assert 0.0 < m.position_ned_m[0] - where[0] < 30.0


@pytest.mark.parametrize("how", ["crash", "disarm"])
def test_crash_or_disarm_in_air_falls_and_stops_on_ground(how):
    m = _airborne(alt_m=20.0)
    getattr(m, how)()
    assert not m.armed
    _run(m, 10.0)
    assert m.position_ned_m[2] == 0.0
    assert np.linalg.norm(m.velocity_ned_m_s) == 0.0
    assert m.landed and m.crashed  # a 20 m fall is a crash either way
    m.arm()
    m.command_takeoff(5.0)
    _run(m, 3.0)
    assert m.position_ned_m[2] == 0.0  # a crashed vehicle does not fly again


def test_battery_drains_in_proportion_to_flight_time():
    m = _airborne(alt_m=5.0, battery_flight_time_s=100.0)
    b0, v0 = m.battery_remaining, m.battery_voltage_v
    _run(m, 10.0)
    b1 = m.battery_remaining
    _run(m, 10.0)
    b2 = m.battery_remaining
    assert b0 - b1 == pytest.approx(0.1, rel=0.05)
    assert b1 - b2 == pytest.approx(b0 - b1, rel=1e-6)
    assert m.battery_voltage_v < v0


def test_empty_battery_in_air_falls():
    m = _airborne(alt_m=5.0)
    m.battery_remaining = 0.001
    _run(m, 10.0)
    assert m.battery_remaining == 0.0
    assert not m.armed and m.position_ned_m[2] == 0.0


@pytest.mark.parametrize("wind_gust_std_m_s,gps_noise_std_m", [(1.5, 0.0), (0.0, 0.5), (1.0, 1.0)])
def test_reproducible_with_a_seed(wind_gust_std_m_s, gps_noise_std_m):
    def trace(seed):
        m = _airborne(seed=seed, wind_gust_std_m_s=wind_gust_std_m_s, gps_noise_std_m=gps_noise_std_m)
        m.command_position((20.0, 0.0, -10.0))
        out = []
        _run(m, 5.0, check=lambda v: out.append(v.reported_position_ned_m()))
        return np.array(out)

    np.testing.assert_array_equal(trace(7), trace(7))
    assert not np.array_equal(trace(7), trace(8))


def test_reported_position_has_glitch_and_noise_true_position_does_not():
    m = _airborne(gps_noise_std_m=0.5, gps_noise_tau_s=0.005)
    truth = m.position_ned_m
    m.gps_glitch_ned_m = np.array([25.0, 0.0, 0.0])
    reports = []
    for _ in range(800):
        m.step(DT_S)
        reports.append(m.reported_position_ned_m() - m.position_ned_m)
    reports = np.array(reports)
    np.testing.assert_allclose(reports.mean(axis=0), (25.0, 0.0, 0.0), atol=0.1)
    assert reports.std(axis=0) == pytest.approx([0.5] * 3, rel=0.15)
    np.testing.assert_allclose(m.position_ned_m, truth, atol=0.01)  # hovering, unaffected


def test_gps_error_is_constant_within_a_step_and_correlated_across_steps():
    m = _airborne(gps_noise_std_m=1.0, gps_noise_tau_s=2.0)
    np.testing.assert_array_equal(m.reported_position_ned_m(), m.reported_position_ned_m())
    errs = []
    for _ in range(3000):
        m.step(DT_S)
        errs.append(m.reported_position_ned_m()[0] - m.position_ned_m[0])
    errs = np.array(errs)
    lag1 = np.corrcoef(errs[:-1], errs[1:])[0, 1]
    assert lag1 > 0.95  # exp(-0.02 / 2) = 0.99 in theory
    assert 0.3 < errs.std() < 2.0


def test_large_step_is_substepped_like_small_steps():
    a, b = _airborne(), _airborne()
    a.command_position((15.0, 5.0, -12.0))
    b.command_position((15.0, 5.0, -12.0))
    for _ in range(10):
        a.step(1.0)
    _run(b, 10.0)
    np.testing.assert_allclose(a.position_ned_m, b.position_ned_m, atol=0.05)


def test_yaw_turns_at_limited_rate_to_command():
    m = _airborne()
    m.command_position((0.0, 0.0, -10.0), yaw_rad=math.pi / 2)
    m.step(0.5)
    assert 0.0 < m.yaw_rad <= m.params.yaw_rate_max_rad_s * 0.5 + 1e-9
    _run(m, 3.0)
    assert m.yaw_rad == pytest.approx(math.pi / 2)


def test_position_estimate_ready_after_warmup():
    m = _vehicle(gps_warmup_s=2.0)
    assert not m.position_estimate_ready(1.9)
    assert m.position_estimate_ready(2.0)


@pytest.mark.parametrize("kw,match", [
    ({"max_speed_h_m_s": 0.0}, "max_speed_h_m_s"),
    ({"max_accel_m_s2": -1.0}, "max_accel_m_s2"),
    ({"wind_ned_m_s": (1.0, 2.0)}, "wind_ned_m_s"),
    ({"gps_noise_std_m": -0.1}, "gps_noise_std_m"),
    ({"battery_flight_time_s": math.inf}, "battery_flight_time_s"),
])
def test_params_reject_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        DynamicsParams(**kw)


def test_step_rejects_negative_dt():
    with pytest.raises(ValueError, match="dt_s"):
        _vehicle().step(-0.01)


@pytest.mark.parametrize("call,args,match", [
    ("command_position", ([1.0, math.nan, -3.0],), "position target"),
    ("command_position", ([1.0, 2.0],), "position target"),
    ("command_velocity", ([math.inf, 0.0, 0.0],), "velocity target"),
])
def test_commands_reject_non_finite_or_malformed(call, args, match):
    m = _airborne(alt_m=2.0)
    with pytest.raises(ValueError, match=match):
        getattr(m, call)(*args)
    _run(m, 1.0)
    assert np.all(np.isfinite(m.position_ned_m))
