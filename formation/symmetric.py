"""Symmetric Cylindrical formation of the paper, eq. (1).

Two staggered circles of ``n/2`` robots each on the sphere of radius ``D`` about the centre, at
polar angles ``theta_F`` and ``pi - theta_F`` with ``sin(theta_F) = sqrt(2/3)``. By construction
``sum_i r_i = 0`` and ``sum_i r_i r_i^T = n D^2 / 3 I`` (eq. 2) for every even ``n >= 4``.
"""
from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["THETA_F_RAD", "symmetric_cylinder", "symmetric_cylinder_dmin"]

#: Polar angle of the upper circle, ``sin(THETA_F_RAD) = sqrt(2/3)``.
THETA_F_RAD = math.asin(math.sqrt(2.0 / 3.0))


def _check_radius(radius):
    radius = float(radius)
    if not math.isfinite(radius) or radius <= 0.0:
        raise ValueError(f"radius must be a finite positive number, got {radius!r}")
    return radius


def symmetric_cylinder(n, radius=1.0):
    """Offsets of the Symmetric Cylindrical formation, paper eq. (1).

    Robot ``i`` (1-based) sits at polar angle ``theta_F`` if ``i`` is odd and ``pi - theta_F``
    if ``i`` is even, at azimuth ``phi_i = 2 pi i / n``, at distance ``radius`` from the centre.

    Parameters
    ----------
    n : int
        Number of robots; must be even and at least 4.
    radius : float, optional
        Formation radius ``D`` in metres (or any unit), positive.

    Returns
    -------
    numpy.ndarray
        Shape ``(n, 3)``: offsets from the formation centre (x, y, z). Row ``k`` is robot
        ``i = k + 1`` of the paper.

    Raises
    ------
    ValueError
        If ``n`` is not an integer, is odd, or is smaller than 4 (the two-circle construction
        needs at least two robots per circle to have ``M = n D^2/3 I``), or if ``radius`` is not
        a finite positive number.
    """
    if isinstance(n, bool) or not isinstance(n, numbers.Integral):
        raise ValueError(f"n must be an integer number of robots, got {n!r}")
    n = int(n)
    if n < 4:
        raise ValueError(f"symmetric cylinder needs n >= 4 robots (two per circle), got n={n}")
    if n % 2:
        raise ValueError(
            f"symmetric cylinder needs an even number of robots (n/2 per circle), got n={n}"
        )
    radius = _check_radius(radius)
    i = np.arange(1, n + 1)
    phi = 2.0 * math.pi * i / n
    # sin(theta_F) = sin(pi - theta_F) = sqrt(2/3); cos(theta_F) = -cos(pi - theta_F) = 1/sqrt(3),
    # written exactly rather than through THETA_F_RAD to keep eq. (2) exact to rounding.
    sin_t = math.sqrt(2.0 / 3.0)
    cos_t = np.where(i % 2 == 1, 1.0, -1.0) * math.sqrt(1.0 / 3.0)
    return radius * np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


def symmetric_cylinder_dmin(n, radius=1.0):
    """Closed-form minimum inter-robot distance of :func:`symmetric_cylinder`.

    Neighbours on the same circle (radius ``D sin(theta_F)``, azimuth step ``4 pi / n``) are
    ``2 D sin(theta_F) sin(2 pi / n)`` apart; the closest pair across the circles (height
    ``2 D cos(theta_F)``, azimuth step ``2 pi / n``) is
    ``sqrt((2 D sin(theta_F) sin(pi / n))^2 + (2 D cos(theta_F))^2)`` apart. ``d_min`` is the
    smaller of the two. (The paper prints ``2 D cos(theta_F) sin(2 pi / n)``, which swaps
    ``sin`` and ``cos`` of ``theta_F`` and is smaller than every actual distance.)

    Parameters
    ----------
    n : int
        Even number of robots, at least 4.
    radius : float, optional
        Formation radius ``D``.

    Returns
    -------
    float
        The minimum distance between two robots.
    """
    symmetric_cylinder(n, radius)  # validates
    s, c = math.sqrt(2.0 / 3.0), math.sqrt(1.0 / 3.0)
    same = 2.0 * radius * s * math.sin(2.0 * math.pi / n)
    across = math.hypot(2.0 * radius * s * math.sin(math.pi / n), 2.0 * radius * c)
    return min(same, across)
