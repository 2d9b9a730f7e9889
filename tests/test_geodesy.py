"""formation.geodesy against published reference points and independent closed forms."""
import math

import numpy as np
import pymap3d
import pytest

from formation.geodesy import (
    WGS84_A_M,
    WGS84_F,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
)

WGS84_B_M = 6356752.314245  # published WGS-84 semi-minor axis
E2 = WGS84_F * (2.0 - WGS84_F)

# (lat_deg, lon_deg, alt_m) -> ECEF metres; the first is the MATLAB-checked point of pymap3d's
# own tests, the others follow from the ellipsoid's published axes
REFERENCE_POINTS = [
    ((42.0, -82.0, 200.0), (660675.2518247, -4700948.68316, 4245737.66222)),
    ((0.0, 0.0, 0.0), (WGS84_A_M, 0.0, 0.0)),
    ((0.0, 90.0, 0.0), (0.0, WGS84_A_M, 0.0)),
    ((0.0, 180.0, 100.0), (-(WGS84_A_M + 100.0), 0.0, 0.0)),
    ((90.0, 0.0, 0.0), (0.0, 0.0, WGS84_B_M)),
    ((-90.0, 0.0, -10.0), (0.0, 0.0, -(WGS84_B_M - 10.0))),
]


def test_constants_match_pymap3d_wgs84():
    ell = pymap3d.Ellipsoid.from_name("wgs84")
    assert ell.semimajor_axis == WGS84_A_M
    assert ell.semiminor_axis == pytest.approx(WGS84_B_M, abs=1e-6)
    assert ell.flattening == pytest.approx(WGS84_F, rel=1e-12)


@pytest.mark.parametrize("lla, xyz", REFERENCE_POINTS)
def test_published_ecef_of_known_points(lla, xyz):
    assert np.allclose(geodetic_to_ecef(*lla), xyz, rtol=0.0, atol=1e-3)
    lat, lon, alt = ecef_to_geodetic(np.array(xyz))
    assert lat == pytest.approx(lla[0], abs=1e-9)
    if abs(lla[0]) < 90.0:  # longitude is undefined at the poles
        assert lon == pytest.approx(lla[1], abs=1e-9)
    assert alt == pytest.approx(lla[2], abs=1e-3)


def test_geodetic_ecef_round_trip_is_sub_millimetre_over_arrays():
    rng = np.random.default_rng(3)
    lat = rng.uniform(-89.5, 89.5, 2000)
    lon = rng.uniform(-180.0, 180.0, 2000)
    alt = rng.uniform(-500.0, 20_000.0, 2000)
    back_lat, back_lon, back_alt = ecef_to_geodetic(geodetic_to_ecef(lat, lon, alt))
    assert np.abs(back_lat - lat).max() < 1e-9
    assert np.abs((back_lon - lon + 180.0) % 360.0 - 180.0).max() < 1e-9
    assert np.abs(back_alt - alt).max() < 1e-4


@pytest.mark.parametrize("lat0_deg", [0.0, 45.1885, 47.397742, -33.9])
def test_point_one_km_north_is_1000_m_north_and_below_the_tangent_plane(lat0_deg):
    origin = (lat0_deg, 8.545594, 488.0)
    s_m = 1000.0

    def meridian_radius_m(lat_deg):
        s = math.sin(math.radians(lat_deg))
        return WGS84_A_M * (1.0 - E2) / (1.0 - E2 * s * s) ** 1.5

    # latitude 1 km of meridian arc north at the origin's height (radius of curvature at the
    # arc's midpoint plus the height)
    dlat_rad = s_m / (meridian_radius_m(lat0_deg) + origin[2])
    for _ in range(3):
        dlat_rad = s_m / (meridian_radius_m(lat0_deg + math.degrees(dlat_rad) / 2.0) + origin[2])
    r_m = meridian_radius_m(lat0_deg + math.degrees(dlat_rad) / 2.0) + origin[2]
    east, north, up = geodetic_to_enu(lat0_deg + math.degrees(dlat_rad), origin[1], origin[2], origin)
    assert east == pytest.approx(0.0, abs=1e-6)
    assert north == pytest.approx(r_m * math.sin(dlat_rad), abs=1e-3)
    assert up == pytest.approx(-r_m * (1.0 - math.cos(dlat_rad)), abs=1e-3)  # about -7.9 cm
    lat, lon, alt = enu_to_geodetic(np.array([east, north, up]), origin)
    assert (lat, lon, alt) == pytest.approx((lat0_deg + math.degrees(dlat_rad), origin[1], origin[2]),
                                            abs=1e-9)


def test_enu_round_trip_and_shapes():
    origin = (45.1885, 5.7245, 212.0)
    rng = np.random.default_rng(4)
    enu = rng.uniform(-3000.0, 3000.0, (4, 50, 3))
    lat, lon, alt = enu_to_geodetic(enu, origin)
    assert lat.shape == lon.shape == alt.shape == (4, 50)
    back = geodetic_to_enu(lat, lon, alt, origin)
    assert back.shape == enu.shape
    assert np.abs(back - enu).max() < 1e-6
    # scalars in: a (3,) vector out; mixed scalar / array inputs broadcast
    assert geodetic_to_enu(45.19, 5.72, 200.0, origin).shape == (3,)
    assert geodetic_to_ecef(45.0, np.array([1.0, 2.0]), 0.0).shape == (2, 3)
    assert geodetic_to_enu(np.zeros((2, 4)) + 45.0, 5.7, 0.0, origin).shape == (2, 4, 3)


@pytest.mark.parametrize("origin", [(45.1885, 5.7245, 212.0), (-33.9, 151.2, 40.0), (0.0, 0.0, 0.0),
                                    (69.6, 18.9, 5.0)])
def test_the_mock_autopilots_fast_local_frame_agrees_with_pymap3d(origin):
    """sitl_mock.ap_geo keeps scalar WGS-84 maths for the mock's 50 Hz loop: it must agree."""
    from sitl_mock.ap_geo import LocalFrame

    frame = LocalFrame(origin)
    rng = np.random.default_rng(7)
    for north_m, east_m, down_m in rng.uniform(-2000.0, 2000.0, size=(200, 3)):
        lat, lon, alt = frame.ned_to_geodetic(north_m, east_m, down_m)
        ref = enu_to_geodetic(np.array([east_m, north_m, -down_m]), origin)
        back = geodetic_to_enu(lat, lon, alt, origin)
        assert np.allclose(back, [east_m, north_m, -down_m], atol=1e-3), (back, ref)
        assert abs(lat - ref[0]) < 1e-8 and abs(lon - ref[1]) < 1e-8 and abs(alt - ref[2]) < 1e-3
