"""Parameters of the simulated multicopter's dynamics and controller.

:class:`DynamicsParams` gathers the physical limits, controller gains, wind, GPS noise and
battery model of one simulated vehicle, and validates them on construction. It is kept apart
from :mod:`sitl_mock.dynamics` (import it from here) so that the parameter table can be
built and checked without the simulation itself.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["DynamicsParams", "GRAVITY_M_S2"]

GRAVITY_M_S2 = 9.80665


@dataclass
class DynamicsParams:
    """Physical and controller parameters of one simulated multicopter.

    Attributes
    ----------
    max_speed_h_m_s, max_speed_up_m_s, max_speed_down_m_s : float
        Horizontal, climb and descent speed limits.
    max_accel_m_s2 : float
        Acceleration limit of the controller (horizontal and vertical each).
    land_speed_m_s, takeoff_speed_m_s : float
        Final descent speed when landing, climb speed when taking off.
    wind_ned_m_s : tuple of float
        Constant wind, NED m/s.
    wind_gust_std_m_s : float
        Standard deviation of the gusts (per axis, Ornstein-Uhlenbeck).
    gps_noise_std_m : float
        Standard deviation of the reported position's error (per axis).
    gps_noise_tau_s : float
        Correlation time of that error (first-order Gauss-Markov, updated every step: the
        reports of one step agree with each other, as a real GPS fix does).
    battery_flight_time_s : float
        Hover time from full to empty.
    kp_pos_per_s, kp_vel_per_s : float
        Position and velocity loop gains.
    drag_per_s : float
        Linear drag coefficient through which the wind acts.
    wind_comp_tau_s : float
        Time constant of the autopilot's wind compensation.
    gust_tau_s : float
        Correlation time of the gusts.
    yaw_rate_max_rad_s : float
        Yaw rate limit.
    battery_cells : int
        LiPo cells in series (voltage model: 4.2 V full .. 3.5 V empty per cell, with sag).
    gps_warmup_s : float
        Time after boot before the position estimate is ready.
    """

    max_speed_h_m_s: float = 10.0
    max_speed_up_m_s: float = 3.0
    max_speed_down_m_s: float = 1.5
    max_accel_m_s2: float = 4.0
    land_speed_m_s: float = 0.7
    takeoff_speed_m_s: float = 1.5
    wind_ned_m_s: tuple = (0.0, 0.0, 0.0)
    wind_gust_std_m_s: float = 0.0
    gps_noise_std_m: float = 0.0
    gps_noise_tau_s: float = 1.0
    battery_flight_time_s: float = 1500.0
    kp_pos_per_s: float = 1.0
    kp_vel_per_s: float = 3.0
    drag_per_s: float = 0.3
    wind_comp_tau_s: float = 2.0
    gust_tau_s: float = 2.0
    yaw_rate_max_rad_s: float = math.radians(90.0)
    battery_cells: int = 4
    gps_warmup_s: float = 2.0

    def __post_init__(self):
        for name in ("max_speed_h_m_s", "max_speed_up_m_s", "max_speed_down_m_s", "max_accel_m_s2",
                     "land_speed_m_s", "takeoff_speed_m_s", "battery_flight_time_s", "kp_pos_per_s",
                     "kp_vel_per_s", "wind_comp_tau_s", "gust_tau_s", "gps_noise_tau_s", "yaw_rate_max_rad_s",
                     "wind_gust_std_m_s", "gps_noise_std_m", "drag_per_s", "gps_warmup_s"):
            v = float(getattr(self, name))
            may_be_zero = name in ("wind_gust_std_m_s", "gps_noise_std_m", "drag_per_s", "gps_warmup_s")
            if not (math.isfinite(v) and (v >= 0.0 if may_be_zero else v > 0.0)):
                kind = ">= 0 and finite" if may_be_zero else "a positive finite number"
                raise ValueError(f"DynamicsParams.{name} must be {kind}, got {v!r}")
        wind = tuple(float(w) for w in self.wind_ned_m_s)
        if len(wind) != 3 or not all(math.isfinite(w) for w in wind):
            raise ValueError(f"DynamicsParams.wind_ned_m_s must be 3 finite numbers, got {self.wind_ned_m_s!r}")
        self.wind_ned_m_s = wind
        if int(self.battery_cells) < 1:
            raise ValueError(f"DynamicsParams.battery_cells must be >= 1, got {self.battery_cells!r}")
