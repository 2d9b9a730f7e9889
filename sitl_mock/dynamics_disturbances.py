"""Disturbances acting on the simulated multicopter: gusts, GPS noise and wind drag.

Used by :class:`sitl_mock.dynamics.Multicopter`:

* :class:`NormalBatch` -- standard normals from a seeded rng, drawn in batches (a draw per
  simulation step is slow);
* :func:`gauss_markov_step` -- one exact step of a 3-axis first-order Gauss-Markov process
  (the Ornstein-Uhlenbeck gusts and the correlated GPS error);
* :func:`wind_drag_step` -- the drag through which the wind pushes the vehicle, minus the
  autopilot's low-passed compensation of it (which rejects a constant wind in a few seconds).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["NormalBatch", "gauss_markov_step", "wind_drag_step"]

_NORMAL_BATCH = 3 * 256


class NormalBatch:
    """Standard normal draws from ``rng``, three at a time, fetched in batches.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws (reproducible with a seed).
    """

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self._buf: list[float] = []
        self._i = 0

    def next3(self) -> tuple[float, float, float]:
        """The next three standard normal draws."""
        i = self._i
        if i + 3 > len(self._buf):
            self._buf = self.rng.standard_normal(_NORMAL_BATCH).tolist()
            i = 0
        self._i = i + 3
        b = self._buf
        return b[i], b[i + 1], b[i + 2]


def gauss_markov_step(x, dt_s: float, tau_s: float, std: float,
                      normals: NormalBatch) -> tuple[float, float, float]:
    """One exact step of a 3-axis first-order Gauss-Markov process of stationary ``std``.

    Parameters
    ----------
    x : sequence of float
        Current value (3 axes).
    dt_s, tau_s : float
        Time step and correlation time.
    std : float
        Stationary standard deviation (per axis).
    normals : NormalBatch
        Source of the driving noise.

    Returns
    -------
    tuple of float
        The value after ``dt_s``.
    """
    phi = math.exp(-dt_s / tau_s)
    q = std * math.sqrt(1.0 - phi * phi)
    b0, b1, b2 = normals.next3()
    return x[0] * phi + q * b0, x[1] * phi + q * b1, x[2] * phi + q * b2


def wind_drag_step(wind_ned_m_s, comp_m_s2, drag_per_s: float, comp_tau_s: float,
                   dt_s: float) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Wind drag minus the autopilot's compensation, over one step.

    The compensation (an acceleration, NED m/s^2) first relaxes towards the drag
    ``drag_per_s * wind`` with time constant ``comp_tau_s``; the velocity then changes by the
    drag not yet compensated.

    Parameters
    ----------
    wind_ned_m_s : sequence of float
        Wind (constant + gusts), NED m/s.
    comp_m_s2 : sequence of float
        The autopilot's current compensation, NED m/s^2.
    drag_per_s, comp_tau_s, dt_s : float
        Drag coefficient, compensation time constant, time step.

    Returns
    -------
    comp_m_s2 : tuple of float
        The new compensation.
    dv_ned_m_s : tuple of float
        The change of velocity over the step.
    """
    wn, we, wd = wind_ned_m_s
    c0, c1, c2 = comp_m_s2
    b = min(dt_s / comp_tau_s, 1.0)
    k = drag_per_s
    c0 += (k * wn - c0) * b
    c1 += (k * we - c1) * b
    c2 += (k * wd - c2) * b
    return (c0, c1, c2), ((k * wn - c0) * dt_s, (k * we - c1) * dt_s, (k * wd - c2) * dt_s)
