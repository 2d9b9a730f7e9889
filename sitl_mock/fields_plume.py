"""A wind-advected steady Gaussian plume with ground reflection (the simulated world's gas plume).

The classic steady-state Gaussian plume of a continuous point release (e.g. Seinfeld & Pandis,
*Atmospheric Chemistry and Physics*, 3rd ed., 2016, ch. 18; Turner, *Workbook of Atmospheric
Dispersion Estimates*, 1994), in the wind frame (``x`` downwind of the release point, ``y``
crosswind to the left, ``z`` up from the ground):

``C(x, y, z) = Q / (2 pi U s_y s_z) exp(-y^2 / (2 s_y^2))
[exp(-(z - H)^2 / (2 s_z^2)) + r exp(-(z + H)^2 / (2 s_z^2))]``

with ``Q`` the emission rate, ``U`` the wind speed, ``H`` the release height above the ground,
``r = 1`` with ground reflection (the image source at ``-H``: on the ground ``z = 0`` both terms
are equal, so reflection exactly doubles the ground-level value) and ``r = 0`` without.

The spreads grow downwind as the Briggs (1973) open-country fits of the Pasquill-Gifford curves
(stability classes A, very unstable, to F, very stable; Seinfeld & Pandis table 18.3),
``sigma_y(x) = a_y x / sqrt(1 + 1e-4 x)`` and ``sigma_z(x)`` per class, combined with a source
radius ``s0`` so that the plume is finite at the release: ``s_y = sqrt(s0^2 + sigma_y(x)^2)``
(same for ``z``). Upwind (``x < 0``), where the textbook plume is undefined, the release blob's
value at ``x = 0`` decays as ``exp(-x^2 / (2 s0^2))``: value and slope are continuous at
``x = 0`` and the plume is ~0 a few ``s0`` upwind (only the background remains). The field is
that plume plus a constant ``background`` (> 0 by default, so it is positive everywhere).

Which point is "the source": :meth:`GaussianPlume.source_enu` is the **release point**. At the
release height (``H`` a few ``s0`` above the ground) the field's maximum is the release point
itself: along the centreline ``C`` falls as ``1 / (s_y s_z)`` downwind and as the upwind tail.
Elsewhere it is not: the ground-level maximum (:meth:`GaussianPlume.peak_enu` at ``alt_m = 0``)
lies downwind, where the plume has spread down to the ground. A gradient ascent climbs toward
the centreline (the crosswind gradient dominates off the centreline) and then up the centreline
to the release point; it cannot go anywhere from outside the plume, where the field is flat
(upwind, or many ``s_y`` crosswind): there the gradient is below any sensor noise.
"""
from __future__ import annotations

import numpy as np

from estimator.ste_model import BRIGGS_RURAL

__all__ = ["STABILITY_CLASSES", "briggs_sigmas", "GaussianPlume"]

#: The Pasquill-Gifford classes, with Briggs (1973) open-country coefficients (one table, the
#: dispersion model's: :data:`estimator.ste_model.BRIGGS_RURAL`).
STABILITY_CLASSES = tuple(BRIGGS_RURAL)
_GRAD_STEP_M = 1e-3


def briggs_sigmas(x_m, stability: str = "C"):
    """Briggs open-country ``(sigma_y, sigma_z)`` in metres at downwind distances ``x_m`` (>= 0).

    Raises
    ------
    ValueError
        Unknown stability class.
    """
    try:
        ay, by, az, bz, pz = BRIGGS_RURAL[stability]
    except KeyError:
        raise ValueError(f"unknown stability class {stability!r}; known: {', '.join(STABILITY_CLASSES)}") from None
    x = np.maximum(np.asarray(x_m, dtype=float), 0.0)
    return ay * x / np.sqrt(1.0 + by * x), az * x * (1.0 + bz * x) ** pz


def _positive(value, name: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v < 0.0 or (v == 0.0 and not allow_zero):
        raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


class GaussianPlume:
    """Steady Gaussian plume of one continuous release, advected by a uniform wind.

    Parameters
    ----------
    source : array_like, shape (3,)
        Release point, ENU metres in the mission frame (its ``U`` is the release height above
        the mission origin).
    wind_from_deg : float
        Direction the wind blows FROM, degrees clockwise from north (meteorological: 270 is a
        west wind, blowing toward the east).
    wind_speed_m_s : float
        Wind speed ``U`` (> 0).
    stability : str
        Pasquill-Gifford class ``"A"`` .. ``"F"`` of the Briggs spreads.
    source_radius_m : float
        ``s0`` (> 0): spread at the release point.
    emission_rate : float or None
        ``Q`` in signal units x m^3/s; None: ``2 pi U s0^2`` (the plume is 1 at the release
        point, without the reflected term).
    ground_reflection : bool
        Add the image source below the ground.
    background : float
        Constant added everywhere (>= 0; default 1e-4, so the field is positive everywhere).
    ground_alt_m : float
        Height of the ground in the mission frame's ``U`` (the release must not be below it).

    Raises
    ------
    ValueError
        A parameter is out of range.
    """

    time_dependent = False

    def __init__(self, source=(0.0, 0.0, 0.0), *, wind_from_deg: float = 270.0,
                 wind_speed_m_s: float = 2.0, stability: str = "C", source_radius_m: float = 1.0,
                 emission_rate: float | None = None, ground_reflection: bool = True,
                 background: float = 1e-4, ground_alt_m: float = 0.0):
        src = np.asarray(source, dtype=float).reshape(-1)
        if src.shape != (3,) or not np.all(np.isfinite(src)):
            raise ValueError(f"source must be 3 finite numbers (E, N, U m), got {source!r}")
        if not np.isfinite(float(wind_from_deg)):
            raise ValueError(f"wind_from_deg must be finite, got {wind_from_deg!r}")
        briggs_sigmas(0.0, stability)  # checks the class
        self.release = src
        self.wind_from_deg = float(wind_from_deg) % 360.0
        self.wind_speed_m_s = _positive(wind_speed_m_s, "wind_speed_m_s")
        self.stability = stability
        self.source_radius_m = _positive(source_radius_m, "source_radius_m")
        s0 = self.source_radius_m
        q = 2.0 * np.pi * self.wind_speed_m_s * s0 ** 2 if emission_rate is None else emission_rate
        self.emission_rate = _positive(q, "emission_rate")
        self.ground_reflection = bool(ground_reflection)
        self.background = _positive(background, "background", allow_zero=True)
        self.ground_alt_m = float(ground_alt_m)
        if not np.isfinite(self.ground_alt_m) or src[2] < self.ground_alt_m:
            raise ValueError(f"the release ({src[2]} m up) must not be below the ground ({ground_alt_m!r} m)")
        rad = np.deg2rad(self.wind_from_deg)
        self.downwind_en = np.array([-np.sin(rad), -np.cos(rad)])  # unit vector (east, north)

    def __repr__(self) -> str:
        return (f"GaussianPlume(source={self.release.tolist()}, wind_from_deg={self.wind_from_deg:g}, "
                f"wind_speed_m_s={self.wind_speed_m_s:g}, stability={self.stability!r}, "
                f"source_radius_m={self.source_radius_m:g}, emission_rate={self.emission_rate:g}, "
                f"ground_reflection={self.ground_reflection}, background={self.background:g})")

    # ------------------------------------------------------------------ frames
    def wind_frame(self, points):
        """``(x, y, z)``: downwind and crosswind (left) distances from the release, height above
        the ground; each of shape ``points.shape[:-1]``."""
        p = np.asarray(points, dtype=float)
        de, dn = p[..., 0] - self.release[0], p[..., 1] - self.release[1]
        ue, un = self.downwind_en
        return de * ue + dn * un, -de * un + dn * ue, p[..., 2] - self.ground_alt_m

    def to_enu(self, x, y, z):
        """Inverse of :meth:`wind_frame`: ENU points of shape ``(..., 3)``."""
        ue, un = self.downwind_en
        x, y, z = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, y, z)))
        return np.stack([self.release[0] + x * ue - y * un, self.release[1] + x * un + y * ue,
                         z + self.ground_alt_m], axis=-1)

    @property
    def release_height_m(self) -> float:
        """``H``, the release's height above the ground."""
        return float(self.release[2] - self.ground_alt_m)

    def spreads(self, x_m):
        """``(s_y, s_z)`` at downwind distance ``x_m``: Briggs spreads with the source radius."""
        sy, sz = briggs_sigmas(x_m, self.stability)
        s0 = self.source_radius_m
        return np.sqrt(s0 * s0 + sy * sy), np.sqrt(s0 * s0 + sz * sz)

    # ------------------------------------------------------------------ the field
    def plume(self, x, y, z):
        """The plume without background in wind-frame coordinates (arrays, broadcast)."""
        x = np.asarray(x, dtype=float)
        sy, sz = self.spreads(x)
        h = self.release_height_m
        vert = np.exp(-0.5 * ((z - h) / sz) ** 2)
        if self.ground_reflection:
            vert = vert + np.exp(-0.5 * ((z + h) / sz) ** 2)
        upwind = np.exp(-0.5 * (np.minimum(x, 0.0) / self.source_radius_m) ** 2)
        amp = self.emission_rate / (2.0 * np.pi * self.wind_speed_m_s * sy * sz)
        return amp * np.exp(-0.5 * (y / sy) ** 2) * vert * upwind

    def value(self, points, t_s=0.0):
        """Concentration at ``points`` (..., 3) ENU m, shape (...); ``t_s`` ignored (steady)."""
        return self.plume(*self.wind_frame(points)) + self.background

    def gradient(self, points, t_s=0.0):
        """Gradient by central differences (step 1 mm), shape (..., 3)."""
        p = np.asarray(points, dtype=float)
        g = np.empty(p.shape)
        for i in range(3):
            e = np.zeros(3)
            e[i] = _GRAD_STEP_M
            g[..., i] = (self.value(p + e) - self.value(p - e)) / (2.0 * _GRAD_STEP_M)
        return g

    def release_enu(self) -> np.ndarray:
        """The release point (what "finding the source" means), ENU m."""
        return self.release.copy()

    def source_enu(self) -> np.ndarray:
        """Same as :meth:`release_enu`."""
        return self.release.copy()

    def peak_enu(self, alt_m: float | None = None, max_range_m: float = 500.0) -> np.ndarray:
        """Maximum of the field along the centreline at altitude ``alt_m`` (mission ``U``;
        default the release height), ENU m: searched on a 1 cm grid from 3 ``s0`` upwind to
        ``max_range_m`` downwind (refined around the best grid point)."""
        z = self.release_height_m if alt_m is None else float(alt_m) - self.ground_alt_m
        x = np.linspace(-3.0 * self.source_radius_m, max_range_m, 20001)
        best = x[int(np.argmax(self.plume(x, 0.0, z)))]
        fine = np.linspace(best - 0.05, best + 0.05, 1001)
        best = fine[int(np.argmax(self.plume(fine, 0.0, z)))]
        return self.to_enu(best, 0.0, z)

    def newton_gain(self) -> float:
        """Step gain ``eps = s0^2 / C0`` (``C0`` the release-point value): the Newton step
        across the centreline near the release, where the plume is ``C0 exp(-y^2 / (2 s0^2))``
        (``1 / (2 A lambda)`` with ``lambda = 1 / (2 s0^2)``)."""
        c0 = float(self.plume(0.0, 0.0, self.release_height_m))
        return self.source_radius_m ** 2 / c0
