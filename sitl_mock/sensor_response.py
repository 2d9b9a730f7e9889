"""A sensor's dynamic response: a first-order lag of the concentration it is exposed to.

Real gas and heat sensors do not read the concentration at their position instantly: a
photo-ionisation or metal-oxide sensor responds as a first-order system,
``tau dy/dt = c(t) - y`` (``tau`` its time constant; after a step the output reaches
``1 - 1/e``, 63 %, of it in ``tau``). :class:`FirstOrderLag` integrates it exactly between
samples, the concentration taken linear between two samples (first-order hold).
"""
from __future__ import annotations

import math

__all__ = ["FirstOrderLag", "set_fleet_response"]


class FirstOrderLag:
    """``tau dy/dt = c(t) - y`` sampled at increasing times (``tau = 0``: ``y = c``).

    Parameters
    ----------
    time_constant_s : float
        ``tau`` (>= 0, finite).

    Raises
    ------
    ValueError
        Negative or non-finite time constant.
    """

    def __init__(self, time_constant_s: float = 0.0):
        tau = float(time_constant_s)
        if not (math.isfinite(tau) and tau >= 0.0):
            raise ValueError(f"time_constant_s must be a finite number >= 0, got {time_constant_s!r}")
        self.time_constant_s = tau
        self._state: tuple[float, float, float] | None = None  # (time, input, output) of the last sample

    def reset(self) -> None:
        """Forget the past: the next sample starts the sensor settled (``y = c``)."""
        self._state = None

    def __call__(self, t_s: float, concentration: float) -> float:
        """The output at ``t_s`` for the input ``concentration`` sampled then.

        The first sample returns ``concentration`` (settled sensor); a sample at or before the
        previous one's time returns the previous output.
        """
        tau = self.time_constant_s
        if tau <= 0.0:
            return concentration
        if self._state is None:
            y = concentration
        elif t_s <= self._state[0]:
            y = self._state[2]
        else:
            t0, c0, y0 = self._state
            dt = t_s - t0
            alpha = math.exp(-dt / tau)
            rate = (concentration - c0) / dt  # the input's ramp between the two samples
            y = concentration - rate * tau * (1.0 - alpha) + alpha * (y0 - c0)
        self._state = (t_s, concentration, y)
        return y


def set_fleet_response(fleet, time_constant_s: float = 0.0, detection_floor: float = 0.0) -> int:
    """:meth:`~sitl_mock.sensor.SignalSensor.set_response` on every sensor of a mock fleet.

    Returns
    -------
    int
        Sensors set (vehicles without a sensor are skipped).

    Raises
    ------
    ValueError
        A value is negative or not finite.
    """
    count = 0
    for v in fleet.vehicles:
        if v.sensor is not None:
            v.sensor.set_response(time_constant_s, detection_floor)
            count += 1
    return count
