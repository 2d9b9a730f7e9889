"""Control laws of the simulated multicopter's cascaded position / velocity controller.

Pure functions on plain floats (tiny numpy arrays are slower in the simulation's hot loop),
used by :class:`sitl_mock.dynamics.Multicopter`:

* :func:`sqrt_speed` and :func:`position_velocity_command` -- the position loop, a
  square-root controller as ArduPilot's ``sqrt_controller``;
* :func:`limit_velocity_command` -- the horizontal, climb and descent speed limits;
* :func:`velocity_loop_step` -- the first-order velocity loop, which moves the velocity
  towards the command without overshooting it and within the acceleration limit;
* :func:`finite3` and :func:`wrap_pi` -- input checking and angle wrapping.
"""
from __future__ import annotations

import math

__all__ = ["finite3", "wrap_pi", "sqrt_speed", "position_velocity_command", "limit_velocity_command",
           "velocity_loop_step"]


def finite3(values, what: str) -> tuple[float, float, float]:
    """Three finite floats from ``values``.

    Parameters
    ----------
    values : iterable of float
        The three numbers.
    what : str
        What they are, for the error message.

    Returns
    -------
    tuple of float

    Raises
    ------
    ValueError
        If ``values`` are not three numbers, or one of them is not finite.
    """
    try:
        a, b, c = (float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 3 numbers, got {values!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)):
        raise ValueError(f"{what} must be finite, got {values!r}")
    return a, b, c


def wrap_pi(a: float) -> float:
    """Angle ``a`` (rad) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def sqrt_speed(err_m: float, kp: float, accel: float) -> float:
    """Speed (>= 0) commanded for a distance ``err_m`` >= 0 (ArduPilot's sqrt_controller).

    Linear (``kp * err_m``) near the target, ``sqrt(2 accel d)`` far from it.
    """
    lin = accel / (kp * kp)
    if err_m <= lin:
        return kp * err_m
    return math.sqrt(2.0 * accel * (err_m - 0.5 * lin))


def position_velocity_command(en_m: float, ee_m: float, ed_m: float, kp_per_s: float,
                              accel_m_s2: float) -> tuple[float, float, float]:
    """Velocity (NED m/s) commanded by the position loop for a position error (NED m).

    The horizontal command points along the horizontal error, the vertical one along the
    vertical error; each has the square-root controller's speed (:func:`sqrt_speed`). No
    speed limit is applied here (see :func:`limit_velocity_command`).
    """
    dist_h = math.hypot(en_m, ee_m)
    if dist_h > 1e-9:
        s = sqrt_speed(dist_h, kp_per_s, accel_m_s2) / dist_h
        cn, ce = en_m * s, ee_m * s
    else:
        cn = ce = 0.0
    sd = sqrt_speed(abs(ed_m), kp_per_s, accel_m_s2)
    return cn, ce, (sd if ed_m > 0 else -sd)


def limit_velocity_command(cn: float, ce: float, cd: float, h_max_m_s: float, up_max_m_s: float,
                           down_max_m_s: float) -> tuple[float, float, float]:
    """Velocity command (NED m/s) clamped to the horizontal, climb and descent speed limits.

    The horizontal part is scaled down (its direction kept); the vertical part is clipped
    to ``[-up_max_m_s, down_max_m_s]`` (z is down).
    """
    sh = math.hypot(cn, ce)
    if sh > h_max_m_s:
        cn, ce = cn * h_max_m_s / sh, ce * h_max_m_s / sh
    return cn, ce, min(max(cd, -up_max_m_s), down_max_m_s)


def velocity_loop_step(vn: float, ve: float, vd: float, cn: float, ce: float, cd: float,
                       kp_vel_per_s: float, max_accel_m_s2: float,
                       dt_s: float) -> tuple[float, float, float]:
    """One step of the first-order velocity loop, towards the command and never past it.

    ``dv = (v_cmd - v) * min(kp_vel * dt, a_max * dt / |v_cmd - v|)``, horizontal and
    vertical separately.

    Parameters
    ----------
    vn, ve, vd : float
        Current velocity, NED m/s.
    cn, ce, cd : float
        Commanded velocity, NED m/s.
    kp_vel_per_s, max_accel_m_s2 : float
        Velocity loop gain and acceleration limit.
    dt_s : float
        Time step.

    Returns
    -------
    tuple of float
        The new velocity, NED m/s.
    """
    amax_dt = max_accel_m_s2 * dt_s
    kdt = min(kp_vel_per_s * dt_s, 1.0)
    dn, de = cn - vn, ce - ve
    dh = math.hypot(dn, de)
    f = kdt if dh * kdt <= amax_dt else amax_dt / dh
    vn, ve = vn + dn * f, ve + de * f
    dd = cd - vd
    f = kdt if abs(dd) * kdt <= amax_dt else amax_dt / abs(dd)
    return vn, ve, vd + dd * f
