"""How much independent evidence each reading carries: the ``ste`` seeker's tempering by reading time.

A sensor read at 10 Hz inside an intermittent plume sees the same meander (the plume's
direction wanders on a correlation time ``tau``, 5 s in the simulated plume) for ``tau``
seconds: its readings there are nearly one observation, not ``10 tau``. Counting each as
independent makes the posterior overconfident; dropping all but one (the old thinning) throws
away hits. The rule here keeps every reading and shares the evidence:

* **per sensor, in time** (:func:`time_weights`): each reading's weight is
  ``min(1, max(|dt| / tau, ds / L_path))``, ``dt`` and ``ds`` the time and path distance to the
  previous reading of the *same sensor* (in this update or an earlier one); the first weighs 1.
  A sustained stream at any rate then carries one unit per ``tau`` per sensor; readings ``tau``
  or more apart weigh 1 each; a burst much shorter than ``tau`` weighs about 1 in total, and
  within it each reading, hit or miss, its share: the window's log-likelihood is its readings'
  mean, so the fraction of hits in it (what the hit model predicts) is kept, and no reading, a
  hit least of all, is dropped. (Sharing per outcome instead, hits apart from misses, gives a
  window with one short puff as much hit evidence as one in the plume's core: tried, it put the
  estimate 20 m off on the lock-step mission.) ``L_path`` lets a moving sensor decorrelate by
  distance too (the steady plume's model error is a function of place, about 1 m; for the
  intermittent plume infinite: time alone).
* **across sensors, at one instant** (:func:`shared_counts`): readings of other sensors taken within
  ``same_time_s`` and within about ``length_m`` see the same puff; reading ``i``'s weight is divided by
  ``n_i = 1 + sum_u max_j exp(-d_ij^2 / 2 L^2)`` over the other sensors ``u`` (their readings
  ``j`` within ``same_time_s``), as the position-only sharing of one update did before.
"""
from __future__ import annotations

import numpy as np

__all__ = ["time_weights", "shared_counts"]


def time_weights(times_s, positions, sensor_ids, last: dict, corr_time_s: float,
                 corr_path_m: float = np.inf) -> np.ndarray:
    """Per-reading weights in ``(0, 1]`` of one trial's readings by sensor and time.

    Parameters
    ----------
    times_s : ndarray, shape (M,)
        When each reading was taken, s.
    positions : ndarray, shape (M, 3)
        Where, ENU m.
    sensor_ids : ndarray, shape (M,)
        Which sensor took it (any hashable labels).
    last : dict
        ``sensor -> (time_s, position)`` of its newest reading seen before this call; updated in
        place (the state across updates).
    corr_time_s : float
        ``tau``; 0 gives every reading weight 1.
    corr_path_m : float
        ``L_path``: a reading this far along the path from the previous one weighs 1 (inf: time only).

    Returns
    -------
    ndarray, shape (M,)
        ``min(1, max(|dt| / tau, ds / L_path))`` to the previous reading of the same sensor
        (module docstring); 1 for the first.
    """
    t = np.asarray(times_s, dtype=float)
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    ids = np.asarray(sensor_ids)
    w = np.ones(t.shape[0])
    if corr_time_s <= 0 or t.size == 0:
        return w
    keys = ids.tolist()
    for key in dict.fromkeys(keys):
        idx = np.flatnonzero(ids == key)
        idx = idx[np.argsort(t[idx], kind="stable")]
        prev = last.get(key)
        pt = np.concatenate([[np.nan if prev is None else prev[0]], t[idx[:-1]]])
        pp = np.concatenate([np.full((1, 3), np.nan) if prev is None else np.reshape(prev[1], (1, 3)), p[idx[:-1]]])
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.maximum(np.abs(t[idx] - pt) / corr_time_s, np.linalg.norm(p[idx] - pp, axis=1) / corr_path_m)
        w[idx] = np.where(np.isnan(frac), 1.0, np.minimum(frac, 1.0))
        newest = idx[-1]
        if prev is None or t[newest] >= prev[0]:
            last[key] = (float(t[newest]), p[newest].copy())
    return w


def shared_counts(times_s, positions, sensor_ids, length_m: float, same_time_s: float) -> np.ndarray:
    """``n_i >= 1`` (module docstring): 1 plus, per other sensor, its nearest reading's
    ``exp(-d^2 / 2 length_m^2)`` among its readings within ``same_time_s`` of reading ``i``
    (0 when it has none); all 1 for ``length_m`` 0."""
    t = np.asarray(times_s, dtype=float)
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    ids = np.asarray(sensor_ids)
    n = np.ones(t.shape[0])
    if length_m <= 0 or t.size == 0:
        return n
    for u in np.unique(ids):
        mask = ids == u
        d2 = np.sum((p[:, None, :] - p[None, mask, :]) ** 2, axis=-1)
        near = np.abs(t[:, None] - t[None, mask]) <= same_time_s
        share = np.where(near, np.exp(-0.5 * d2 / length_m ** 2), 0.0).max(axis=1)
        n += np.where(mask, 0.0, share)
    return n
