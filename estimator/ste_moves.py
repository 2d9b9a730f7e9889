"""Two opt-in move rules of the ``ste`` seeker: the bold move and information per second.

**The bold move** (``bold_sd_m``): straight to the posterior mean once the release's line is known.

Infotaxis (:meth:`estimator.ste.SteSeeker._next_centre`) steps at most ``max_step_m`` at a time
toward where the particles disagree most near the formation. On an intermittent plume the posterior
is soon a strip up the wind: the release's line (across the wind and in height) is known to a
metre or two, its distance up the wind to tens of metres, because the hit rate on the plume's axis
hardly depends on the distance (docs/seekers.md, round 6). Infotaxis then hovers down the wind of a
good estimate (rounds 4 and 9). On the line, though, a formation at the posterior mean splits the
strip: particles up the wind of it predict hits there, those down the wind of it predict none; the
readings there are a bisection of the distance up the wind.

:func:`bold_centres` replaces infotaxis's choice with the posterior mean wherever the posterior's
deviations across the wind and vertically are both at most ``line_sd_m`` and the mean is up the
wind of the centre by more than the deviation along it (the caller, as for every move, caps the
step and applies the safety envelope).

**Information per second** (``move_s_per_m``): infotaxis picks the candidate with the most expected
information per iteration, whatever the iteration costs; a stop-and-go iteration that stays costs
about 0.5 s (the formation settles and reads), one that moves 4 m about 2.7 s (docs/seekers.md, the
time model). :func:`information_rate` divides each candidate's information by
``STOP_S + move_s_per_m * max(|d|, VERTICAL_RATIO |d_up|)`` (``d`` the move; the vertical part
counts ``VERTICAL_RATIO`` times: the plan's vertical speed limit is a third of the horizontal one).
"""
from __future__ import annotations

import numpy as np

__all__ = ["across_wind", "bold_centres", "line_known", "information_rate", "STOP_S", "VERTICAL_RATIO"]

#: Mission time of an iteration that does not move, s (the stop-and-go time model's floor)
STOP_S = 0.5
#: A metre up or down costs this many metres across (the plan's 3 m/s horizontal, 1 m/s vertical limits)
VERTICAL_RATIO = 3.0


def information_rate(info: np.ndarray, centre_enu: np.ndarray, cand_enu: np.ndarray,
                     move_s_per_m: float | None) -> np.ndarray:
    """Each candidate's expected information per second of mission time ``(K, C)``.

    Parameters
    ----------
    info : ndarray, shape (K, C)
        Each candidate's expected information (nats).
    centre_enu : ndarray, shape (K, 3)
        The current centres, ENU m.
    cand_enu : ndarray, shape (K, C, 3)
        The candidate centres, ENU m.
    move_s_per_m : float or None
        Seconds of mission time per metre moved (module docstring); None: ``info`` unchanged.

    Returns
    -------
    ndarray, shape (K, C)
    """
    if move_s_per_m is None:
        return info
    d = cand_enu - centre_enu[:, None, :]
    dist = np.maximum(np.linalg.norm(d, axis=-1), VERTICAL_RATIO * np.abs(d[..., 2]))
    return info / (STOP_S + move_s_per_m * dist)


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


def bold_centres(centre_enu: np.ndarray, best_enu: np.ndarray, mean_enu: np.ndarray, up: np.ndarray,
                 spreads: tuple, line_sd_m: float | None) -> np.ndarray:
    """Next centres ``(K, 3)``: the posterior mean where the line is known (:func:`line_known`) and
    the mean is up the wind of the centre by more than the posterior's deviation along the wind;
    else infotaxis's choice.

    Only up the wind: a formation sent to the mean of a posterior whose line is a metre or two off
    reads misses there, which push the mean down the wind, where the formation follows it without
    ever reading the plume again (measured: docs/seekers.md, round 9). Near or up the wind of the
    mean, infotaxis (whose casts find the line) moves.

    Parameters
    ----------
    centre_enu : ndarray, shape (K, 3)
        The current centres, ENU m.
    best_enu : ndarray, shape (K, 3)
        Infotaxis's next centres, ENU m.
    mean_enu : ndarray, shape (K, 3)
        The posterior mean release points, ENU m.
    up : ndarray, shape (K, 3)
        Horizontal unit vectors up the posterior's mean wind.
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
    ahead = np.einsum("ki,ki->k", mean_enu - centre_enu, up) > np.asarray(spreads[0])
    return np.where((line_known(spreads, line_sd_m) & ahead)[:, None], mean_enu, best_enu)
