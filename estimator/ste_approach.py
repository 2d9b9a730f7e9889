"""The ``ste`` seeker's approach move: surge and cast, driven by the posterior (pure numpy).

While the posterior's 95 % region is wide (above ``approach_m``, :class:`estimator.ste.SteSeeker`),
myopic infotaxis is slow: it rewards places near the formation where the particles disagree,
steps half the region at most and, with a prior half downwind, drifts downwind after misses
(docs/seekers.md, "Round 4"). The approach move instead heads for the release the posterior
believes in, the way a moth does in an intermittent plume, in wind coordinates about the centre
(``a`` the posterior mean's distance up the wind, ``y`` across it, ``dz`` above):

* **Surge** (a vehicle read a hit within the last ``cast_after`` iterations): up the wind toward
  the mean's along-wind place less ``standoff_m``, but at most ``surge_m`` past where the last hit
  was read and never down the wind (a hit says the release is up the wind of it); across to the
  mean's line.
* **Cast** (no hit for ``cast_after`` iterations or more): across the wind about the mean's line,
  alternating sides, the sweep growing by ``cast_m`` every other iteration (at most
  ``surge_m``), and back down the wind to the last hit (or the mean) if the centre is past it.

The vertical move goes to the mean's height, at most ``vertical_m`` per iteration. The seeker
uses it only after a first hit (before it, infotaxis). Measured in docs/seekers.md ("Round 5"):
slower than infotaxis and less often successful; kept opt-in for the record.
"""
from __future__ import annotations

import numpy as np

__all__ = ["approach_centres", "upwind_unit"]


def upwind_unit(theta_rad: np.ndarray) -> np.ndarray:
    """Horizontal unit vectors ``(K, 3)`` up the wind from the wind's ENU heading ``theta_rad``
    (the direction the wind blows toward, counter-clockwise from east) ``(K,)``."""
    th = np.asarray(theta_rad, dtype=float)
    return np.stack([-np.cos(th), -np.sin(th), np.zeros_like(th)], axis=1)


def approach_centres(centre, mean, up, hit_enu, dry, *, surge_m: float, standoff_m: float = 0.0,
                     cast_m: float = 4.0, cast_after: int = 2, vertical_m: float = 2.0) -> np.ndarray:
    """Next centres ``(K, 3)`` of the approach (module docstring).

    Parameters
    ----------
    centre, mean : array_like, shape (K, 3)
        The formation's centre and the posterior mean release point (ENU, m).
    up : array_like, shape (K, 3)
        Horizontal unit vectors up the wind (:func:`upwind_unit`).
    hit_enu : array_like, shape (K, 3)
        Where the last hit was read (the mean of that iteration's hit readings; ENU, m).
    dry : array_like of int, shape (K,)
        Iterations since the last hit (0: a hit in this iteration).
    surge_m : float
        The surge goes at most this far up the wind of the last hit, and no move goes farther
        than this along or across the wind (m).
    standoff_m : float
        The surge stops this far down the wind of the mean.
    cast_m : float
        The cast's sweep grows by this much (m) every other dry iteration.
    cast_after : int
        Dry iterations before casting (>= 1).
    vertical_m : float
        The largest vertical move of an iteration (m).
    """
    c, m, u, h = (np.asarray(x, dtype=float) for x in (centre, mean, up, hit_enu))
    dry = np.asarray(dry, dtype=int)
    cross = np.stack([-u[:, 1], u[:, 0], np.zeros(len(u))], axis=1)
    d = m - c
    a, y = np.einsum("ki,ki->k", d, u), np.einsum("ki,ki->k", d, cross)
    a_hit = np.einsum("ki,ki->k", h - c, u)
    limit = np.minimum(a - standoff_m, a_hit + surge_m)  # not past the mean, nor far past the last hit
    along = np.clip(limit, 0.0, surge_m)  # surging: never down the wind
    across = np.clip(y, -surge_m, surge_m)
    casting = dry >= max(int(cast_after), 1)
    n = np.maximum(dry - max(int(cast_after), 1), 0)
    side = np.where(n % 2 == 0, 1.0, -1.0)
    sweep = np.minimum(cast_m * (1 + n // 2), surge_m)
    across = np.where(casting, np.clip(y + side * sweep, -surge_m, surge_m), across)
    along = np.where(casting, np.clip(np.minimum(a_hit, a), -surge_m, 0.0), along)  # back to the hits if past them
    dz = np.clip(d[:, 2], -vertical_m, vertical_m)
    return c + along[:, None] * u + across[:, None] * cross + dz[:, None] * np.array([0.0, 0.0, 1.0])
