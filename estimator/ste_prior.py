"""The ``ste`` seeker's prior over the release (:class:`estimator.ste.SteSeeker`), pure numpy.

A particle is ``(east, north, up, log A, wind angle)`` (ENU metres; the angle the wind blows
toward, radians counter-clockwise from east). The prior about a centre ``c``:

* the release uniform in a vertical cylinder of radius ``radius_m`` and half-height ``height_m``
  about ``c`` (not below the ground: ``ground_alt_m + 0.1``); with ``upwind_half_rad``, only the
  sector of that half-angle up each particle's own wind from ``c`` (the formation starts downwind);
* with a search ``box`` (``[[e_min, n_min, u_min], [e_max, n_max, u_max]]``, ENU m: in missions the
  plan's geofence, the release is inside it or the mission cannot reach it), the release uniform in
  the cylinder (or sector) *inside* the box; where the sector and the box barely meet, the disk
  inside the box, and where even that fails, the box about ``c`` (every particle ends inside it);
* ``log A`` uniform in ``log_amp``; the wind angle from :func:`wind_angles`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["check_box", "draw_prior", "trial_boxes", "wind_angles"]

_ROUNDS = 40  # rejection rounds per proposal before the next, wider one


def check_box(box, trials: int | None = None, ground_alt_m: float | None = None) -> np.ndarray | None:
    """A search box as a float array ``(2, 3)`` (or ``(K, 2, 3)``, one per trial), checked; None: None.

    Raises
    ------
    ValueError
        Not finite, not of shape ``(2, 3)`` / ``(K, 2, 3)`` (``K`` = ``trials`` when given), a
        minimum not below its maximum, or (with ``ground_alt_m``) a top not above the ground + 0.1 m.
    """
    if box is None:
        return None
    b = np.asarray(box, dtype=float)
    if b.shape[-2:] != (2, 3) or b.ndim not in (2, 3) or (b.ndim == 3 and trials is not None and len(b) != trials):
        want = "(2, 3)" if trials is None else f"(2, 3) or ({trials}, 2, 3)"
        raise ValueError(f"prior_box_enu must have shape {want} ([[e_min, n_min, u_min], [e_max, n_max, u_max]] m), "
                         f"got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise ValueError("prior_box_enu must be finite")
    if not np.all(b[..., 0, :] < b[..., 1, :]):
        raise ValueError(f"prior_box_enu: each minimum must be below its maximum, got {b.tolist()}")
    if ground_alt_m is not None and not np.all(b[..., 1, 2] > ground_alt_m + 0.1):
        raise ValueError(f"prior_box_enu's top must be above the ground ({ground_alt_m:g} m) + 0.1 m, got {b.tolist()}")
    return b


def trial_boxes(box: np.ndarray | None, c: np.ndarray) -> np.ndarray | None:
    """The box of each of the ``K`` trials ``(K, 2, 3)`` for first centres ``c`` ``(K, 3)``; None without a box.

    Raises
    ------
    ValueError
        One box per trial for another number of trials, or a first centre outside its box.
    """
    if box is None:
        return None
    out = np.broadcast_to(check_box(box, len(c)), (len(c), 2, 3))
    inside = np.all((c >= out[:, 0]) & (c <= out[:, 1]), axis=1)
    if not inside.all():
        bad = int(np.flatnonzero(~inside)[0])
        raise ValueError(f"the first centre {np.round(c[bad], 2).tolist()} (trial {bad}) is outside "
                         f"prior_box_enu {out[bad].tolist()}")
    return out


def wind_angles(rng, shape, wind_from_deg: float | None, wind_std_rad: float) -> np.ndarray:
    """Wind angles (toward, radians from east): uniform without ``wind_from_deg``, else Gaussian about it."""
    if wind_from_deg is None:
        return rng.uniform(-np.pi, np.pi, shape)
    toward = np.pi / 2.0 - np.deg2rad(wind_from_deg + 180.0)  # met "from", clockwise from N -> ENU angle
    return toward + wind_std_rad * rng.standard_normal(shape)


def _in_box(xy: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(n, p)``: (east, north) ``xy`` ``(n, p, 2)`` inside the boxes ``(n, 2, 3)`` in plan view."""
    return np.all((xy >= box[:, None, 0, :2]) & (xy <= box[:, None, 1, :2]), axis=-1)


def _polar(rng, c: np.ndarray, theta: np.ndarray | None, radius_m: float, half: float | None,
           size) -> np.ndarray:
    """(east, north) ``size + (2,)`` uniform in the disk about ``c`` or, with ``theta`` and ``half``,
    in the sector up each wind ``theta``."""
    r = radius_m * np.sqrt(rng.uniform(0.0, 1.0, size))
    if half is not None:
        phi = theta + np.pi + rng.uniform(-half, half, size)
    else:
        phi = rng.uniform(0.0, 2.0 * np.pi, size)
    return c[..., :2] + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def _into_box(rng, xy: np.ndarray, c: np.ndarray, theta: np.ndarray, radius_m: float, half: float | None,
              box: np.ndarray) -> np.ndarray:
    """``xy`` ``(n, p, 2)`` with each point outside the box redrawn: the sector (or disk) inside the
    box by rejection, then the disk, then the box within the disk's square (module docstring)."""
    for stage_half in ([half] if half is not None else []) + [None]:
        for _ in range(_ROUNDS):
            k, j = np.nonzero(~_in_box(xy, box))
            if k.size == 0:
                return xy
            xy[k, j] = _polar(rng, c[k], theta[k, j] if stage_half is not None else None, radius_m, stage_half,
                              k.size)
    k, j = np.nonzero(~_in_box(xy, box))
    lo = np.maximum(box[k, 0, :2], c[k, :2] - radius_m)
    hi = np.minimum(box[k, 1, :2], c[k, :2] + radius_m)
    lo, hi = np.where(hi > lo, lo, box[k, 0, :2]), np.where(hi > lo, hi, box[k, 1, :2])
    xy[k, j] = lo + rng.uniform(0.0, 1.0, (k.size, 2)) * (hi - lo)
    return xy


def draw_prior(rng, c: np.ndarray, particles: int, *, radius_m: float, height_m: float, ground_alt_m: float,
               log_amp: tuple, wind_from_deg: float | None, wind_std_rad: float,
               upwind_half_rad: float | None = None, box: np.ndarray | None = None) -> np.ndarray:
    """Particles ``(n, particles, 5)`` from the prior (module docstring) about centres ``c`` ``(n, 3)``;
    ``box`` ``(n, 2, 3)`` or None (without a box the draws are those of the seeker before boxes)."""
    n, shape = c.shape[0], (c.shape[0], particles)
    sector = upwind_half_rad is not None
    r = radius_m * np.sqrt(rng.uniform(0.0, 1.0, shape))
    theta = wind_angles(rng, shape, wind_from_deg, wind_std_rad) if sector else None
    phi = theta + np.pi + rng.uniform(-upwind_half_rad, upwind_half_rad, shape) if sector else \
        rng.uniform(0.0, 2.0 * np.pi, shape)
    ground = ground_alt_m + 0.1
    z_lo = np.maximum(c[:, 2] - height_m, ground)
    z_hi = np.maximum(c[:, 2] + height_m, ground + 1.0)
    if box is not None:
        z_lo, z_hi = np.maximum(z_lo, box[:, 0, 2]), np.minimum(z_hi, box[:, 1, 2])
        z_hi = np.where(z_hi > z_lo, z_hi, np.maximum(box[:, 1, 2], z_lo + 1e-6))  # the cylinder misses the band
    z = rng.uniform(0.0, 1.0, shape) * (z_hi - z_lo)[:, None] + z_lo[:, None]
    log_a = rng.uniform(*log_amp, shape)
    theta = wind_angles(rng, shape, wind_from_deg, wind_std_rad) if theta is None else theta
    xy = c[:, None, :2] + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)
    if box is not None:
        xy = _into_box(rng, xy, c, theta, radius_m, upwind_half_rad, box)
    return np.concatenate([xy, z[..., None], log_a[..., None], theta[..., None]], axis=-1)
