"""Exact spherical Voronoi cells and the constrained CVT on the sphere."""
import math

import numpy as np
import pytest
from scipy.spatial import SphericalVoronoi, cKDTree

from formation import (
    cell_areas,
    constrained_centroids,
    cvt_energy,
    cvt_energy_gradient,
    cvt_from,
    cvt_sphere,
    cvt_sphere_result,
    delaunay_neighbours,
    metrics,
    random_sphere_points,
    spherical_cells,
    symmetric_cylinder,
)
from formation.cvt import FAST_MIN_N, fibonacci_start
from formation.spherical_cells import _Triangulation


def _fibonacci(m):
    k = np.arange(m) + 0.5
    z = 1.0 - 2.0 * k / m
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    rho = np.sqrt(1.0 - z * z)
    return np.c_[rho * np.cos(phi), rho * np.sin(phi), z]


@pytest.fixture(scope="module")
def quadrature():
    """Equal-weight quasi-uniform quadrature of the unit sphere (independent of the code)."""
    u = _fibonacci(400_000)
    return u, 4.0 * math.pi / len(u)


@pytest.mark.parametrize("n", [4, 7, 25])
@pytest.mark.parametrize("seed", [1, 2])
def test_cell_integrals_match_quadrature(n, seed, quadrature):
    u, w = quadrature
    p = random_sphere_points(n, seed)
    cells = spherical_cells(p)
    idx = cKDTree(p).query(u)[1]
    area_q = np.bincount(idx, minlength=n) * w
    cint_q = np.stack([np.bincount(idx, weights=u[:, k], minlength=n) for k in range(3)], 1) * w
    energy_q = w * np.sum((u - p[idx]) ** 2)
    np.testing.assert_allclose(cells.areas, area_q, atol=2e-3)
    np.testing.assert_allclose(cells.centroid_integrals, cint_q, atol=2e-3)
    assert cells.energy == pytest.approx(energy_q, rel=1e-3)
    np.testing.assert_allclose(cells.areas, SphericalVoronoi(p).calculate_areas(), atol=1e-12)


@pytest.mark.parametrize("n", [4, 5, 11, 60])
def test_areas_sum_to_4pi_even_in_one_hemisphere(n):
    p = random_sphere_points(n, 3)
    p[:, 2] = np.abs(p[:, 2]) + 0.3  # all generators in the upper hemisphere
    areas = cell_areas(p)
    assert np.all(areas > 0)
    assert areas.sum() == pytest.approx(4 * math.pi, abs=1e-12)


def test_facets_are_counter_clockwise_from_outside():
    cells = spherical_cells(random_sphere_points(50, 8))
    a, b, c = (cells.points[cells.facets[:, k]] for k in range(3))
    assert cells.facets.shape == (2 * 50 - 4, 3)
    assert np.all(np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) > 0)


def test_cocircular_generators_are_handled():
    # the symmetric cylinder has 4 co-circular points per circle: zero-length Voronoi edges
    cells = spherical_cells(symmetric_cylinder(8))
    np.testing.assert_allclose(cells.areas, 4 * math.pi / 8, rtol=1e-12)
    assert np.all(np.isfinite(cells.centroids))


@pytest.mark.parametrize("seed", [0, 5])
def test_energy_gradient_matches_finite_differences(seed):
    p = random_sphere_points(12, seed)
    _, grad = cvt_energy_gradient(p)
    rng = np.random.default_rng(seed + 100)
    t = rng.normal(size=p.shape)
    t -= np.einsum("ij,ij->i", t, p)[:, None] * p  # tangent direction
    h = 1e-6
    fd = (cvt_energy(p + h * t) - cvt_energy(p - h * t)) / (2 * h)
    assert fd == pytest.approx(np.sum(grad * t), rel=1e-5)


@pytest.mark.parametrize("n", [4, 5, 9, 16, 33])
@pytest.mark.parametrize("radius", [1.0, 4.0])
def test_cvt_on_sphere_and_lloyd_fixed_point(n, radius):
    r = cvt_sphere(n, radius=radius, seed=1)
    assert r.shape == (n, 3)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), radius, rtol=1e-14)
    areas = cell_areas(r)
    assert areas.sum() == pytest.approx(4 * math.pi, abs=1e-11)
    step = constrained_centroids(r) - r / radius
    assert np.max(np.linalg.norm(step, axis=1)) < 1e-8


@pytest.mark.parametrize("n", [6, 8, 10, 12, 20])
def test_lbfgs_reaches_lloyd_energy(n):
    lloyd = cvt_sphere_result(n, seed=0, method="lloyd")
    fast = cvt_sphere_result(n, seed=0, method="lbfgs")
    assert lloyd.converged and fast.converged
    assert fast.energy == pytest.approx(lloyd.energy, rel=1e-7)
    assert fast.evaluations <= lloyd.evaluations + 1  # +1: energy after the Lloyd warm-up


@pytest.mark.parametrize("n", [8, 12])
def test_scipy_lbfgs_reaches_lloyd_energy(n):
    lloyd = cvt_sphere_result(n, seed=0, method="lloyd")
    fast = cvt_sphere_result(n, seed=0, method="lbfgs-scipy")
    assert fast.converged
    assert fast.energy == pytest.approx(lloyd.energy, rel=1e-7)


def test_known_optimal_configurations():
    tetra = cvt_sphere(4)
    assert metrics(tetra).d_min == pytest.approx(math.sqrt(8.0 / 3.0), rel=1e-8)
    octa = cvt_sphere(6)
    assert metrics(octa).d_min == pytest.approx(math.sqrt(2.0), rel=1e-8)
    assert metrics(octa).norm_M_alpha == pytest.approx(0.0, abs=1e-8)


@pytest.mark.parametrize("method", ["lbfgs", "lloyd"])
def test_deterministic_for_a_seed(method):
    a = cvt_sphere(13, seed=7, method=method)
    b = cvt_sphere(13, seed=7, method=method)
    np.testing.assert_array_equal(a, b)


def test_n_starts_keeps_lowest_energy():
    single = [cvt_sphere_result(20, seed=s).energy for s in range(3)]
    best = cvt_sphere_result(20, seed=0, n_starts=3)
    assert best.energy == pytest.approx(min(single), rel=1e-12)


def test_warm_start_keeps_a_cvt():
    p = cvt_sphere(15)
    res = cvt_from(p * 3.0)
    assert res.iterations <= 1
    np.testing.assert_allclose(res.points, p, atol=1e-9)


def test_delaunay_neighbours_are_symmetric():
    nb = delaunay_neighbours(random_sphere_points(30, 4))
    assert sum(len(x) for x in nb) == 2 * (3 * 30 - 6)  # Euler: 3n - 6 edges
    for i, row in enumerate(nb):
        assert i not in row
        assert all(i in nb[j] for j in row)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n": 3}, "n >= 4"),
        ({"n": 4.5}, "integer"),
        ({"n": 8, "radius": 0.0}, "radius"),
        ({"n": 8, "radius": -2.0}, "radius"),
        ({"n": 8, "method": "newton"}, "method"),
        ({"n": 8, "tol": 0.0}, "tol"),
        ({"n": 8, "max_iter": 0}, "max_iter"),
        ({"n": 8, "n_starts": 0}, "n_starts"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        cvt_sphere(**kwargs)


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((3, 3)) + 1.0, "at least 4"),
        (np.vstack([np.eye(3), np.zeros((1, 3))]), "non-zero"),
        (np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]]), "degenerate"),
        (np.array([[1.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, -1]]), "coincident"),
    ],
)
def test_degenerate_generators(points, match):
    with pytest.raises(ValueError, match=match):
        spherical_cells(points)


# --- fast path (method="fast"): same quality as the plain solver, same cells -----------------


@pytest.mark.parametrize("n", [8, 20, 100, 500])
def test_fast_path_same_quality_as_plain(n):
    plain = cvt_sphere_result(n, seed=0, method="lbfgs")
    fast = cvt_sphere_result(n, seed=0, method="fast")
    assert plain.converged and fast.converged
    assert fast.method == "fast"
    # a Lloyd fixed point (checked with the plain exact cells, not the fast evaluator)
    step = constrained_centroids(fast.points) - fast.points
    assert np.max(np.linalg.norm(step, axis=1)) < 1e-9
    # quality: energy not more than 1 % higher, d_min not more than 1 % lower
    assert fast.energy <= plain.energy * 1.01
    assert metrics(fast.points).d_min >= metrics(plain.points).d_min * 0.99
    assert abs(fast.energy - cvt_energy(fast.points)) < 1e-12
    assert fast.evaluations < plain.evaluations


def test_fast_path_deterministic_for_a_seed():
    a = cvt_sphere_result(300, seed=3, method="fast")
    b = cvt_sphere_result(300, seed=3, method="fast")
    np.testing.assert_array_equal(a.points, b.points)
    c = cvt_sphere_result(300, seed=4, method="fast")
    assert not np.allclose(a.points, c.points)  # another seed: another orientation


def test_auto_method_switches_at_fast_min_n():
    assert cvt_sphere_result(FAST_MIN_N - 1, seed=0, max_iter=1).method == "lbfgs"
    assert cvt_sphere_result(FAST_MIN_N, seed=0, max_iter=1).method == "fast"
    # below the switch the default is exactly the plain solver (mission formations unchanged)
    np.testing.assert_array_equal(cvt_sphere(12, seed=2), cvt_sphere(12, seed=2, method="lbfgs"))


@pytest.mark.parametrize("n", [8, 30, 400])
def test_kept_triangulation_matches_convex_hull_cells(n):
    rng = np.random.default_rng(n)
    p = fibonacci_start(n, 1)
    tri = _Triangulation()
    spacing = math.sqrt(4.0 * math.pi / n)
    for _ in range(60):
        p = p + 0.03 * spacing * rng.normal(size=p.shape)
        p /= np.linalg.norm(p, axis=1)[:, None]
        areas, cint, energy = tri.cells(p)
        ref = spherical_cells(p)
        np.testing.assert_allclose(cint, ref.centroid_integrals, rtol=0, atol=1e-13)
        np.testing.assert_allclose(areas, ref.areas, rtol=0, atol=1e-13)
        assert energy == pytest.approx(ref.energy, abs=1e-13)
        # the fast solver's energy from the tiling identity (areas sum to 4 pi), no areas
        cint_only, energy_tiled = tri.centroids_and_energy(p)
        np.testing.assert_array_equal(cint_only, cint)
        assert energy_tiled == pytest.approx(ref.energy, abs=1e-12)
    assert tri.flips > 0  # the repair path was exercised, not only fresh hulls


def test_fibonacci_start_is_rotated_unit_points():
    a, b = fibonacci_start(50, 0), fibonacci_start(50, 1)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, rtol=1e-14)
    # a rotation keeps every pairwise distance
    np.testing.assert_allclose(
        np.linalg.norm(a[:, None] - a[None], axis=2),
        np.linalg.norm(b[:, None] - b[None], axis=2),
        atol=1e-12,
    )


def test_warm_start_fast_keeps_a_cvt():
    p = cvt_sphere(FAST_MIN_N, seed=0)
    res = cvt_from(p, method="fast")
    assert res.converged and res.iterations <= 1
    np.testing.assert_allclose(res.points, p, atol=1e-9)
