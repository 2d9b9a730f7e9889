"""Tests of the shared foundations: geodesy, simulated fields, fault settings, CLI registry."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from formation.geodesy import (
    enu_to_geodetic,
    enu_to_ned,
    geodetic_to_ecef,
    geodetic_to_enu,
    ned_to_enu,
)
from sitl_mock.faults import FAULT_NAMES, FaultSet, parse_fault
from sitl_mock.fields_gaussian import GaussianField, S1, S2, SumField, sigma1, sigma2
from sitl_mock.fields_config import make_field

ORIGIN = (45.1885, 5.7245, 212.0)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(-100, 500),
    st.floats(-80, 80), st.floats(-179, 179),
)
def test_enu_geodetic_round_trip_is_millimetre_exact(e, n, u, lat, lon):
    origin = (lat, lon, 100.0)
    enu = np.array([e, n, u])
    back = geodetic_to_enu(*enu_to_geodetic(enu, origin), origin)
    assert np.allclose(back, enu, atol=1e-3)


def test_enu_axes_point_east_north_up():
    # 100 m north raises latitude only; 100 m east raises longitude only; up raises altitude
    lat, lon, alt = enu_to_geodetic(np.array([0.0, 100.0, 0.0]), ORIGIN)
    assert lat > ORIGIN[0] and abs(lon - ORIGIN[1]) < 1e-9
    lat, lon, alt = enu_to_geodetic(np.array([100.0, 0.0, 0.0]), ORIGIN)
    assert lon > ORIGIN[1] and abs(lat - ORIGIN[0]) < 1e-6
    lat, lon, alt = enu_to_geodetic(np.array([0.0, 0.0, 10.0]), ORIGIN)
    assert alt == pytest.approx(ORIGIN[2] + 10.0, abs=1e-6)
    # one degree of latitude is ~111 km
    d = geodetic_to_enu(ORIGIN[0] + 1.0, ORIGIN[1], ORIGIN[2], ORIGIN)
    assert 110_000 < d[1] < 112_000


def test_ecef_equator_prime_meridian():
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [6378137.0, 0.0, 0.0])


def test_ned_enu_swap_is_an_involution():
    v = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]])
    assert np.array_equal(ned_to_enu(enu_to_ned(v)), v)
    assert np.array_equal(enu_to_ned(v)[0], [2.0, 1.0, -3.0])


@pytest.mark.parametrize("field", [sigma1((3.0, -2.0, 5.0)), sigma2((10.0, 4.0, -1.0))])
def test_field_gradient_and_hessian_match_finite_differences(field):
    rng = np.random.default_rng(1)
    p = rng.normal(size=(5, 3)) * 8.0
    h = 1e-5
    fd = np.stack([(field.value(p + h * e) - field.value(p - h * e)) / (2 * h) for e in np.eye(3)], -1)
    assert np.allclose(fd, field.gradient(p), rtol=1e-6, atol=1e-9)
    fdh = np.stack([(field.gradient(p + h * e) - field.gradient(p - h * e)) / (2 * h) for e in np.eye(3)], -1)
    assert np.allclose(fdh, field.hessian(p), rtol=1e-5, atol=1e-8)


def test_paper_fields_have_their_published_parameters():
    assert sigma1().amplitude == 100.0 and sigma2().amplitude == 1.0
    assert S1[0, 0] == pytest.approx(0.01) and S1[2, 2] == pytest.approx(0.001)
    assert S2[2, 2] == pytest.approx(0.01) and S2[0, 1] == pytest.approx(5e-4)
    src = np.array([7.0, -3.0, 12.0])
    f = make_field("sigma2", src)
    assert f.value(src) == pytest.approx(1.0)
    assert np.allclose(f.gradient(src), 0.0)
    assert np.allclose(f.source_enu(), src)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(amplitude=1.0, S=np.eye(2)), "3x3"),
        (dict(amplitude=1.0, S=np.array([[1, 2, 0], [0, 1, 0], [0, 0, 1.0]])), "symmetric"),
        (dict(amplitude=1.0, S=-np.eye(3)), "positive definite"),
        (dict(amplitude=0.0, S=np.eye(3)), "amplitude"),
    ],
)
def test_bad_fields_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GaussianField(**kwargs)


def test_unknown_field_name_lists_known_ones():
    with pytest.raises(ValueError, match="sigma1, sigma2"):
        make_field("sigma9")


def test_sum_field_finds_the_stronger_source():
    f = SumField([sigma2((0.0, 0.0, 0.0)), GaussianField(3.0, S2, np.array([40.0, 0.0, 0.0]))])
    x = f.source_enu()
    assert np.linalg.norm(x - [40.0, 0.0, 0.0]) < 2.0
    assert np.linalg.norm(f.gradient(x)) < 1e-8
    assert f.value(x) > 3.0 > f.value(np.zeros(3))


def test_fault_set_parses_and_checks_values():
    f = FaultSet()
    f.set("link_cut", "on")
    f.set("loss_uplink", "0.25")
    assert f.link_cut is True and f.loss_uplink == 0.25
    with pytest.raises(ValueError, match=r"probability in \[0, 1\]"):
        f.set("loss_downlink", 1.5)
    with pytest.raises(ValueError, match="expected true/false"):
        f.set("crashed", "maybe")
    with pytest.raises(ValueError, match="unknown fault"):
        f.set("warp_drive", 1)
    assert parse_fault("3:loss_uplink=0.2") == (3, "loss_uplink", "0.2")
    with pytest.raises(ValueError, match="SYSID:NAME=VALUE"):
        parse_fault("loss_uplink=0.2")
    assert "sensor_stuck" in FAULT_NAMES


def test_cli_without_command_prints_help_and_fails(capsys):
    from mission.cli import main

    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_cli_rejects_unknown_command(capsys):
    from mission.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["warp"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_sum_field_maximum_is_a_stationary_point_between_overlapping_sources():
    # two equal wide Gaussians 4 m apart merge into one peak in the middle
    a = GaussianField(1.0, 0.01 * np.eye(3), np.array([0.0, 0.0, 0.0]))
    b = GaussianField(1.0, 0.01 * np.eye(3), np.array([4.0, 0.0, 0.0]))
    x = SumField([a, b]).source_enu()
    assert np.allclose(x, [2.0, 0.0, 0.0], atol=1e-4)
    assert np.linalg.norm(SumField([a, b]).gradient(x)) < 1e-8
