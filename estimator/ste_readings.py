"""The ``ste`` seeker's readings by sensor and time: checks and per-sensor selections.

:meth:`estimator.ste.SteSeeker.propose` takes, with the readings, when each was taken and by
which sensor; these helpers check those arrays and pick each sensor's first reading of an update
(the per-update tempering's input) or its newest (where the formation is, for the move).
"""
from __future__ import annotations

import numpy as np

__all__ = ["reading_times", "first_per_sensor", "formation_points"]


def reading_times(times_s, sensor_ids, shape) -> tuple:
    """``(times (K, M), sensor ids (K, M))`` checked, or ``(None, None)`` without times.

    Parameters
    ----------
    times_s : array_like or None
        When each reading was taken, s (reshaped to ``shape``); None: no times.
    sensor_ids : array_like or None
        Which sensor took each reading, shape ``shape``; None: column ``m`` is sensor ``m``.
    shape : tuple of int
        The readings' shape ``(K, M)``.

    Raises
    ------
    ValueError
        A time that is not finite, or sensor ids of another shape.
    """
    if times_s is None:
        return None, None
    t = np.asarray(times_s, dtype=float).reshape(shape)
    if not np.all(np.isfinite(t)):
        raise ValueError("times_s must be finite")
    ids = np.broadcast_to(np.arange(shape[1]), shape) if sensor_ids is None else np.asarray(sensor_ids)
    if ids.shape != shape:
        raise ValueError(f"sensor_ids must have the readings' shape {shape}, got {ids.shape}")
    return t, ids


def first_per_sensor(p: np.ndarray, v: np.ndarray, t: np.ndarray, ids: np.ndarray) -> tuple:
    """Each sensor's earliest reading of the update (the same sensors in every trial), without
    times: ``(positions, values, None, None)``; the per-update tempering takes them.

    Parameters
    ----------
    p : ndarray, shape (K, M, 3)
        The readings' positions, ENU m.
    v : ndarray, shape (K, M)
        The readings.
    t, ids : ndarray, shape (K, M)
        Their times (s) and sensors (:func:`reading_times`).

    Raises
    ------
    ValueError
        The trials' updates hold readings of different numbers of sensors.
    """
    keep = []
    for k in range(p.shape[0]):
        order = np.lexsort((t[k], ids[k]))
        keep.append(order[np.r_[True, ids[k][order][1:] != ids[k][order][:-1]]])
    if len({len(x) for x in keep}) != 1:
        raise ValueError("every trial's update needs readings of the same number of sensors")
    idx = np.sort(np.stack(keep), axis=1)
    return np.take_along_axis(p, idx[..., None], axis=1), np.take_along_axis(v, idx, axis=1), None, None


def formation_points(p: np.ndarray, t, ids) -> np.ndarray:
    """Where the formation's vehicles are for the move's information: the readings' positions,
    or with times each sensor's newest reading (the same sensors in every trial, else all readings).

    Parameters
    ----------
    p : ndarray, shape (K, M, 3)
        The readings' positions, ENU m.
    t, ids : ndarray, shape (K, M), or None
        Their times (s) and sensors (:func:`reading_times`); None: no times.

    Returns
    -------
    ndarray, shape (K, N, 3)
    """
    if t is None:
        return p
    last = []
    for k in range(p.shape[0]):
        order = np.lexsort((t[k], ids[k]))
        newest = order[np.r_[ids[k][order][1:] != ids[k][order][:-1], True]]
        last.append(p[k, newest])
    return np.stack(last) if len({len(x) for x in last}) == 1 else p
