"""The geofence: a polygon of ENU (east, north) vertices extruded between two altitudes.

Used by the safety envelope (:mod:`mission.safety.envelope`) and by the transfer planner
(:mod:`mission.safety.transfer`), hence in a module of its own below both.
"""
from __future__ import annotations

import numpy as np

from mission.safety.geometry import (
    boundary_distance,
    inside_fraction,
    nearest_boundary_point,
    offset_polygon_inward,
    polygon_is_simple,
    signed_area,
)
from mission.safety.report import EmptyFenceError, SafetyError

__all__ = ["Geofence"]

#: numerical slack (m) when checking a point against a boundary it was projected onto
_TOL_M = 1e-7


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
        edge = np.roll(self._poly, -1, axis=0) - self._poly
        nxt = np.roll(edge, -1, axis=0)
        turn = edge[:, 0] * nxt[:, 1] - edge[:, 1] * nxt[:, 0]
        self._convex = bool(np.all(turn >= -1e-12 * scale * scale))
        # edges of the crossing rule of point_in_polygon, kept once (the fence is immutable)
        start, end = self._poly, np.roll(self._poly, -1, axis=0)
        self._edge_a0, self._edge_a1, self._edge_b1 = start[:, 0].copy(), start[:, 1].copy(), end[:, 1].copy()
        self._edge_dx = end[:, 0] - start[:, 0]
        self._edge_dy = np.where(end[:, 1] - start[:, 1] == 0, 1.0, end[:, 1] - start[:, 1])
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
    def convex(self) -> bool:
        """Whether the polygon is convex (then a segment between inside points is inside)."""
        return self._convex

    @property
    def area_m2(self) -> float:
        """Horizontal area of the polygon."""
        return signed_area(self._poly)

    def horizontal_contains(self, points, tol_m: float = _TOL_M) -> np.ndarray:
        """Whether points ``(..., 2 or 3)`` are inside the polygon, ignoring altitude.

        The same as ``point_in_polygon(points[..., :2], polygon_en_m, tol_m)`` (identical
        results) with the polygon's edges prepared once. Returns a bool array of shape ``(...)``.
        """
        pts = np.asarray(points, dtype=float)
        x, y = pts[..., 0:1], pts[..., 1:2]
        a1 = self._edge_a1
        cond = (a1 > y) != (self._edge_b1 > y)
        x_cross = self._edge_a0 + (y - a1) * self._edge_dx / self._edge_dy
        inside = (np.count_nonzero(cond & (x < x_cross), axis=-1) % 2) == 1
        if tol_m <= 0 or inside.all():
            return inside
        inside = np.array(inside)  # writable, also for a single point
        out = ~inside  # only points outside by the crossing rule need the (costlier) distance
        inside[out] = boundary_distance(pts[..., :2][out], self._poly) <= tol_m
        return inside

    def band_contains(self, up_m, tol_m: float = _TOL_M) -> np.ndarray:
        """Whether altitudes ``up_m`` are inside the altitude band (within ``tol_m``)."""
        return (up_m >= self.min_alt_m - tol_m) & (up_m <= self.max_alt_m + tol_m)

    def contains(self, points, tol_m: float = _TOL_M):
        """Whether points ``(..., 3)`` are inside the prism (boundary within ``tol_m`` counts).

        Returns a ``bool`` for a single point, else a bool array of shape ``(...)``.
        """
        pts = _as_points(points, "points")
        inside = self.horizontal_contains(pts, tol_m)
        inside &= (pts[..., 2] >= self.min_alt_m - tol_m) & (pts[..., 2] <= self.max_alt_m + tol_m)
        return bool(inside) if inside.ndim == 0 else inside

    def distance_inside(self, points):
        """Signed distance to the prism's boundary: positive inside, negative outside (metres).

        Inside, the distance to the nearest wall, floor or ceiling; outside, minus the
        Euclidean distance to the prism.
        """
        pts = _as_points(points, "points")
        inside_h = self.horizontal_contains(pts, 0.0)
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
        inside_h = self.horizontal_contains(pts, 0.0)
        if not inside_h.all():  # (all inside: nothing moves horizontally)
            near = nearest_boundary_point(pts[..., :2], self._poly)
            out[..., :2] = np.where(inside_h[..., None], pts[..., :2], near)
        out[..., 2] = np.clip(pts[..., 2], self.min_alt_m, self.max_alt_m)
        return out

    def shrunk(self, margin_m: float, alt_margin_m: float | None = None) -> "Geofence":
        """The fence moved inward by ``margin_m`` (walls) and ``alt_margin_m`` (floor and ceiling).

        Convex corners are exact; reflex corners of non-convex fences are conservative (see
        :func:`mission.safety.geometry.offset_polygon_inward`). If the offset splits the fence
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

    def reachable_fraction(self, p0, p1):
        """How far along each straight segment ``p0 -> p1`` (``(..., 3)``) a vehicle starting
        inside can fly without leaving the prism: 1.0 when the whole segment is inside,
        0.0 when it leaves at once (e.g. a chord between two boundary points across a notch).

        The polygon part is exact up to ``1e-7`` m (touching the boundary does not count as
        leaving); the altitude band is convex, so only its end points matter.
        """
        p0 = _as_points(p0, "p0")
        p1 = _as_points(p1, "p1")
        if self._convex and np.all(self.horizontal_contains(p1, _TOL_M)):
            t = np.ones(p0.shape[:-1])  # convex: a segment between inside points is inside
        else:
            t = inside_fraction(p0[..., :2], p1[..., :2], self._poly, _TOL_M)
        dz = p1[..., 2] - p0[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hi = np.where(dz > 0, (self.max_alt_m + _TOL_M - p0[..., 2]) / dz, np.inf)
            t_lo = np.where(dz < 0, (self.min_alt_m - _TOL_M - p0[..., 2]) / dz, np.inf)
        t = np.clip(np.minimum(t, np.minimum(t_hi, t_lo)), 0.0, 1.0)
        t = np.where(np.atleast_1d(self.contains(p0)).reshape(t.shape), t, 0.0)
        return float(t) if t.ndim == 0 else t

    def segment_inside(self, p0, p1):
        """Whether each whole straight segment ``p0 -> p1`` (``(..., 3)``) stays inside."""
        inside = np.asarray(self.reachable_fraction(p0, p1)) >= 1.0
        inside &= np.atleast_1d(self.contains(p1)).reshape(inside.shape)
        return bool(inside) if inside.ndim == 0 else inside

    def last_inside_point(self, p0, p1) -> np.ndarray:
        """The farthest point along each ``p0 -> p1`` reachable without leaving the prism
        (``p0`` must be inside; returns ``p1`` where the whole segment is inside)."""
        p0 = _as_points(p0, "p0")
        p1 = _as_points(p1, "p1")
        t = np.asarray(self.reachable_fraction(p0, p1))
        return p0 + t[..., None] * (p1 - p0)
