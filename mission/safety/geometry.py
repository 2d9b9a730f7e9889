"""Plane and segment geometry for the safety envelope (pure numpy, no state).

Everything here works on plain arrays in the mission ENU frame (metres). Polygons are ``(K, 2)``
arrays of ``(east_m, north_m)`` vertices, not closed (the last vertex is not repeated).

Public functions
----------------
``segment_distance``
    Minimum distance between two segments (any dimension, vectorised).
``synchronous_distance``
    Minimum distance between two points moving simultaneously at constant velocity along two
    segments over the same time interval (what two vehicles flying straight lines do).
``inside_fraction``
    How far along a segment one stays inside a (possibly non-convex) polygon.
``offset_polygon_inward``
    Conservative inward offset (erosion by a disc) of a simple polygon, convex or not.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "segment_distance",
    "synchronous_distance",
    "signed_area",
    "point_in_polygon",
    "boundary_distance",
    "nearest_boundary_point",
    "polygon_is_simple",
    "inside_fraction",
    "offset_polygon_inward",
]



def segment_distance(a0, a1, b0, b1) -> np.ndarray:
    """Minimum distance between segments ``[a0, a1]`` and ``[b0, b1]``.

    Parameters
    ----------
    a0, a1, b0, b1 : array_like, shape (..., D)
        Segment end points; leading dimensions broadcast. Degenerate (zero-length) segments are
        points.

    Returns
    -------
    numpy.ndarray, shape (...)
        The distance between the closest points of the two segments.
    """
    a0, a1, b0, b1 = (np.asarray(x, dtype=float) for x in (a0, a1, b0, b1))
    d1 = a1 - a0
    d2 = b1 - b0
    r = a0 - b0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    # interior critical point (non-parallel segments) ...
    denom = a * e - b * b
    ok = denom > 1e-12 * np.maximum(a * e, 1e-300)
    safe = np.where(ok, denom, 1.0)
    s = np.clip((b * f - c * e) / safe, 0.0, 1.0)
    t = np.clip((a * f - b * c) / safe, 0.0, 1.0)
    inner = np.linalg.norm(a0 + s[..., None] * d1 - b0 - t[..., None] * d2, axis=-1)
    best = np.where(ok, inner, np.inf)
    # ... or an end point of one segment against the other segment (always a candidate)
    for p, q0, dq, qq in ((a0, b0, d2, e), (a1, b0, d2, e), (b0, a0, d1, a), (b1, a0, d1, a)):
        u = np.clip(np.einsum("...i,...i->...", p - q0, dq) / np.where(qq > 0, qq, 1.0), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - q0 - u[..., None] * dq, axis=-1))
    return best


def synchronous_distance(p0, p1, q0, q1) -> np.ndarray:
    """Minimum distance between two points moving simultaneously along straight segments.

    Point P goes from ``p0`` to ``p1`` and point Q from ``q0`` to ``q1`` over the same time
    interval, each at constant velocity (both start and arrive together).

    Parameters
    ----------
    p0, p1, q0, q1 : array_like, shape (..., D)
        Start and end positions; leading dimensions broadcast.

    Returns
    -------
    numpy.ndarray, shape (...)
        ``min over t in [0, 1] of ||(p0 + t (p1 - p0)) - (q0 + t (q1 - q0))||``.
    """
    p0, p1, q0, q1 = (np.asarray(x, dtype=float) for x in (p0, p1, q0, q1))
    d0 = p0 - q0
    dv = (p1 - p0) - (q1 - q0)
    vv = np.einsum("...i,...i->...", dv, dv)
    dvd = np.einsum("...i,...i->...", d0, dv)
    dd = np.einsum("...i,...i->...", d0, d0)
    t = np.clip(-dvd / np.where(vv > 0, vv, 1.0), 0.0, 1.0)
    t = np.where(vv > 0, t, 0.0)
    # |d0 + t dv|^2 expanded (no (..., 3) temporaries); never above either end point's distance
    best = np.minimum(dd + t * (2.0 * dvd + t * vv), np.minimum(dd, dd + 2.0 * dvd + vv))
    return np.sqrt(np.maximum(best, 0.0))


def signed_area(poly) -> float:
    """Signed area of a polygon ``(K, 2)``: positive for counter-clockwise vertices."""
    p = np.asarray(poly, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edges(poly):
    p = np.asarray(poly, dtype=float)
    return p, np.roll(p, -1, axis=0)


def boundary_distance(points, poly) -> np.ndarray:
    """Distance from points ``(..., 2)`` to the polygon's boundary, shape ``(...)``."""
    return np.linalg.norm(points - nearest_boundary_point(points, poly), axis=-1)


def nearest_boundary_point(points, poly) -> np.ndarray:
    """Nearest point of the polygon's boundary to each point ``(..., 2)``; same shape."""
    pts = np.asarray(points, dtype=float)
    a, b = _edges(poly)
    d = b - a
    dd = np.einsum("ki,ki->k", d, d)
    rel = pts[..., None, :] - a
    t = np.clip(np.einsum("...ki,ki->...k", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    proj = a + t[..., None] * d
    dist2 = np.einsum("...ki,...ki->...k", pts[..., None, :] - proj, pts[..., None, :] - proj)
    k = np.argmin(dist2, axis=-1)
    return np.take_along_axis(proj, k[..., None, None], axis=-2)[..., 0, :]


def point_in_polygon(points, poly, tol_m: float = 1e-9) -> np.ndarray:
    """Whether points ``(..., 2)`` lie inside the polygon or within ``tol_m`` of its boundary."""
    pts = np.asarray(points, dtype=float)
    a, b = _edges(poly)
    x, y = pts[..., 0:1], pts[..., 1:2]
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    dy = np.where(b[:, 1] - a[:, 1] == 0, 1.0, b[:, 1] - a[:, 1])
    x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
    inside = (np.count_nonzero(cond & (x < x_cross), axis=-1) % 2) == 1
    if tol_m <= 0 or np.all(inside):
        return inside
    inside = np.array(inside)  # writable, also for a single point
    out = ~inside  # only points outside by the crossing rule need the (costlier) distance
    inside[out] = boundary_distance(pts[out], poly) <= tol_m
    return inside


def _cross2(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def polygon_is_simple(poly) -> tuple[bool, tuple[int, int] | None]:
    """Whether a polygon is simple (no two non-adjacent edges touch).

    Returns
    -------
    (bool, (i, j) or None)
        ``True, None`` if simple, else ``False`` and the indices of two offending edges
        (edge ``i`` goes from vertex ``i`` to vertex ``i + 1``).
    """
    a, b = _edges(poly)
    k = len(a)
    dist = segment_distance(a[:, None, :], b[:, None, :], a[None, :, :], b[None, :, :])
    scale = max(float(np.ptp(a, axis=0).max()), 1.0)
    for i in range(k):
        for j in range(i + 1, k):
            adjacent = j == i + 1 or (i == 0 and j == k - 1)
            if adjacent:
                # adjacent edges share a vertex; they may not fold back onto each other
                if j == i + 1:
                    u, v = a[i] - b[i], b[j] - a[j]
                else:
                    u, v = b[i] - a[i], a[j] - b[j]
                if abs(_cross2(u, v)) <= 1e-12 * scale * scale and float(np.dot(u, v)) > 0:
                    return False, (i, j)
                continue
            if dist[i, j] <= 1e-9 * scale:
                return False, (i, j)
    return True, None


def inside_fraction(p0, p1, poly, tol_m: float = 1e-7) -> np.ndarray:
    """How far along each segment ``p0 -> p1`` (2D) one stays inside the polygon (boundary
    included): the start of the first piece between boundary contacts that lies outside, or
    1.0 when none does. Grazing a vertex or running along an edge is not leaving.

    Parameters
    ----------
    p0, p1 : array_like, shape (..., 2)
    poly : array_like, shape (K, 2)

    Returns
    -------
    numpy.ndarray, shape (...)
    """
    p0 = np.asarray(p0, dtype=float)
    p1 = np.asarray(p1, dtype=float)
    a, b = _edges(poly)
    d = (p1 - p0)[..., None, :]
    e = b - a
    w = a - p0[..., None, :]
    den = _cross2(d, e)
    length = np.linalg.norm(d, axis=-1)
    ok = np.abs(den) > 1e-12 * length * np.linalg.norm(e, axis=-1)
    safe = np.where(ok, den, 1.0)
    with np.errstate(over="ignore"):  # a crossing far beyond the segment overflows to inf: no hit, rightly
        t = _cross2(w, e) / safe
        u = _cross2(w, d) / safe
    hit = ok & (t > 0.0) & (t < 1.0) & (u >= -1e-12) & (u <= 1.0 + 1e-12)
    ts = np.sort(np.where(hit, t, 1.0), axis=-1)
    ts = np.concatenate([np.zeros(ts.shape[:-1] + (1,)), ts, np.ones(ts.shape[:-1] + (1,))], axis=-1)
    mid = 0.5 * (ts[..., :-1] + ts[..., 1:])
    pts = p0[..., None, :] + mid[..., None] * (p1 - p0)[..., None, :]
    bad = ~point_in_polygon(pts, poly, tol_m) & (ts[..., 1:] - ts[..., :-1] > 0)
    first = np.argmax(bad, axis=-1)
    start = np.take_along_axis(ts[..., :-1], first[..., None], axis=-1)[..., 0]
    return np.where(np.any(bad, axis=-1), start, 1.0)


def _clean(poly, scale):
    """Drop repeated and collinear vertices (they would give parallel consecutive lines)."""
    p = np.asarray(poly, dtype=float)
    changed = True
    while changed and len(p) >= 3:
        changed = False
        prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        cr = _cross2(p - prev, nxt - p)
        dup = np.linalg.norm(p - prev, axis=1) <= 1e-12 * scale
        lin = np.abs(cr) <= 1e-12 * scale * scale
        drop = dup | (lin & (np.einsum("ij,ij->i", p - prev, nxt - p) >= 0))
        if np.any(drop):
            p = p[~drop] if np.count_nonzero(~drop) >= 3 else p[:0]
            changed = True
    return p


def _offset_lines(ccw, arc_step_rad):
    """Lines ``n . x = c`` (inward normals) of the edges plus tangent lines at reflex corners."""
    a, b = _edges(ccw)
    d = b - a
    d = d / np.linalg.norm(d, axis=1)[:, None]
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)  # left normal: inward for CCW
    normals, anchors = [], []
    k = len(ccw)
    for i in range(k):
        # corner at vertex i between edge i-1 and edge i
        n_prev, n_cur = n[i - 1], n[i]
        turn = _cross2(d[i - 1], d[i])
        if turn < 0:  # reflex corner: the erosion has an arc about the vertex
            ang = np.arctan2(_cross2(n_prev, n_cur), float(np.dot(n_prev, n_cur)))  # < 0
            m = int(np.ceil(abs(ang) / arc_step_rad))
            for j in range(1, m):
                phi = np.arctan2(n_prev[1], n_prev[0]) + ang * j / m
                normals.append(np.array([np.cos(phi), np.sin(phi)]))
                anchors.append(ccw[i])
        normals.append(n_cur)
        anchors.append(ccw[i])
    normals = np.asarray(normals)
    anchors = np.asarray(anchors)
    return normals, np.einsum("ij,ij->i", normals, anchors)


def _intersections(normals, c):
    """Vertex between consecutive lines i and i+1; None if two consecutive lines are parallel."""
    n1, n2 = normals, np.roll(normals, -1, axis=0)
    c1, c2 = c, np.roll(c, -1)
    det = _cross2(n1, n2)
    if np.any(np.abs(det) < 1e-12):
        return None
    x = (c1 * n2[:, 1] - c2 * n1[:, 1]) / det
    y = (n1[:, 0] * c2 - n2[:, 0] * c1) / det
    return np.stack([x, y], axis=1)


def _split_loops(poly):
    """Split a self-intersecting closed polyline into simple loops at its crossings."""
    loops, stack = [], [np.asarray(poly, dtype=float)]
    while stack:
        p = stack.pop()
        k = len(p)
        found = None
        for i in range(k):
            for j in range(i + 2, k):
                if i == 0 and j == k - 1:
                    continue
                a0, a1, b0, b1 = p[i], p[(i + 1) % k], p[j], p[(j + 1) % k]
                den = _cross2(a1 - a0, b1 - b0)
                if abs(den) < 1e-15:
                    continue
                t = _cross2(b0 - a0, b1 - b0) / den
                u = _cross2(b0 - a0, a1 - a0) / den
                if 0 < t < 1 and 0 < u < 1:
                    found = (i, j, a0 + t * (a1 - a0))
                    break
            if found:
                break
        if found is None:
            loops.append(p)
            continue
        i, j, x = found
        stack.append(np.vstack([p[: i + 1], x[None], p[j + 1:]]))
        stack.append(np.vstack([x[None], p[i + 1: j + 1]]))
    return [q for q in loops if len(q) >= 3]


def offset_polygon_inward(poly, margin_m: float, arc_step_rad: float = np.pi / 8) -> np.ndarray:
    """Conservative inward offset of a simple polygon (its erosion by a disc of radius margin).

    Each edge moves inward by ``margin_m``; convex corners are mitred (exact); at reflex
    corners the exact erosion has a circular arc, replaced here by lines tangent to it every
    ``arc_step_rad`` (so the result stays outside the arc: conservative by at most a factor
    ``1 / cos(arc_step_rad / 2)`` of the margin there). Edges that vanish as the offset grows
    are removed in the order they vanish. If the offset splits the region, the largest piece
    is returned. Every returned polygon is verified: each of its points is at least
    ``margin_m`` (to 1e-9 relative) from the original boundary.

    Parameters
    ----------
    poly : array_like, shape (K, 2)
        Simple polygon, either orientation.
    margin_m : float
        Offset distance (>= 0).
    arc_step_rad : float
        Angular step of the tangent lines at reflex corners.

    Returns
    -------
    numpy.ndarray, shape (L, 2)
        Counter-clockwise vertices of the offset polygon; ``shape (0, 2)`` if it is empty.
    """
    p = np.asarray(poly, dtype=float)
    scale = max(float(np.ptp(p, axis=0).max()), 1.0)
    if signed_area(p) < 0:
        p = p[::-1]
    p = _clean(p, scale)
    empty = np.zeros((0, 2))
    if len(p) < 3:
        return empty
    if margin_m <= 0:
        return p.copy()
    normals, c0 = _offset_lines(p, arc_step_rad)
    c_m = c0 + margin_m
    while True:
        if len(normals) < 3:
            return empty
        v0 = _intersections(normals, c0)
        vm = _intersections(normals, c_m)
        if v0 is None or vm is None:
            return empty
        dirs = np.stack([normals[:, 1], -normals[:, 0]], axis=1)
        # line i's segment runs from vertex (i-1, i) to vertex (i, i+1)
        len0 = np.einsum("ij,ij->i", v0 - np.roll(v0, 1, axis=0), dirs)
        len_m = np.einsum("ij,ij->i", vm - np.roll(vm, 1, axis=0), dirs)
        bad = len_m < -1e-12 * scale
        if not np.any(bad):
            break
        drop_rate = len0 - len_m
        root = np.where(drop_rate > 0, len0 / np.where(drop_rate > 0, drop_rate, 1.0), -np.inf)
        root = np.where(bad, root, np.inf)
        kill = int(np.argmin(root))
        normals = np.delete(normals, kill, axis=0)
        c0 = np.delete(c0, kill)
        c_m = np.delete(c_m, kill)
    out = _clean(vm, scale)
    if len(out) < 3:
        return empty
    candidates = [out] if polygon_is_simple(out)[0] else _split_loops(out)
    best, best_area = empty, 0.0
    for q in candidates:
        q = _clean(q, scale)
        if len(q) < 3:
            continue
        area = signed_area(q)
        if area <= 1e-12 * scale * scale or not polygon_is_simple(q)[0]:
            continue
        if area > best_area and _verify_offset(q, p, margin_m):
            best, best_area = q, area
    return best


def _verify_offset(inner, outer, margin_m):
    """Every point of ``inner`` is inside ``outer`` and >= margin_m from its boundary."""
    if not point_in_polygon(inner[:1], outer)[0]:
        return False
    ia, ib = _edges(inner)
    oa, ob = _edges(outer)
    dist = segment_distance(ia[:, None, :], ib[:, None, :], oa[None, :, :], ob[None, :, :])
    return bool(np.min(dist) >= margin_m * (1.0 - 1e-9) - 1e-9)
