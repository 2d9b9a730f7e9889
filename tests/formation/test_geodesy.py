"""formation.geodesy against published reference points and independent closed forms.

Its scalar :class:`~formation.geodesy.TangentFrame` (the readings' and the mock autopilot's hot
path) agrees with pymap3d's array maths to within :data:`_ULPS` units in the last place, on random
points and on a grid: it calls ``math.sin``/``math.cos`` where pymap3d calls numpy's, whose
vectorised float64 routines may round the last bit differently on some CPUs (hypothesis found
1.1067048847885922e-05 against ...924e-05 degrees).
"""
import math

import numpy as np
import pymap3d
import pytest

from hypothesis import given, settings
from hypothesis import strategies as st

from formation.geodesy import (
    WGS84_A_M,
    WGS84_F,
    TangentFrame,
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


#: units in the last place allowed between TangentFrame and pymap3d
_ULPS = 4


def _same(got, want) -> bool:
    """``got`` and ``want`` (sequences of floats) within :data:`_ULPS` units in the last place."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    return got.shape == want.shape and bool(np.all(np.abs(got - want) <= _ULPS * np.spacing(np.maximum(
        np.abs(got), np.abs(want)))))


_LAT = st.floats(-90, 90)
_LON = st.floats(-180, 180)


@settings(max_examples=1000, deadline=None)
@given(_LAT, _LON, st.floats(-500, 9000), _LAT, _LON, st.floats(-1000, 1e6), st.booleans())
def test_tangent_frame_geodetic_to_enu_agrees_with_pymap3d(lat0, lon0, alt0, lat, lon, alt, near):
    origin = (lat0, lon0, alt0)
    if near:   # the mission's case: within a few km of the origin
        lat, lon = min(90.0, max(-90.0, lat0 + lat * 1e-3)), min(180.0, max(-180.0, lon0 + lon * 1e-3))
    got = TangentFrame(origin).geodetic_to_enu_m(lat, lon, alt)
    assert all(type(v) is float for v in got)
    want = tuple(geodetic_to_enu(lat, lon, alt, origin).tolist())
    assert _same(got, want), (got, want)


@settings(max_examples=1000, deadline=None)
@given(_LAT, _LON, st.floats(-500, 9000), st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-1e4, 1e6),
       st.sampled_from([1e-3, 1.0, 1e3]))
def test_tangent_frame_enu_to_geodetic_agrees_with_pymap3d(lat0, lon0, alt0, east_m, north_m, up_m, scale):
    origin = (lat0, lon0, alt0)
    enu = (east_m * scale, north_m * scale, up_m)
    got = TangentFrame(origin).enu_to_geodetic(*enu)
    assert all(type(v) is float for v in got)
    want = tuple(float(v) for v in enu_to_geodetic(np.array(enu), origin))
    assert _same(got, want), (got, want)


def test_tangent_frame_agrees_with_pymap3d_on_a_grid():
    """Origins every 15 degrees (poles included), points up to 20 km out, 0-5 km up and down.

    pymap3d's answers for an origin's 100 points come from one array call each way (elementwise
    maths: the same floats as 100 scalar calls, a fraction of the CPU); the frame is called per point."""
    grid = np.array([(east_m, north_m, up_m)
                     for east_m in (-20000.0, -150.5, 0.0, 3.25, 20000.0)
                     for north_m in (-20000.0, -7.75, 0.0, 150.5, 20000.0)
                     for up_m in (-5000.0, 0.0, 42.0, 5000.0)])
    checked = 0
    for lat0 in np.arange(-90.0, 90.1, 15.0):
        for lon0 in np.arange(-180.0, 180.1, 45.0):
            origin = (float(lat0), float(lon0), 212.0)
            frame = TangentFrame(origin)
            lats, lons, alts = enu_to_geodetic(grid, origin)
            backs = geodetic_to_enu(lats, lons, alts, origin)
            for (east_m, north_m, up_m), lat, lon, alt, back in zip(grid.tolist(), lats.tolist(), lons.tolist(),
                                                                     alts.tolist(), backs.tolist()):
                assert _same(frame.enu_to_geodetic(east_m, north_m, up_m), (lat, lon, alt)), (origin, east_m)
                assert _same(frame.ned_to_geodetic(north_m, east_m, -up_m), (lat, lon, alt))
                assert _same(frame.geodetic_to_enu_m(lat, lon, alt), back)
                checked += 1
    assert checked == 13 * 9 * 100


def test_tangent_frame_hands_pymap3d_its_special_cases():
    """The Earth's centre and a point on its axis go to pymap3d's own branches, same answer."""
    frame = TangentFrame((10.0, 20.0, 0.0))
    for xyz in ((0.0, 0.0, 0.0), (0.0, 0.0, 6356752.0), (0.0, 0.0, -7000000.0)):
        ref = tuple(float(v) for v in pymap3d.ecef2geodetic(np.asarray(xyz[0]), np.asarray(xyz[1]), np.asarray(xyz[2])))
        assert frame.ecef_to_geodetic(*xyz) == ref
