"""The safety envelope: geofence, altitude band, speed limit and separation (pure maths).

Everything is in the mission ENU frame (metres): ``x = east_m``, ``y = north_m``, ``z = up_m``
about the mission origin (``docs/interfaces.md``). Altitudes of the band are mission-frame ``up_m``.

The rule the mission relies on: **no setpoint leaves the geofence or the altitude band, ever,
whatever the maths says.** :meth:`SafetyEnvelope.clamp_setpoints` makes setpoints safe (inside
the fence and band, speed-limited) and ends with :meth:`SafetyEnvelope.assert_safe`, which raises
:class:`SafetyViolation` if anything would still leave.

Separation is checked on the paths, not only on the end points: two vehicles flying straight
lines simultaneously at constant speed (start together, arrive together) are closest at a time
given in closed form (:func:`mission.safety_geometry.synchronous_distance`).
:func:`plan_transfer` (in :mod:`mission.safety_transfer`) plans assembly, reconfiguration and
return moves that keep separation.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mission.safety_geometry import (
    nearest_boundary_point,
    offset_polygon_inward,
    point_in_polygon,
    boundary_distance,
    polygon_is_simple,
    segment_polygon_crossings,
    signed_area,
    synchronous_distance,
)

__all__ = [
    "SafetyError",
    "EmptyFenceError",
    "SafetyViolation",
    "Geofence",
    "CentreClamp",
    "Violation",
    "SetpointReport",
    "ClampedSetpoints",
    "SafetyEnvelope",
    "pairwise_path_separation",
    "plan_transfer",
    "TransferPlan",
    "TransferError",
]

#: numerical slack (m) when checking a point against a boundary it was projected onto
_TOL_M = 1e-7


class SafetyError(ValueError):
    """An invalid safety configuration (fence, band, limits)."""


class EmptyFenceError(SafetyError):
    """A fence shrunk by a margin (e.g. the formation radius) leaves no room at all."""


class SafetyViolation(RuntimeError):
    """A setpoint would break the envelope even after clamping; never send it."""


def _as_points(p, name):
    arr = np.asarray(p, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) (east_m, north_m, up_m), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite coordinates")
    return arr


class Geofence:
    """A vertical prism: a simple polygon (east, north) and an altitude band (up).

    Parameters
    ----------
    polygon_en_m : array_like, shape (K, 2)
        Vertices ``(east_m, north_m)`` in the mission frame, either orientation, K >= 3, not
        closed (a repeated first vertex at the end is accepted and dropped).
    min_alt_m, max_alt_m : float
        Altitude band, mission-frame ``up_m``; ``min_alt_m < max_alt_m``.

    Raises
    ------
    SafetyError
        Fewer than 3 distinct vertices, NaN, zero area, self-intersection (names the edges),
        or an empty altitude band.
    """

    def __init__(self, polygon_en_m, min_alt_m: float, max_alt_m: float):
        poly = np.asarray(polygon_en_m, dtype=float)
        if poly.ndim != 2 or poly.shape[1] != 2:
            raise SafetyError(f"geofence polygon must have shape (K, 2) (east_m, north_m), got {poly.shape}")
        if not np.all(np.isfinite(poly)):
            raise SafetyError("geofence polygon has NaN or infinite vertices")
        if len(poly) >= 2 and np.allclose(poly[0], poly[-1]):
            poly = poly[:-1]
        keep = np.ones(len(poly), dtype=bool)
        keep[1:] = np.any(poly[1:] != poly[:-1], axis=1)
        poly = poly[keep]
        if len(poly) < 3:
            raise SafetyError(f"geofence polygon needs at least 3 distinct vertices, got {len(poly)}")
        area = signed_area(poly)
        scale = max(float(np.ptp(poly, axis=0).max()), 1.0)
        if np.linalg.matrix_rank(poly - poly.mean(axis=0), tol=1e-9 * scale) < 2:
            raise SafetyError("geofence polygon has zero area (its vertices are collinear)")
        simple, edges = polygon_is_simple(poly)
        if not simple:
            i, j = edges
            k = len(poly)
            raise SafetyError(
                f"geofence polygon is self-intersecting: edge {i} (vertex {i} -> {(i + 1) % k}) "
                f"touches edge {j} (vertex {j} -> {(j + 1) % k})"
            )
        if abs(area) <= 1e-9 * scale * scale:
            raise SafetyError("geofence polygon has zero area")
        try:
            lo, hi = float(min_alt_m), float(max_alt_m)
        except (TypeError, ValueError) as exc:
            raise SafetyError(f"altitude band must be numbers: {exc}") from None
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise SafetyError("altitude band must be finite")
        if not lo < hi:
            raise SafetyError(f"altitude band is empty: min_alt_m={lo} must be < max_alt_m={hi}")
        self._poly = poly if area > 0 else poly[::-1].copy()
        self._poly.setflags(write=False)
        self.min_alt_m = lo
        self.max_alt_m = hi

    def __repr__(self):
        return (f"Geofence({len(self._poly)} vertices, area {self.area_m2:.1f} m^2, "
                f"alt {self.min_alt_m:g}..{self.max_alt_m:g} m)")

    @property
    def polygon_en_m(self) -> np.ndarray:
        """Counter-clockwise vertices ``(K, 2)`` (read-only)."""
        return self._poly

    @property
    def area_m2(self) -> float:
        """Horizontal area of the polygon."""
        return signed_area(self._poly)

    def contains(self, points, tol_m: float = _TOL_M):
        """Whether points ``(..., 3)`` are inside the prism (boundary within ``tol_m`` counts).

        Returns a ``bool`` for a single point, else a bool array of shape ``(...)``.
        """
        pts = _as_points(points, "points")
        inside = point_in_polygon(pts[..., :2], self._poly, tol_m)
        inside &= (pts[..., 2] >= self.min_alt_m - tol_m) & (pts[..., 2] <= self.max_alt_m + tol_m)
        return bool(inside) if inside.ndim == 0 else inside

    def distance_inside(self, points):
        """Signed distance to the prism's boundary: positive inside, negative outside (metres).

        Inside, the distance to the nearest wall, floor or ceiling; outside, minus the
        Euclidean distance to the prism.
        """
        pts = _as_points(points, "points")
        inside_h = point_in_polygon(pts[..., :2], self._poly, 0.0)
        dh = boundary_distance(pts[..., :2], self._poly)
        z = pts[..., 2]
        dz_in = np.minimum(z - self.min_alt_m, self.max_alt_m - z)
        out_h = np.where(inside_h, 0.0, dh)
        out_v = np.maximum(0.0, -dz_in)
        outside = np.sqrt(out_h**2 + out_v**2)
        inside = np.minimum(np.where(inside_h, dh, 0.0), dz_in)
        res = np.where(outside > 0, -outside, inside)
        return float(res) if res.ndim == 0 else res

    def clamp(self, points) -> np.ndarray:
        """Nearest point of the prism to each point ``(..., 3)`` (points inside are unchanged)."""
        pts = _as_points(points, "points")
        out = pts.copy()
        inside_h = point_in_polygon(pts[..., :2], self._poly, 0.0)
        near = nearest_boundary_point(pts[..., :2], self._poly)
        out[..., :2] = np.where(inside_h[..., None], pts[..., :2], near)
        out[..., 2] = np.clip(pts[..., 2], self.min_alt_m, self.max_alt_m)
        return out

    def shrunk(self, margin_m: float, alt_margin_m: float | None = None) -> "Geofence":
        """The fence moved inward by ``margin_m`` (walls) and ``alt_margin_m`` (floor and ceiling).

        Convex corners are exact; reflex corners of non-convex fences are conservative (see
        :func:`mission.safety_geometry.offset_polygon_inward`). If the offset splits the fence
        the largest piece is kept.

        Raises
        ------
        EmptyFenceError
            If nothing is left, with the sizes involved.
        """
        margin = float(margin_m)
        alt_margin = margin if alt_margin_m is None else float(alt_margin_m)
        if not (np.isfinite(margin) and margin >= 0 and np.isfinite(alt_margin) and alt_margin >= 0):
            raise SafetyError(f"shrink margins must be finite and >= 0, got {margin_m!r}, {alt_margin_m!r}")
        lo, hi = self.min_alt_m + alt_margin, self.max_alt_m - alt_margin
        if not lo < hi:
            raise EmptyFenceError(
                f"altitude band {self.min_alt_m:g}..{self.max_alt_m:g} m shrunk by {alt_margin:g} m "
                "is empty: the band must be taller than twice the margin (formation radius)"
            )
        poly = offset_polygon_inward(self._poly, margin)
        if len(poly) < 3:
            raise EmptyFenceError(
                f"geofence shrunk by {margin:g} m is empty: the fence polygon is too narrow "
                "for that margin (formation radius)"
            )
        return Geofence(poly, lo, hi)

    def segment_inside(self, p0, p1, tol_m: float = _TOL_M) -> bool:
        """Whether the whole straight segment ``p0 -> p1`` (3D) stays inside the prism."""
        p0 = _as_points(p0, "p0").reshape(3)
        p1 = _as_points(p1, "p1").reshape(3)
        if not (self.contains(p0, tol_m) and self.contains(p1, tol_m)):
            return False
        ts = segment_polygon_crossings(p0[:2], p1[:2], self._poly)
        ts = np.unique(np.concatenate([[0.0, 1.0], ts]))
        mids = 0.5 * (ts[1:] + ts[:-1])
        pts = p0[:2] + mids[:, None] * (p1[:2] - p0[:2])
        return bool(np.all(point_in_polygon(pts, self._poly, tol_m)))

    def last_inside_point(self, p0, p1) -> np.ndarray:
        """The farthest point along ``p0 -> p1`` reachable without leaving the prism
        (``p0`` must be inside; returns ``p1`` if the whole segment is inside)."""
        p0 = _as_points(p0, "p0").reshape(3)
        p1 = _as_points(p1, "p1").reshape(3)
        if self.segment_inside(p0, p1):
            return p1.copy()
        ts = segment_polygon_crossings(p0[:2], p1[:2], self._poly)
        ts = np.unique(np.concatenate([[0.0, 1.0], ts]))
        t_ok = 0.0
        for t0, t1 in zip(ts[:-1], ts[1:]):
            mid = p0 + 0.5 * (t0 + t1) * (p1 - p0)
            if not self.contains(mid, 0.0):
                break
            t_ok = t1
        # the altitude band is convex: limit t so z stays in the band
        dz = p1[2] - p0[2]
        if dz > 0:
            t_ok = min(t_ok, (self.max_alt_m - p0[2]) / dz)
        elif dz < 0:
            t_ok = min(t_ok, (self.min_alt_m - p0[2]) / dz)
        return p0 + max(0.0, t_ok) * (p1 - p0)


@dataclass(frozen=True)
class CentreClamp:
    """Result of :meth:`SafetyEnvelope.clamp_centre`.

    Attributes
    ----------
    centre_enu : numpy.ndarray, shape (3,)
        The centre to use (inside the fence shrunk by the formation radius).
    at_boundary : bool
        True if the requested centre was outside and was stopped at the boundary.
    requested_enu : numpy.ndarray, shape (3,)
        The centre that was asked for.
    message : str
        Human-readable explanation ("" when not clamped).
    """

    centre_enu: np.ndarray
    at_boundary: bool
    requested_enu: np.ndarray
    message: str = ""

    @property
    def shortfall_m(self) -> float:
        """Distance between the requested and the allowed centre."""
        return float(np.linalg.norm(self.requested_enu - self.centre_enu))


@dataclass(frozen=True)
class Violation:
    """One broken rule: ``kind`` in ``fence``, ``fence_path``, ``altitude``, ``speed``,
    ``separation`` (end points) or ``separation_path``; ``vehicles`` are 0-based indices."""

    kind: str
    vehicles: tuple[int, ...]
    value: float
    limit: float
    message: str


@dataclass(frozen=True)
class SetpointReport:
    """Every violation found by :meth:`SafetyEnvelope.check_setpoints`."""

    violations: tuple[Violation, ...] = ()
    min_separation_m: float = float("inf")
    max_speed_m_s: float = 0.0

    @property
    def ok(self) -> bool:
        """True when nothing is violated."""
        return not self.violations

    def kinds(self) -> set[str]:
        """The set of violated rule kinds."""
        return {v.kind for v in self.violations}

    def __str__(self):
        if self.ok:
            return "setpoints safe"
        return "; ".join(v.message for v in self.violations)


@dataclass(frozen=True)
class ClampedSetpoints:
    """Result of :meth:`SafetyEnvelope.clamp_setpoints`.

    Attributes
    ----------
    positions_enu : numpy.ndarray, shape (N, 3)
        Safe setpoints: inside the fence and band, speed-limited where the previous position
        was inside the fence.
    fence_clamped, speed_limited : numpy.ndarray of bool, shape (N,)
        Which vehicles' setpoints were moved by the fence/band or shortened by the speed limit.
    report : SetpointReport
        The check of the returned setpoints (separation problems are reported, not fixed).
    """

    positions_enu: np.ndarray
    fence_clamped: np.ndarray
    speed_limited: np.ndarray
    report: SetpointReport = field(default_factory=SetpointReport)


def pairwise_path_separation(prev_positions, new_positions) -> np.ndarray:
    """``(N, N)`` minimum distance of each pair flying straight ``prev -> new`` simultaneously
    (diagonal = +inf)."""
    p0 = np.asarray(prev_positions, dtype=float)
    p1 = np.asarray(new_positions, dtype=float)
    d = synchronous_distance(p0[:, None], p1[:, None], p0[None, :], p1[None, :])
    np.fill_diagonal(d, np.inf)
    return d


class SafetyEnvelope:
    """Geofence, speed limit and minimum separation for a formation of radius ``D``.

    Parameters
    ----------
    fence : Geofence
        The hard fence for every vehicle.
    max_speed_m_s : float
        Speed limit of every vehicle (> 0).
    min_separation_m : float
        Minimum distance between any two vehicles (>= 0), on paths and end points.
    formation_radius_m : float
        Radius of the formation; the centre is kept inside the fence shrunk by it.

    Raises
    ------
    SafetyError
        Bad limits; :class:`EmptyFenceError` if the fence cannot hold the formation.
    """

    def __init__(self, fence: Geofence, max_speed_m_s: float, min_separation_m: float,
                 formation_radius_m: float):
        if not isinstance(fence, Geofence):
            raise SafetyError(f"fence must be a Geofence, got {type(fence).__name__}")
        for name, val, strict in (("max_speed_m_s", max_speed_m_s, True),
                                  ("min_separation_m", min_separation_m, False),
                                  ("formation_radius_m", formation_radius_m, False)):
            if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val) \
                    or (val <= 0 if strict else val < 0):
                raise SafetyError(f"{name} must be a finite number {'> 0' if strict else '>= 0'}, got {val!r}")
        self.fence = fence
        self.max_speed_m_s = float(max_speed_m_s)
        self.min_separation_m = float(min_separation_m)
        self.formation_radius_m = float(formation_radius_m)
        try:
            self.centre_fence = fence.shrunk(self.formation_radius_m)
        except EmptyFenceError as exc:
            raise EmptyFenceError(f"the formation (radius {self.formation_radius_m:g} m) does not fit "
                                  f"in the geofence: {exc}") from None

    def clamp_centre(self, centre_prev, centre_new) -> CentreClamp:
        """Keep the formation centre inside the fence shrunk by the radius.

        If ``centre_new`` is outside, or the straight move from ``centre_prev`` leaves the
        shrunk fence (non-convex fences), the centre stops at the boundary and
        ``at_boundary`` is set with a message saying so. A ``centre_prev`` outside the shrunk
        fence is ignored (the nearest allowed point of ``centre_new`` is used).
        """
        prev = _as_points(centre_prev, "centre_prev").reshape(3)
        new = _as_points(centre_new, "centre_new").reshape(3)
        inner = self.centre_fence
        target = inner.clamp(new)
        clamped = not inner.contains(new, 0.0)
        if inner.contains(prev) and not inner.segment_inside(prev, target):
            target = inner.last_inside_point(prev, target)
            clamped = True
        msg = ""
        if clamped:
            why = ("is outside" if not inner.contains(new, 0.0)
                   else "cannot be reached in a straight line inside")
            msg = (f"requested centre ({new[0]:.2f}, {new[1]:.2f}, {new[2]:.2f}) {why} the fence "
                   f"shrunk by the formation radius {self.formation_radius_m:g} m: stopped at the "
                   f"boundary ({target[0]:.2f}, {target[1]:.2f}, {target[2]:.2f}), "
                   f"{float(np.linalg.norm(new - target)):.2f} m short")
        return CentreClamp(target, clamped, new, msg)

    def check_setpoints(self, prev_positions, new_positions, dt_s: float) -> SetpointReport:
        """Every violation of moving all vehicles ``prev -> new`` in ``dt_s`` seconds.

        Checks the new setpoints against the fence and band, each straight path against the
        (possibly non-convex) fence, speed ``||new - prev|| / dt_s``, and separation at the end
        points and along the simultaneous straight-line paths.
        """
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        out = []
        n = len(p0)
        horiz_in = point_in_polygon(p1[:, :2], self.fence.polygon_en_m, _TOL_M)
        for i in range(n):
            if not horiz_in[i]:
                d = float(boundary_distance(p1[i, :2], self.fence.polygon_en_m))
                out.append(Violation("fence", (i,), d, 0.0,
                                     f"vehicle {i} setpoint is {d:.2f} m outside the geofence"))
            elif self.fence.contains(p0[i]) and not self.fence.segment_inside(
                    np.r_[p0[i, :2], self.fence.min_alt_m], np.r_[p1[i, :2], self.fence.min_alt_m]):
                out.append(Violation("fence_path", (i,), 0.0, 0.0,
                                     f"vehicle {i} path leaves the geofence between its setpoints"))
            z = p1[i, 2]
            if z < self.fence.min_alt_m - _TOL_M or z > self.fence.max_alt_m + _TOL_M:
                out.append(Violation("altitude", (i,), float(z), self.fence.min_alt_m if z < self.fence.min_alt_m
                                     else self.fence.max_alt_m,
                                     f"vehicle {i} setpoint altitude {z:.2f} m is outside the band "
                                     f"{self.fence.min_alt_m:g}..{self.fence.max_alt_m:g} m"))
        speed = np.linalg.norm(p1 - p0, axis=1) / dt_s
        for i in np.nonzero(speed > self.max_speed_m_s * (1 + 1e-9) + 1e-12)[0]:
            out.append(Violation("speed", (int(i),), float(speed[i]), self.max_speed_m_s,
                                 f"vehicle {i} would fly {speed[i]:.2f} m/s > limit {self.max_speed_m_s:g} m/s"))
        sep_min = float("inf")
        if n >= 2:
            d_end = np.linalg.norm(p1[:, None] - p1[None, :], axis=-1)
            np.fill_diagonal(d_end, np.inf)
            d_path = pairwise_path_separation(p0, p1)
            sep_min = float(d_path.min())
            lim = self.min_separation_m * (1 - 1e-9)
            for i, j in zip(*np.nonzero(np.triu(d_end < lim, 1))):
                out.append(Violation("separation", (int(i), int(j)), float(d_end[i, j]), self.min_separation_m,
                                     f"vehicles {i} and {j} setpoints {d_end[i, j]:.2f} m apart "
                                     f"< {self.min_separation_m:g} m"))
            for i, j in zip(*np.nonzero(np.triu((d_path < lim) & (d_end >= lim), 1))):
                out.append(Violation("separation_path", (int(i), int(j)), float(d_path[i, j]),
                                     self.min_separation_m,
                                     f"vehicles {i} and {j} come {d_path[i, j]:.2f} m close on their "
                                     f"paths < {self.min_separation_m:g} m"))
        return SetpointReport(tuple(out), sep_min, float(speed.max()) if n else 0.0)

    def clamp_setpoints(self, prev_positions, new_positions, dt_s: float) -> ClampedSetpoints:
        """Safe setpoints: inside the fence and band, each step scaled down to the speed limit.

        Each new setpoint is moved to the nearest point of the fence; if the straight path from
        the previous position leaves a non-convex fence, it stops where it would leave; the
        step is then scaled to at most ``max_speed_m_s * dt_s``. The fence wins over the speed
        limit: a vehicle whose previous position is outside the fence gets the nearest inside
        point (and a ``speed`` violation in the report if that is too far). Separation is
        checked and reported, not changed.

        Raises
        ------
        SafetyViolation
            If a setpoint would still be outside the fence or band (never expected).
        """
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        fence = self.fence
        out = fence.clamp(p1)
        fence_clamped = np.any(out != p1, axis=1)
        speed_limited = np.zeros(len(p0), dtype=bool)
        step_max = self.max_speed_m_s * dt_s
        for i in range(len(p0)):
            if not fence.contains(p0[i]):
                continue
            if not fence.segment_inside(p0[i], out[i]):
                out[i] = fence.last_inside_point(p0[i], out[i])
                fence_clamped[i] = True
            step = out[i] - p0[i]
            norm = float(np.linalg.norm(step))
            if norm > step_max:
                out[i] = p0[i] + step * (step_max / norm)
                speed_limited[i] = True
        self.assert_safe(p0, out, dt_s)
        return ClampedSetpoints(out, fence_clamped, speed_limited, self.check_setpoints(p0, out, dt_s))

    def assert_safe(self, prev_positions, new_positions, dt_s: float) -> None:
        """Raise :class:`SafetyViolation` if a setpoint is outside the fence or band, or too
        fast from a previous position that was inside the fence."""
        p0, p1 = self._check_shapes(prev_positions, new_positions, dt_s)
        bad = ~np.atleast_1d(self.fence.contains(p1, _TOL_M))
        if np.any(bad):
            raise SafetyViolation(f"setpoints of vehicles {np.nonzero(bad)[0].tolist()} would leave the "
                                  f"geofence or altitude band: not sent")
        inside_before = np.atleast_1d(self.fence.contains(p0))
        speed = np.linalg.norm(p1 - p0, axis=1) / dt_s
        fast = inside_before & (speed > self.max_speed_m_s * (1 + 1e-6))
        if np.any(fast):
            raise SafetyViolation(f"setpoints of vehicles {np.nonzero(fast)[0].tolist()} exceed the speed "
                                  f"limit {self.max_speed_m_s:g} m/s: not sent")

    @staticmethod
    def _check_shapes(prev_positions, new_positions, dt_s):
        p0 = _as_points(prev_positions, "prev_positions")
        p1 = _as_points(new_positions, "new_positions")
        if p0.ndim != 2 or p0.shape != p1.shape:
            raise ValueError(f"prev_positions and new_positions must both be (N, 3), got {p0.shape} and {p1.shape}")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a finite number > 0, got {dt_s!r}")
        return p0, p1


from mission.safety_transfer import TransferError, TransferPlan, plan_transfer  # noqa: E402
