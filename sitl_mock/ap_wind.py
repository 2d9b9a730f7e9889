"""The mock autopilot's wind estimate: the simulated world's wind plus an estimator's error.

A real autopilot estimates the wind in its EKF (PX4: EKF2 with drag or airspeed fusion, published
as WIND_COV; ArduPilot: the AHRS wind estimate, published as WIND). The mock reports

    estimate = true wind + error

where the true wind is the world's (the plume field's ``wind_from_deg`` / ``wind_speed_m_s`` when
the field has them, otherwise the dynamics' constant ``wind_ned_m_s``) and the error is a
horizontal first-order Gauss-Markov process per axis (north, east) of stationary standard
deviation :data:`ERROR_STD_M_S` (0.3 m/s) and correlation time :data:`ERROR_TAU_S` (30 s): an
EKF's wind states wander slowly, they do not jitter from one message to the next. For a 3 m/s
wind that is a speed error of ~0.3 m/s and a direction error of ~6 degrees (1 sigma); in a 1 m/s
wind the direction is ~17 degrees off, as a drag-based estimate would be. The vertical component
is the true one (zero for every field of the project).

:func:`wind_cov_fields` and :func:`wind_fields` give the two messages' values with the
firmware's conventions: WIND_COV ``wind_x`` / ``wind_y`` / ``wind_z`` are the air's velocity in
NED (a wind from the west, 270 degrees, at 3 m/s: ``(0, +3, 0)``); WIND ``direction`` is where
the wind comes FROM in degrees (ArduPilot sends ``degrees(atan2(-wind.y, -wind.x))``, in
-180..180: the same wind is ``-90``), ``speed`` the horizontal speed and ``speed_z`` the NED
down component.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["ERROR_STD_M_S", "ERROR_TAU_S", "WindEstimateModel", "wind_ned_from_met", "world_wind_ned_m_s",
           "wind_cov_fields", "wind_fields"]

#: stationary standard deviation of the estimate's error, per horizontal axis (m/s)
ERROR_STD_M_S = 0.3
#: correlation time of the estimate's error (s)
ERROR_TAU_S = 30.0


def wind_ned_from_met(from_deg: float, speed_m_s: float) -> tuple[float, float, float]:
    """The air's velocity (NED m/s) of a wind blowing FROM ``from_deg`` (clockwise from north).

    Parameters
    ----------
    from_deg : float
        Meteorological direction: where the wind comes from (270: a west wind).
    speed_m_s : float
        Horizontal speed.

    Returns
    -------
    tuple of float
        ``(north, east, down)``: a west wind of 3 m/s is ``(0, 3, 0)``.
    """
    rad = math.radians(from_deg)
    return -speed_m_s * math.cos(rad), -speed_m_s * math.sin(rad), 0.0


def _field_wind(field):
    """``(from_deg, speed_m_s)`` of a field's wind (plume, filament plume, a sum's first plume)."""
    for f in (field, getattr(field, "steady", None), *getattr(field, "parts", ())):
        if f is None:
            continue
        from_deg, speed = getattr(f, "wind_from_deg", None), getattr(f, "wind_speed_m_s", None)
        if from_deg is not None and speed is not None:
            return float(from_deg), float(speed)
        inner = getattr(f, "steady", None)
        if inner is not None and getattr(inner, "wind_from_deg", None) is not None:
            return float(inner.wind_from_deg), float(inner.wind_speed_m_s)
    return None


def world_wind_ned_m_s(field, dynamics_wind_ned_m_s) -> tuple[float, float, float]:
    """The simulated world's wind, NED m/s: the field's when it has one, else the dynamics'.

    Parameters
    ----------
    field : object or None
        The signal field (a plume has ``wind_from_deg`` and ``wind_speed_m_s``; a filament plume
        its ``steady`` plume's; a sum of fields its first plume's).
    dynamics_wind_ned_m_s : sequence of float
        ``DynamicsParams.wind_ned_m_s``, the constant wind the vehicles' drag feels.

    Returns
    -------
    tuple of float
        ``(north, east, down)`` m/s.
    """
    met = _field_wind(field) if field is not None else None
    if met is None:
        n, e, d = dynamics_wind_ned_m_s
        return float(n), float(e), float(d)
    return wind_ned_from_met(*met)


class WindEstimateModel:
    """One vehicle's wind estimate over simulated time.

    Parameters
    ----------
    true_wind_ned_m_s : sequence of float
        The world's wind (NED m/s), constant over the mission.
    rng : numpy.random.Generator
        Source of the estimate's error (its own stream: the dynamics' draws are unchanged).
    error_std_m_s, error_tau_s : float
        Stationary error per horizontal axis and its correlation time.
    """

    def __init__(self, true_wind_ned_m_s, rng: np.random.Generator, *,
                 error_std_m_s: float = ERROR_STD_M_S, error_tau_s: float = ERROR_TAU_S):
        wind = tuple(float(w) for w in true_wind_ned_m_s)
        if len(wind) != 3 or not all(math.isfinite(w) for w in wind):
            raise ValueError(f"true_wind_ned_m_s must be 3 finite numbers, got {true_wind_ned_m_s!r}")
        if not (error_std_m_s >= 0.0 and error_tau_s > 0.0):
            raise ValueError(f"error_std_m_s must be >= 0 and error_tau_s > 0, got "
                             f"{error_std_m_s!r}, {error_tau_s!r}")
        self.true_wind_ned_m_s = wind
        self.rng = rng
        self.error_std_m_s = float(error_std_m_s)
        self.error_tau_s = float(error_tau_s)
        self._err = tuple(self.error_std_m_s * rng.standard_normal(2))
        self._t_s: float | None = None

    def estimate_ned_m_s(self, t_s: float) -> tuple[float, float, float]:
        """The estimate at ``t_s`` (the error advanced exactly over the time since the last call)."""
        if self._t_s is not None and t_s > self._t_s:
            phi = math.exp(-(t_s - self._t_s) / self.error_tau_s)
            q = self.error_std_m_s * math.sqrt(1.0 - phi * phi)
            b = self.rng.standard_normal(2)
            self._err = (self._err[0] * phi + q * b[0], self._err[1] * phi + q * b[1])
        if self._t_s is None or t_s > self._t_s:
            self._t_s = t_s
        n, e, d = self.true_wind_ned_m_s
        return n + self._err[0], e + self._err[1], d


def wind_cov_fields(wind_ned_m_s, alt_amsl_m: float) -> dict:
    """WIND_COV's values (PX4) for an estimated wind.

    Parameters
    ----------
    wind_ned_m_s : sequence of float
        The estimate, the air's velocity in NED m/s.
    alt_amsl_m : float
        Altitude the estimate belongs to.

    Returns
    -------
    dict
        ``wind_x``, ``wind_y``, ``wind_z`` (NED m/s), ``var_horiz``, ``var_vert``, ``wind_alt``,
        ``horiz_accuracy``, ``vert_accuracy``. PX4 fills ``var_*`` with the EKF's variances and
        the accuracies with 0 (unknown); the mock reports its error variance.
    """
    n, e, d = wind_ned_m_s
    return {"wind_x": n, "wind_y": e, "wind_z": d, "var_horiz": 2.0 * ERROR_STD_M_S ** 2,
            "var_vert": 0.0, "wind_alt": alt_amsl_m, "horiz_accuracy": 0.0, "vert_accuracy": 0.0}


def wind_fields(wind_ned_m_s) -> dict:
    """WIND's values (ArduPilot) for an estimated wind.

    Parameters
    ----------
    wind_ned_m_s : sequence of float
        The estimate, the air's velocity in NED m/s.

    Returns
    -------
    dict
        ``direction`` (degrees the wind comes FROM, -180..180 as ArduPilot's
        ``degrees(atan2(-y, -x))``), ``speed`` (m/s: ArduPilot sends the vector's length, the
        horizontal speed when the vertical wind is zero), ``speed_z`` (NED down m/s).
    """
    n, e, d = wind_ned_m_s
    return {"direction": math.degrees(math.atan2(-e, -n)), "speed": math.sqrt(n * n + e * e + d * d),
            "speed_z": d}
