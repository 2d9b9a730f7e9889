"""The ``ste`` seeker's bold move: straight to the posterior mean once the release's line is known.

Infotaxis (:meth:`estimator.ste.SteSeeker._next_centre`) steps at most ``max_step_m`` at a time
toward where the particles disagree most near the formation. On an intermittent plume the posterior
is soon a strip up the wind: the release's line (across the wind and in height) is known to a
metre or two, its distance up the wind to tens of metres, because the hit rate on the plume's axis
hardly depends on the distance (docs/seekers.md, round 6). Infotaxis then hovers down the wind of a
good estimate (rounds 4 and 9). On the line, though, a formation at the posterior mean splits the
strip: particles up the wind of it predict hits there, those down the wind of it predict none; the
readings there are a bisection of the distance up the wind.

:func:`bold_centres` replaces infotaxis's choice with the posterior mean wherever the posterior's
deviations across the wind and vertically are both at most ``line_sd_m`` (the caller, as for every
move, caps the step and applies the safety envelope).
"""
from __future__ import annotations

import numpy as np

__all__ = ["across_wind", "bold_centres", "line_known"]


def across_wind(up: np.ndarray) -> np.ndarray:
    """Horizontal unit vectors ``(K, 3)`` across the wind (to the left of ``up``, looking up it).

    Parameters
    ----------
    up : ndarray, shape (K, 3)
        Horizontal unit vectors up the wind.

    Returns
    -------
    ndarray, shape (K, 3)
    """
    return np.stack([-up[:, 1], up[:, 0], np.zeros(len(up))], axis=1)


def line_known(spreads: tuple, line_sd_m: float) -> np.ndarray:
    """Where the release's line is known ``(K,)``: both deviations across the wind and vertically
    at most ``line_sd_m``.

    Parameters
    ----------
    spreads : tuple of ndarray
        The posterior's deviations ``(K,)`` of the release up the wind, across it and vertically, m
        (:meth:`estimator.ste.SteSeeker._spreads`).
    line_sd_m : float
        The largest deviation across the wind and vertically of a known line, m.

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    _, across, vertical = spreads
    return (np.asarray(across) <= line_sd_m) & (np.asarray(vertical) <= line_sd_m)


def bold_centres(best_enu: np.ndarray, mean_enu: np.ndarray, spreads: tuple, line_sd_m: float | None) -> np.ndarray:
    """Next centres ``(K, 3)``: the posterior mean where the line is known (:func:`line_known`), else
    infotaxis's choice.

    Parameters
    ----------
    best_enu : ndarray, shape (K, 3)
        Infotaxis's (or the exploit rule's) next centres, ENU m.
    mean_enu : ndarray, shape (K, 3)
        The posterior mean release points, ENU m.
    spreads : tuple of ndarray
        The posterior's deviations ``(K,)`` up the wind, across it and vertically, m.
    line_sd_m : float or None
        :func:`line_known`'s bound; None: off (``best_enu`` unchanged).

    Returns
    -------
    ndarray, shape (K, 3)
    """
    if line_sd_m is None:
        return best_enu
    return np.where(line_known(spreads, line_sd_m)[:, None], mean_enu, best_enu)
