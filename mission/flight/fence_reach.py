"""Whether a source the seek cannot centre on (the centre held at the fence) is still within reach.

The safety envelope keeps the formation centre inside the geofence shrunk by the formation radius
(:meth:`mission.safety.envelope.SafetyEnvelope.clamp_centre`), so a source closer to the fence than
the radius (a large formation over a low source: ``1.7 n^(1/3)`` m is 10.8 m at n = 254, above a
floor 2 m up) can never be the centre. It is still inside the formation: the vehicles surround it
and the seeker's readings locate it by interpolation. Such a seek has found the source; only a
source the formation cannot surround is "outside" (``stopped_at_fence``).
"""
from __future__ import annotations

import numpy as np

__all__ = ["source_in_reach"]


def source_in_reach(held_enu, requested_enu, own_estimate_enu, radius_m: float, tol_m: float,
                    fence) -> bool:
    """Whether the source is within reach of a formation whose centre is held at ``held_enu``.

    Parameters
    ----------
    held_enu : array_like, shape (3,)
        The centre the envelope allowed (on the shrunk fence).
    requested_enu : array_like, shape (3,)
        The centre the seeker asked for (its step towards the source, capped at ``gamma``).
    own_estimate_enu : array_like, shape (3,), or None
        The seeker's own estimate of the source (the ``model`` seeker's fitted maximum, the
        ``ste`` posterior's mean); None when the mission reports the mean of the held centres.
    radius_m : float
        The formation radius: a point within it of the centre is surrounded by the vehicles.
    tol_m : float
        The convergence tolerance: with no estimate of its own the mission reports the held
        centres, so the request must be within this of them.
    fence : mission.safety.fence.Geofence
        The geofence itself (not shrunk): a source outside it is out of reach.

    Returns
    -------
    bool
        True when the requested centre (and the seeker's estimate, if it has one) is inside the
        geofence and within ``radius_m`` of the held centre (``tol_m`` without an own estimate).
    """
    held = np.asarray(held_enu, dtype=float)
    requested = np.asarray(requested_enu, dtype=float)
    if not fence.contains(requested):
        return False
    short_m = float(np.linalg.norm(requested - held))
    if own_estimate_enu is None:
        return short_m <= tol_m
    own = np.asarray(own_estimate_enu, dtype=float)
    return bool(fence.contains(own)) and short_m <= radius_m and float(np.linalg.norm(own - held)) <= radius_m
