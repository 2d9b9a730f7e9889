"""The autopilot's wind estimate: WIND_COV (PX4) and WIND (ArduPilot) decoded into one snapshot.

Conventions (checked against the MAVLink definitions and the firmware's senders):

* WIND_COV (message id 231, common): ``wind_x`` / ``wind_y`` / ``wind_z`` are the wind's velocity, NED m/s
  (the direction the air moves TO): a wind from the west (270 degrees) at 3 m/s is
  ``wind_x = 0, wind_y = +3``. PX4 fills them from EKF2's wind states.
* WIND (message id 168, ardupilotmega): ``direction`` is where the wind comes FROM, degrees (ArduPilot sends
  ``degrees(atan2(-wind.y, -wind.x))``, -180..180: the same wind is ``-90``), ``speed`` the
  length of the wind vector (m/s), ``speed_z`` its NED down component.

Both become a :class:`WindEstimate`: ``from_deg`` meteorological (0..360, clockwise from north,
where the wind comes from), ``speed_m_s`` horizontal. A frame whose values cannot be a wind
(NaN, infinite, a negative or absurd speed) raises :class:`ValueError` here and is counted as a
rejection by the telemetry handler (:meth:`mission.vehicle.state.VehicleTelemetry._reject`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MAX_WIND_M_S", "WindEstimate", "decode_wind_cov", "decode_wind", "wind_rates_hz", "wrap_360_deg"]

#: a wind estimate faster than this (m/s) is not believed (a corrupt or uninitialised value)
MAX_WIND_M_S = 100.0


@dataclass(frozen=True)
class WindEstimate:
    """One vehicle's latest wind estimate.

    Attributes
    ----------
    from_deg : float
        Where the wind comes FROM, degrees clockwise from north, in [0, 360) (270: a west wind).
    speed_m_s : float
        Horizontal speed, >= 0.
    down_m_s : float
        Vertical component, NED (positive: the air moves down).
    time_s : float
        Ground-station clock time it was received.
    message : str
        ``"WIND_COV"`` or ``"WIND"``.
    """

    from_deg: float
    speed_m_s: float
    down_m_s: float
    time_s: float
    message: str

    def toward_en_m_s(self) -> tuple[float, float]:
        """The wind's velocity ``(east, north)`` m/s (where the air moves to)."""
        rad = math.radians(self.from_deg)
        return -self.speed_m_s * math.sin(rad), -self.speed_m_s * math.cos(rad)


def wrap_360_deg(angle_deg: float) -> float:
    """``angle_deg`` in [0, 360) (``-1e-14 % 360`` is 360.0 in floating point: folded to 0)."""
    wrapped = angle_deg % 360.0
    return 0.0 if wrapped >= 360.0 else wrapped


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def decode_wind_cov(msg, time_s: float) -> WindEstimate:
    """The estimate in a WIND_COV message (PX4).

    Parameters
    ----------
    msg : pymavlink WIND_COV message
    time_s : float
        Receive time (ground-station clock).

    Returns
    -------
    WindEstimate

    Raises
    ------
    ValueError
        Non-finite or absurd (> :data:`MAX_WIND_M_S`) components.
    """
    n, e, d = float(msg.wind_x), float(msg.wind_y), float(msg.wind_z)
    if not _finite(n, e, d) or max(abs(n), abs(e), abs(d)) > MAX_WIND_M_S:
        raise ValueError(f"wind_x/y/z {n}, {e}, {d} m/s non-finite or absurd")
    speed = math.hypot(n, e)
    from_deg = wrap_360_deg(math.degrees(math.atan2(-e, -n))) if speed > 0.0 else 0.0
    return WindEstimate(from_deg, speed, d, time_s, "WIND_COV")


def decode_wind(msg, time_s: float) -> WindEstimate:
    """The estimate in a WIND message (ArduPilot).

    ``speed`` is the length of the 3D wind vector (ArduPilot's ``wind.length()``); the horizontal
    speed is ``sqrt(speed^2 - speed_z^2)``.

    Parameters
    ----------
    msg : pymavlink WIND message
    time_s : float
        Receive time (ground-station clock).

    Returns
    -------
    WindEstimate

    Raises
    ------
    ValueError
        Non-finite values, a negative or absurd speed, a direction outside -360..360 degrees.
    """
    direction, speed, down = float(msg.direction), float(msg.speed), float(msg.speed_z)
    if not _finite(direction, speed, down):
        raise ValueError(f"direction {direction} deg, speed {speed} m/s, speed_z {down} m/s non-finite")
    if not (0.0 <= speed <= MAX_WIND_M_S and abs(down) <= MAX_WIND_M_S and abs(direction) <= 360.0):
        raise ValueError(f"direction {direction} deg, speed {speed} m/s, speed_z {down} m/s out of range")
    horizontal = math.sqrt(max(speed * speed - down * down, 0.0))
    return WindEstimate(wrap_360_deg(direction), horizontal, down, time_s, "WIND")


def wind_rates_hz(flavour: str) -> dict[str, float]:
    """The wind message to ask for, per autopilot flavour (1 Hz; none for a generic autopilot).

    PX4 streams WIND_COV (0.5 Hz on a normal link, when EKF2 estimates the wind); ArduPilot sends
    WIND in its SRx_EXTRA3 group, off on a link until asked, and refuses WIND_COV.
    """
    if flavour == "px4":
        return {"WIND_COV": 1.0}
    if flavour == "ardupilot":
        return {"WIND": 1.0}
    return {}
