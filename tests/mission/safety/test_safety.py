"""Safety envelope: geometry primitives, geofence, shrinking, clamping and setpoint checks."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mission.safety.report import EmptyFenceError, SafetyError, SafetyViolation
from mission.safety.fence import Geofence
from mission.safety.envelope import SafetyEnvelope
from mission.safety.geometry import (
    offset_polygon_inward,
    point_in_polygon,
    segment_distance,
    signed_area,
    synchronous_distance,
)

SQUARE = np.array([(0.0, 0.0), (100.0, 0.0), (100.0, 100.0), (0.0, 100.0)])
L_SHAPE = np.array([(0.0, 0.0), (100.0, 0.0), (100.0, 50.0), (50.0, 50.0), (50.0, 100.0), (0.0, 100.0)])
TRIANGLE = np.array([(0.0, 0.0), (60.0, 0.0), (10.0, 80.0)])

coord = st.floats(-50, 50, allow_nan=False, allow_infinity=False)


def _vec(dim):
    return st.lists(coord, min_size=dim, max_size=dim).map(np.array)


def _max_gap(angles):
    a = np.sort(np.asarray(angles))
    return float(np.max(np.diff(np.r_[a, a[0] + 2 * np.pi])))


def _star_polygon(draw_angles, draw_radii):
    """Star-shaped about (50, 50), hence simple (angular gaps < pi are filtered for)."""
    ang = np.sort(np.asarray(draw_angles))
    r = np.asarray(draw_radii)
    return np.stack([50 + r * np.cos(ang), 50 + r * np.sin(ang)], axis=1)


star_polygons = st.integers(3, 9).flatmap(
    lambda k: st.tuples(
        st.lists(st.floats(0, 2 * np.pi - 1e-3), min_size=k, max_size=k, unique=True),
        st.lists(st.floats(15, 60), min_size=k, max_size=k),
    )
).map(lambda t: _star_polygon(*t)).filter(
    lambda p: _max_gap(np.arctan2(p[:, 1] - 50, p[:, 0] - 50)) < 0.9 * np.pi and abs(signed_area(p)) > 200 and np.min(np.diff(np.sort(np.arctan2(p[:, 1] - 50, p[:, 0] - 50)))) > 0.05
)


# ---------------------------------------------------------------- distances vs brute force

@settings(max_examples=60, deadline=None)
@given(dim=st.sampled_from([2, 3]), data=st.data())
def test_segment_distance_matches_brute_force(dim, data):
    a0, a1, b0, b1 = (data.draw(_vec(dim)) for _ in range(4))
    if data.draw(st.booleans()):
        a1 = a0.copy()  # degenerate segment
    s = np.linspace(0, 1, 301)
    pa = a0 + s[:, None] * (a1 - a0)
    pb = b0 + s[:, None] * (b1 - b0)
    brute = np.linalg.norm(pa[:, None] - pb[None, :], axis=-1).min()
    exact = float(segment_distance(a0, a1, b0, b1))
    step = (np.linalg.norm(a1 - a0) + np.linalg.norm(b1 - b0)) / 300
    assert exact <= brute + 1e-9
    assert brute - exact <= step + 1e-9


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_synchronous_distance_matches_brute_force(data):
    p0, p1, q0, q1 = (data.draw(_vec(3)) for _ in range(4))
    t = np.linspace(0, 1, 4001)[:, None]
    brute = np.linalg.norm((p0 + t * (p1 - p0)) - (q0 + t * (q1 - q0)), axis=1).min()
    exact = float(synchronous_distance(p0, p1, q0, q1))
    # the expanded quadratic loses about sqrt(machine eps) relative to the distances involved near a
    # zero: 1.35e-6 m was seen for points ~100 m apart; far below any separation either way
    scale = max(1.0, float(np.linalg.norm(p0 - q0)), float(np.linalg.norm(p1 - q1)))
    tol = 1e-6 + 5e-8 * scale
    assert exact <= brute + tol
    assert brute - exact <= np.linalg.norm((p1 - p0) - (q1 - q0)) / 4000 + tol
    # never more than the end-point distances, never less than the plain segment distance
    assert exact <= min(np.linalg.norm(p0 - q0), np.linalg.norm(p1 - q1)) + tol
    assert exact >= float(segment_distance(p0, p1, q0, q1)) - tol


def test_crossing_paths_collide_although_segments_differ_in_time():
    # two vehicles swapping through the same point at the same time: distance 0
    assert synchronous_distance([0, 0, 0], [10, 0, 0], [10, 0, 0], [0, 0, 0]) == pytest.approx(0.0)
    # crossing lines but one passes the crossing point much later: no collision
    assert synchronous_distance([-5, 0, 0], [5, 0, 0], [0, -1, 0], [0, 19, 0]) > 1.0


# ---------------------------------------------------------------- geofence validation

@pytest.mark.parametrize(
    "poly, lo, hi, match",
    [
        ([(0, 0), (1, 0)], 0, 10, "at least 3"),
        ([(0, 0), (0, 0), (1, 1), (0, 0)], 0, 10, "at least 3"),
        ([(0, 0), (10, 10), (10, 0), (0, 10)], 0, 10, "self-intersecting: edge"),
        ([(0, 0), (5, 0), (10, 0)], 0, 10, "zero area"),
        ([(0, 0), (10, 0), (0, np.nan)], 0, 10, "NaN"),
        (SQUARE, 10, 10, "altitude band is empty"),
        (SQUARE, 20, 10, "min_alt_m=20"),
        (np.zeros((4, 3)), 0, 10, r"shape \(K, 2\)"),
    ],
)
def test_geofence_rejects_bad_input(poly, lo, hi, match):
    with pytest.raises(SafetyError, match=match):
        Geofence(poly, lo, hi)


def test_geofence_accepts_either_orientation_and_a_closing_vertex():
    cw = Geofence(L_SHAPE[::-1], 0, 50)
    closed = Geofence(np.vstack([L_SHAPE, L_SHAPE[:1]]), 0, 50)
    assert cw.area_m2 == pytest.approx(7500.0)
    assert closed.area_m2 == pytest.approx(7500.0)
    assert signed_area(cw.polygon_en_m) > 0


@pytest.mark.parametrize(
    "point, inside, dist",
    [
        ((10, 10, 20), True, 10.0),
        ((75, 75, 20), False, -25.0),
        ((25, 75, 48), True, 2.0),
        ((25, 25, -3), False, -3.0),
        ((110, 25, 60), False, -np.hypot(10, 10)),
    ],
)
def test_contains_and_signed_distance(point, inside, dist):
    fence = Geofence(L_SHAPE, 0, 50)
    assert fence.contains(point) is inside
    assert fence.distance_inside(point) == pytest.approx(dist)


# ---------------------------------------------------------------- clamping

@settings(max_examples=60, deadline=None)
@given(poly=star_polygons, pts=st.lists(st.tuples(st.floats(-100, 200), st.floats(-100, 200),
                                                   st.floats(-50, 150)), min_size=1, max_size=20))
def test_clamp_is_inside_and_nearest(poly, pts):
    fence = Geofence(poly, 10, 60)
    p = np.asarray(pts, dtype=float)
    c = fence.clamp(p)
    assert np.all(fence.contains(c))
    inside = fence.contains(p, 0.0)
    assert np.array_equal(c[inside], p[inside])
    # nearest: no sampled inside point is closer than the clamp result
    rng = np.random.default_rng(0)
    samples = np.c_[rng.uniform(-10, 110, (4000, 2)), rng.uniform(10, 60, 4000)]
    samples = samples[fence.contains(samples, 0.0)]
    d_clamp = np.linalg.norm(p - c, axis=1)
    d_best = np.linalg.norm(p[:, None] - samples[None], axis=-1).min(axis=1)
    assert np.all(d_clamp <= d_best + 1e-9)


# ---------------------------------------------------------------- shrinking

@pytest.mark.parametrize("margin", [0.0, 1.0, 10.0, 49.0])
def test_shrunk_square_is_exact(margin):
    inner = Geofence(SQUARE, 0, 200).shrunk(margin)
    lo, hi = margin, 100 - margin
    assert inner.area_m2 == pytest.approx((hi - lo) ** 2)
    assert np.allclose(np.sort(inner.polygon_en_m, axis=0), np.sort(
        np.array([(lo, lo), (hi, lo), (hi, hi), (lo, hi)]), axis=0))
    assert inner.min_alt_m == margin and inner.max_alt_m == 200 - margin


def test_shrunk_triangle_is_exact():
    margin = 5.0
    inner = offset_polygon_inward(TRIANGLE, margin)
    assert len(inner) == 3
    # every edge of the result is parallel to the original one at distance margin
    d = [float(np.min(np.abs(_line_distances(TRIANGLE, v)))) for v in inner]
    assert np.allclose(d, margin)


def _line_distances(poly, v):
    a, b = poly, np.roll(poly, -1, axis=0)
    e = b - a
    return ((v - a)[:, 0] * e[:, 1] - (v - a)[:, 1] * e[:, 0]) / np.linalg.norm(e, axis=1)


@pytest.mark.parametrize("poly", [SQUARE, L_SHAPE, TRIANGLE], ids=["square", "L", "triangle"])
@pytest.mark.parametrize("margin", [2.0, 8.0, 20.0])
def test_shrunk_polygon_is_the_erosion(poly, margin):
    """Sound (every point of the result is >= margin from the boundary) and nearly complete
    (every point >= margin * 1.02 from the boundary is in the result: reflex corners are
    approximated by tangent lines every pi/8). Every case is non-empty (the L's arms are 50 m
    wide, the triangle's inradius is 20.4 m): EmptyFenceError here is a failure."""
    fence = Geofence(poly, 0, 1000)
    inner = fence.shrunk(margin, alt_margin_m=0.0)
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-5, 105, (20000, 2)), np.full(20000, 500.0)]
    depth = fence.distance_inside(pts)
    in_inner = inner.contains(pts, 0.0)
    assert np.all(depth[in_inner] >= margin - 1e-9)
    assert np.all(in_inner[depth >= margin * 1.02 + 1e-9])


def test_shrunk_l_shape_keeps_its_notch():
    inner = Geofence(L_SHAPE, 0, 100).shrunk(10.0)
    assert inner.contains((30, 80, 50)) and inner.contains((80, 30, 50))
    assert not inner.contains((45, 45, 50))  # within 10 m of the reflex corner (50, 50)
    assert inner.contains((35, 35, 50))


@pytest.mark.parametrize(
    "margin, alt, match",
    [(50.0, 0.0, "geofence shrunk by 50 m is empty"), (60.0, 0.0, "empty"),
     (1.0, 30.0, "altitude band 0..50 m shrunk by 30 m is empty")],
)
def test_shrunk_empty_says_so(margin, alt, match):
    with pytest.raises(EmptyFenceError, match=match):
        Geofence(SQUARE, 0, 50).shrunk(margin, alt)


def test_shrunk_dumbbell_keeps_one_safe_lobe():
    db = np.array([(0, 0), (10, 0), (10, 4), (20, 4), (20, 0), (30, 0), (30, 10), (20, 10),
                   (20, 6), (10, 6), (10, 10), (0, 10)], dtype=float)
    fence = Geofence(db, 0, 10)
    inner = fence.shrunk(1.5, 0.0)
    pts = np.c_[inner.polygon_en_m, np.full(len(inner.polygon_en_m), 5.0)]
    assert np.all(fence.distance_inside(pts) >= 1.5 - 1e-9)
    assert inner.area_m2 == pytest.approx(49.0, rel=0.05)


# ---------------------------------------------------------------- the envelope

def _envelope(poly=L_SHAPE, speed=5.0, sep=2.0, radius=4.0):
    return SafetyEnvelope(Geofence(poly, 5, 60), speed, sep, radius)


@pytest.mark.parametrize(
    "kwargs, match",
    [({"speed": 0.0}, "max_speed_m_s"), ({"sep": -1.0}, "min_separation_m"),
     ({"radius": float("nan")}, "formation_radius_m"), ({"radius": 40.0}, "does not fit")],
)
def test_envelope_rejects_bad_limits(kwargs, match):
    with pytest.raises(SafetyError, match=match):
        _envelope(**kwargs)


def test_source_outside_fence_stops_at_boundary():
    env = _envelope()
    res = env.clamp_centre([20, 20, 30], [250, 20, 30])
    assert res.at_boundary
    assert "stopped at the boundary" in res.message
    assert res.centre_enu == pytest.approx([96.0, 20.0, 30.0])
    assert env.fence.distance_inside(res.centre_enu) >= 4.0 - 1e-9


def test_centre_move_across_the_notch_stops_where_it_would_leave():
    env = _envelope()
    res = env.clamp_centre([20, 80, 30], [80, 20, 30])  # both inside, straight line crosses the notch
    assert res.at_boundary and "straight line" in res.message
    assert env.centre_fence.segment_inside([20, 80, 30], res.centre_enu)


@settings(max_examples=80, deadline=None)
@given(prev=st.tuples(st.floats(4, 96), st.floats(4, 46), st.floats(9, 56)),
       new=st.tuples(st.floats(-100, 200), st.floats(-100, 200), st.floats(-50, 150)))
def test_clamped_centre_keeps_formation_inside(prev, new):
    env = _envelope()
    res = env.clamp_centre(prev, new)
    assert env.fence.distance_inside(res.centre_enu) >= 4.0 - 1e-6
    assert res.at_boundary == (not np.allclose(res.centre_enu, new))


def test_check_setpoints_reports_every_kind():
    env = _envelope(speed=5.0, sep=2.0)
    prev = np.array([[10, 10, 20], [20, 10, 20], [30, 10, 20], [90, 10, 20], [10, 90, 20], [40, 40, 20]], float)
    new = prev.copy()
    new[0] = [20, 10, 20]      # swaps with vehicle 1 -> collides on the way (path)
    new[1] = [10, 10, 20]
    new[2] = [30, 10, 70]      # above the band, 50 m in 1 s -> altitude + speed
    new[3] = [90, 90, 20]      # outside the L fence
    new[4] = [45, 45, 20]      # inside, but the path ... stays inside; fine
    new[5] = [60, 45, 20]      # inside at both ends
    rep = env.check_setpoints(prev, new, dt_s=1.0)
    kinds = {(v.kind, v.vehicles) for v in rep.violations}
    assert ("separation_path", (0, 1)) in kinds
    assert ("altitude", (2,)) in kinds and ("speed", (2,)) in kinds
    assert ("fence", (3,)) in kinds
    assert not rep.ok and "outside the geofence" in str(rep)


def test_check_setpoints_flags_a_path_through_the_notch():
    env = _envelope(speed=100.0)
    rep = env.check_setpoints([[20, 90, 20]], [[90, 20, 20]], dt_s=1.0)
    assert rep.kinds() == {"fence_path"}


def test_check_setpoints_end_separation():
    env = _envelope(sep=3.0)
    rep = env.check_setpoints([[10, 10, 20], [20, 10, 20]], [[14, 10, 20], [16, 10, 20]], 10.0)
    assert rep.kinds() == {"separation"} and rep.min_separation_m == pytest.approx(2.0)


@settings(max_examples=60, deadline=None)
@given(data=st.data(), n=st.integers(1, 6), dt=st.floats(0.05, 1.0),
       poly=st.sampled_from([SQUARE, L_SHAPE, TRIANGLE]))
def test_clamp_setpoints_always_inside_and_speed_limited(data, n, dt, poly):
    env = SafetyEnvelope(Geofence(poly, 5, 60), 4.0, 0.0, 0.0)
    prev = np.array(data.draw(st.lists(st.tuples(st.floats(-20, 120), st.floats(-20, 120), st.floats(-10, 80)),
                                       min_size=n, max_size=n)))
    new = np.array(data.draw(st.lists(st.tuples(st.floats(-200, 300), st.floats(-200, 300), st.floats(-100, 200)),
                                      min_size=n, max_size=n)))
    res = env.clamp_setpoints(prev, new, dt)
    out = res.positions_enu
    assert np.all(env.fence.contains(out))
    was_inside = env.fence.contains(prev)
    step = np.linalg.norm(out - prev, axis=1)
    assert np.all(step[was_inside] <= 4.0 * dt * (1 + 1e-9))
    for i in np.nonzero(was_inside)[0]:
        assert env.fence.segment_inside(prev[i], out[i])
    assert not ({"fence", "altitude", "fence_path"} & res.report.kinds())


def test_clamp_setpoints_leaves_safe_setpoints_alone():
    env = _envelope()
    prev = np.array([[10, 10, 20], [20, 20, 20]], float)
    new = prev + [0.3, 0.2, 0.1]
    res = env.clamp_setpoints(prev, new, 0.1)
    assert np.array_equal(res.positions_enu, new)
    assert not res.fence_clamped.any() and not res.speed_limited.any() and res.report.ok


def test_assert_safe_raises_on_a_fence_breach():
    env = _envelope()
    with pytest.raises(SafetyViolation, match=r"vehicles \[1\] would leave the geofence"):
        env.assert_safe([[10, 10, 20], [10, 20, 20]], [[10, 10, 20], [10, 20, 61]], 1.0)
    with pytest.raises(SafetyViolation, match="speed limit"):
        env.assert_safe([[10, 10, 20]], [[30, 10, 20]], 1.0)


@pytest.mark.parametrize(
    "prev, new, dt, match",
    [(np.zeros((2, 3)), np.zeros((3, 3)), 1.0, "both be"), (np.zeros((2, 3)), np.zeros((2, 3)), 0.0, "dt_s"),
     (np.zeros((2, 2)), np.zeros((2, 2)), 1.0, "shape"), ([[0, 0, np.nan]], [[0, 0, 0]], 1.0, "NaN")],
)
def test_setpoint_functions_reject_bad_input(prev, new, dt, match):
    with pytest.raises(ValueError, match=match):
        _envelope().check_setpoints(prev, new, dt)


def test_point_in_polygon_is_boundary_inclusive():
    assert point_in_polygon(np.array([[0.0, 50.0], [100.0, 100.0], [-1e-3, 50.0]]), SQUARE).tolist() == [
        True, True, False]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 12), step=st.floats(0.0, 30.0))
def test_pair_pruning_matches_the_dense_check(seed, n, step):
    from mission.safety.envelope import pairwise_path_separation

    rng = np.random.default_rng(seed)
    prev = np.c_[rng.uniform(10, 40, (n, 2)), rng.uniform(10, 40, n)]
    new = prev + rng.normal(0, step, (n, 3))
    env = SafetyEnvelope(Geofence(SQUARE, 0, 100), 1e6, 3.0, 0.0)
    rep = env.check_setpoints(prev, new, 1.0)
    dense = pairwise_path_separation(prev, new)
    assert rep.min_separation_m == pytest.approx(dense.min(), abs=1e-6)
    flagged = {v.vehicles for v in rep.violations if v.kind.startswith("separation")}
    expected = {(i, j) for i in range(n) for j in range(i + 1, n) if dense[i, j] < 3.0 * (1 - 1e-9)}
    assert flagged == expected


@settings(max_examples=60, deadline=None)
@given(poly=star_polygons, a=st.tuples(st.floats(0, 1), st.floats(0, 1)),
       b=st.tuples(st.floats(-60, 160), st.floats(-60, 160)))
def test_inside_fraction_matches_sampling(poly, a, b):
    from mission.safety.geometry import inside_fraction

    # a start point inside: somewhere between the centre (50, 50) and a vertex
    k = int(a[0] * (len(poly) - 1))
    p0 = np.array([50.0, 50.0]) + 0.9 * a[1] * (poly[k] - [50.0, 50.0])
    p1 = np.asarray(b, dtype=float)
    f = float(inside_fraction(p0, p1, poly))
    t = np.linspace(0, 1, 4001)
    pts = p0 + t[:, None] * (p1 - p0)
    inside = point_in_polygon(pts, poly, 1e-7)
    assert np.all(inside[t < f - 1e-6])  # sound: everything before f is inside
    if not np.all(inside):
        assert f <= t[np.argmax(~inside)] + 1e-9  # complete: stops before the first outside sample
