"""Simulated signal sensors and their zenoh publication (``docs/interfaces.md``, zenoh section).

:class:`SignalSensor` samples a field at a vehicle's true position and the sample's time, passes
it through the sensor's response (first-order lag of time constant ``time_constant_s``), adds its
own Gaussian noise and the sensor faults of a :class:`~sitl_mock.faults.FaultSet` (noise override,
stuck, bias, spikes), applies the detection floor (a value below ``detection_floor`` reads 0),
and builds the reading dict of schema ``swarmseek.sensor.v1``. Its encoding and zenoh publication
(``encode_reading``, ``sensor_key``, ``SensorPublisher``) are the senders' one copy,
:mod:`companion.sensor_wire`, which a real sensor's publisher uses too.
"""
from __future__ import annotations

import math

import numpy as np

from companion.sensor_wire import SENSOR_SCHEMA, check_sysid
from sitl_mock.faults import FaultSet
from sitl_mock.sensor_response import FirstOrderLag
from wire.fleet_name import check_fleet_name

__all__ = ["SignalSensor"]


def _finite(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


class SignalSensor:
    """One vehicle's sensor: samples the field with noise and faults, builds the payload.

    Parameters
    ----------
    field : sitl_mock.fields_gaussian.Field
        The signal field (mission frame, ENU m).
    noise_std : float
        Standard deviation of the additive Gaussian noise (signal units, >= 0); overridden by
        ``faults.sensor_noise_std`` when that is set.
    rng : numpy.random.Generator
        Source of noise and spikes (reproducible with a seed).
    faults : FaultSet
        The vehicle's faults, read at every sample (so they may change at run time).
    fleet : str
        Fleet name (goes into the key and the payload).
    sysid : int
        MAVLink system id of the vehicle carrying the sensor.

    Attributes
    ----------
    seq : int
        Sequence number of the next reading (starts at 0, +1 per reading).
    time_constant_s : float
        First-order lag of the response (0: instantaneous); see :meth:`set_response`.
    detection_floor : float
        Readings below it report 0.0 (0: no floor); see :meth:`set_response`.
    """

    def __init__(self, field, noise_std: float, rng, faults: FaultSet, fleet: str, sysid: int):
        self.field = field
        self.noise_std = _finite(noise_std, "noise_std")
        if self.noise_std < 0.0:
            raise ValueError(f"noise_std must be >= 0, got {noise_std!r}")
        self.rng = rng
        self.faults = faults
        self.fleet = check_fleet_name(fleet)
        self.sysid = check_sysid(sysid)
        self.seq = 0
        self._last_value: float | None = None
        self.detection_floor = 0.0
        self._lag = FirstOrderLag(0.0)

    def set_response(self, time_constant_s: float = 0.0, detection_floor: float = 0.0) -> None:
        """Set the sensor's response (both >= 0; 0 turns each off) and restart its lag.

        The lag is :class:`~sitl_mock.sensor_response.FirstOrderLag` (``tau dy/dt = c(t) - y``,
        first-order hold, exact; the first sample starts the sensor settled, ``y = c``). A
        sensor whose output (with noise, bias and spikes) is below ``detection_floor`` reports
        0.0 (a non-detect).

        Raises
        ------
        ValueError
            A value is negative or not finite.
        """
        floor = _finite(detection_floor, "detection_floor")
        if floor < 0.0:
            raise ValueError(f"detection_floor must be >= 0, got {detection_floor!r}")
        self._lag = FirstOrderLag(time_constant_s)
        self.detection_floor = floor

    @property
    def time_constant_s(self) -> float:
        """The response's time constant (0: instantaneous)."""
        return self._lag.time_constant_s

    def true_value(self, position_enu, t_s: float = 0.0) -> float:
        """Noise-free field value at ``position_enu`` (mission frame, ENU m) and time ``t_s``."""
        return float(self.field.value(np.asarray(position_enu, dtype=float), t_s))

    def sample(self, t_s: float, true_position_enu, lat_deg, lon_deg, alt_m,
               true_value: float | None = None) -> dict:
        """Take one reading.

        Parameters
        ----------
        t_s : float
            Sender's clock (simulated Unix seconds) when the sample is taken.
        true_position_enu : array_like, shape (3,)
            Where the sample is taken, mission frame ENU m (the field is evaluated there).
        lat_deg, lon_deg, alt_m : float
            The same position, geodetic (goes into the payload).
        true_value : float, optional
            :meth:`true_value` at that position and time when the caller has it already (the
            fleet evaluates the field once for all its vehicles); None: evaluated here.

        Returns
        -------
        dict
            The reading of schema ``swarmseek.sensor.v1``: schema, fleet, sysid, seq, time_s,
            lat_deg, lon_deg, alt_m, value. Faults: a stuck sensor repeats its last value;
            otherwise value = field + noise + bias (+ a spike of random sign).

        Raises
        ------
        ValueError
            If the time or a coordinate is not finite.
        """
        t = _finite(t_s, "t_s")
        pos = np.asarray(true_position_enu, dtype=float)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ValueError(f"true_position_enu must be 3 finite numbers, got {true_position_enu!r}")
        lat, lon, alt = _finite(lat_deg, "lat_deg"), _finite(lon_deg, "lon_deg"), _finite(alt_m, "alt_m")
        f = self.faults
        if f.sensor_stuck and self._last_value is not None:
            value = self._last_value
        else:
            std = self.noise_std if f.sensor_noise_std is None else float(f.sensor_noise_std)
            value = self._lag(t, self.true_value(pos, t) if true_value is None else float(true_value))
            if std > 0.0:
                value += std * float(self.rng.standard_normal())
            value += float(f.sensor_bias)
            if f.sensor_spike_prob > 0.0 and float(self.rng.random()) < f.sensor_spike_prob:
                value += float(f.sensor_spike_size) * (1.0 if self.rng.random() < 0.5 else -1.0)
            if self.detection_floor > 0.0 and value < self.detection_floor:
                value = 0.0
        self._last_value = value
        reading = {
            "schema": SENSOR_SCHEMA,
            "fleet": self.fleet,
            "sysid": self.sysid,
            "seq": self.seq,
            "time_s": t,
            "lat_deg": lat,
            "lon_deg": lon,
            "alt_m": alt,
            "value": value,
        }
        self.seq += 1
        return reading
