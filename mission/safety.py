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

import numpy as np

from mission.safety_geometry import (
    boundary_distance,
    inside_fraction,
    nearest_boundary_point,
    offset_polygon_inward,
    point_in_polygon,
    polygon_is_simple,
    signed_area,
    synchronous_distance,
)
from mission.safety_report import (
    CentreClamp,
    ClampedSetpoints,
    EmptyFenceError,
    SafetyError,
    SafetyViolation,
    SetpointReport,
    Violation,
)
from mission.safety_transfer import TransferError, TransferPlan, plan_transfer

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

    def reachable_fraction(self, p0, p1):
        """How far along each straight segment ``p0 -> p1`` (``(..., 3)``) a vehicle starting
        inside can fly without leaving the prism: 1.0 when the whole segment is inside,
        0.0 when it leaves at once (e.g. a chord between two boundary points across a notch).

        The polygon part is exact up to ``1e-7`` m (touching the boundary does not count as
        leaving); the altitude band is convex, so only its end points matter.
        """
        p0 = _as_points(p0, "p0")
        p1 = _as_points(p1, "p1")
        if self._convex and np.all(point_in_polygon(p1[..., :2], self._poly, _TOL_M)):
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


def _pair_distances(p):
    sq = np.einsum("ni,ni->n", p, p)
    return np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * p @ p.T, 0.0))


def _close_pairs(p0, p1, sep_m):
    """Pairs ``i < j`` that may come closer than ``sep_m`` or be the closest pair, with their
    path and end-point distances.

    Two vehicles flying ``p0 -> p1`` are never closer than their start distance minus both
    steps: only pairs whose lower bound is below ``sep_m`` or below the smallest end-point
    distance (an upper bound of the minimum) need the exact path distance. The overall minimum
    over all pairs is exact.
    """
    step = np.linalg.norm(p1 - p0, axis=1)
    d_start = _pair_distances(p0)
    d_end = _pair_distances(p1)
    iu, ju = np.triu_indices(len(p0), 1)
    lower = d_start[iu, ju] - step[iu] - step[ju]
    ends = d_end[iu, ju]
    keep = (lower < sep_m) | (lower <= ends.min())
    ii, jj = iu[keep], ju[keep]
    d_path = synchronous_distance(p0[ii], p1[ii], p0[jj], p1[jj])
    return ii, jj, np.minimum(d_path, ends[keep]), ends[keep]


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
        clamped = not inner.contains(new)
        if inner.contains(prev) and not inner.segment_inside(prev, target):
            target = inner.last_inside_point(prev, target)
            clamped = True
        msg = ""
        if clamped:
            why = ("is outside" if not inner.contains(new)
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
        fence = self.fence
        poly = fence.polygon_en_m
        horiz_in = point_in_polygon(p1[:, :2], poly, _TOL_M)
        # paths: horizontal part only (the band is convex), for vehicles that start inside
        flat0 = np.c_[p0[:, :2], np.full(n, fence.min_alt_m)]
        flat1 = np.c_[p1[:, :2], np.full(n, fence.min_alt_m)]
        path_out = horiz_in & np.atleast_1d(fence.contains(flat0)) & ~np.atleast_1d(fence.segment_inside(flat0, flat1))
        z = p1[:, 2]
        low, high = z < fence.min_alt_m - _TOL_M, z > fence.max_alt_m + _TOL_M
        for i in np.flatnonzero(~horiz_in):
            d = float(boundary_distance(p1[i, :2], poly))
            out.append(Violation("fence", (int(i),), d, 0.0, f"vehicle {i} setpoint is {d:.2f} m outside the geofence"))
        for i in np.flatnonzero(path_out):
            out.append(Violation("fence_path", (int(i),), 0.0, 0.0,
                                 f"vehicle {i} path leaves the geofence between its setpoints"))
        for i in np.flatnonzero(low | high):
            out.append(Violation("altitude", (int(i),), float(z[i]), fence.min_alt_m if low[i] else fence.max_alt_m,
                                 f"vehicle {i} setpoint altitude {z[i]:.2f} m is outside the band "
                                 f"{fence.min_alt_m:g}..{fence.max_alt_m:g} m"))
        speed = np.linalg.norm(p1 - p0, axis=1) / dt_s
        for i in np.nonzero(speed > self.max_speed_m_s * (1 + 1e-9) + 1e-12)[0]:
            out.append(Violation("speed", (int(i),), float(speed[i]), self.max_speed_m_s,
                                 f"vehicle {i} would fly {speed[i]:.2f} m/s > limit {self.max_speed_m_s:g} m/s"))
        sep_min = float("inf")
        if n >= 2:
            ii, jj, d_path, d_end = _close_pairs(p0, p1, self.min_separation_m)
            sep_min = float(d_path.min()) if len(d_path) else float("inf")
            lim = self.min_separation_m * (1 - 1e-9)
            for i, j, de in zip(ii, jj, d_end):
                if de < lim:
                    out.append(Violation("separation", (int(i), int(j)), float(de), self.min_separation_m,
                                         f"vehicles {i} and {j} setpoints {de:.2f} m apart "
                                         f"< {self.min_separation_m:g} m"))
            for i, j, dp, de in zip(ii, jj, d_path, d_end):
                if dp < lim <= de:
                    out.append(Violation("separation_path", (int(i), int(j)), float(dp), self.min_separation_m,
                                         f"vehicles {i} and {j} come {dp:.2f} m close on their "
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
        inside0 = np.atleast_1d(fence.contains(p0))
        # non-convex fences: stop where the straight (horizontal) path would leave the polygon
        poly = fence.polygon_en_m
        inside0_h = point_in_polygon(p0[:, :2], poly, _TOL_M)
        if not fence.convex:
            frac = np.where(inside0_h, inside_fraction(p0[:, :2], out[:, :2], poly, _TOL_M), 1.0)
            cut = frac < 1.0
            out = np.where(cut[:, None], p0 + frac[:, None] * (out - p0), out)
            out[:, 2] = np.clip(out[:, 2], fence.min_alt_m, fence.max_alt_m)
            fence_clamped |= cut
        # speed: scale each step (the shortened step stays on the inside part of the path)
        step = np.linalg.norm(out - p0, axis=1)
        step_max = self.max_speed_m_s * dt_s
        speed_limited = inside0 & (step > step_max)
        scale = np.where(speed_limited, step_max / np.maximum(step, 1e-300), 1.0)
        out = p0 + scale[:, None] * (out - p0)
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
