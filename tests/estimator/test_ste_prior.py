"""The ``ste`` seeker's prior bounded by a search box (``prior_box_enu``, :mod:`estimator.ste_prior`)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import formation
from estimator.ste import SteSeeker
from estimator.ste_prior import check_box, draw_prior
from sitl_mock.fields_config import make_field

BOX = ((-10.0, -12.0, 0.0), (35.0, 18.0, 30.0))  # a 45 m x 30 m search area, the ground to 30 m up


def _inside(parts: np.ndarray, box) -> np.ndarray:
    b = np.asarray(box, dtype=float)
    return np.all((parts[..., :3] >= b[..., 0, None, :]) & (parts[..., :3] <= b[..., 1, None, :]), axis=-1)


@pytest.mark.parametrize("upwind", [None, 30.0])
def test_the_first_prior_is_inside_the_box_and_above_the_ground(upwind):
    """Every particle of the first prior lies in the box and the cylinder (or sector) about the
    first centre, never below the ground; the box narrows the plan view to its part of the disk."""
    c = np.array([[30.0, 2.0, 3.0], [-5.0, 15.0, 20.0]])
    s = SteSeeker(wind_from_deg=270.0, patchy=True, prior_upwind_deg=upwind, prior_box_enu=BOX, seed=3)
    s._init_state(c)
    assert _inside(s.parts, BOX).all()
    assert np.all(s.parts[..., 2] >= s.model["ground_alt_m"] + 0.1)
    assert np.all(np.linalg.norm(s.parts[..., :2] - c[:, None, :2], axis=-1) <= s.prior_radius_m + 1e-9)
    assert np.all(np.abs(s.parts[..., 2] - c[:, None, 2]) <= s.prior_radius_m)
    span = np.ptp(s.parts[0, :, :2], axis=0)
    assert span[0] > 30.0 and span[1] > 20.0  # the box's part of the disk is filled, not one corner
    free = SteSeeker(wind_from_deg=270.0, patchy=True, prior_upwind_deg=upwind, seed=3)
    free._init_state(c)
    assert not _inside(free.parts, BOX).all()  # without the box the prior reaches outside it


def test_particles_stay_in_the_box_through_updates_resampling_and_a_collapse():
    """After updates (resampling and roughening) and a re-seed about a centre near the box's edge,
    every particle is still inside the box (one box per trial here)."""
    field = make_field("intermittent", np.array([0.0, 0.0, 15.0]))
    boxes = np.array([[[-20.0, -15.0, 0.0], [40.0, 25.0, 40.0]], [[-5.0, -30.0, 2.0], [45.0, 10.0, 25.0]]])
    s = SteSeeker(wind_from_deg=270.0, patchy=True, particles=600, prior_box_enu=boxes, seed=1)
    off = formation.cvt_sphere(8, 3.0, seed=0)
    c = np.array([[25.0, 1.0, 13.0], [25.0, -2.0, 14.0]])
    rng = np.random.default_rng(0)
    for i in range(12):
        pos = c[:, None, :] + off[None]
        vals = np.stack([field.value(p, float(i)) for p in pos]) + 0.01 * rng.standard_normal((2, 8))
        c = s.propose(c, pos, vals)
        assert _inside(s.parts, boxes).all()
    s._seed_prior(np.array([0, 1]), np.array([[39.0, 24.0, 39.0], [44.0, -29.0, 3.0]]))
    assert _inside(s.parts, boxes).all() and np.all(s.parts[..., 2] >= 0.1)


def test_a_box_without_the_first_centre_is_a_clear_error():
    s = SteSeeker(patchy=True, prior_box_enu=BOX)
    with pytest.raises(ValueError, match=r"first centre \[50\.0, 0\.0, 10\.0\] \(trial 0\) is outside prior_box_enu"):
        s.propose(np.array([[50.0, 0.0, 10.0]]), np.array([[[50.0, 0.0, 10.0]] * 4]), np.zeros((1, 4)))
    assert s.estimate_enu is None  # nothing was updated
    two = SteSeeker(prior_box_enu=np.stack([BOX, BOX, BOX]))
    with pytest.raises(ValueError, match=r"shape \(2, 3\) or \(2, 2, 3\)"):
        two.propose(np.zeros((2, 3)) + [0.0, 0.0, 10.0], np.zeros((2, 4, 3)) + [0.0, 0.0, 10.0], np.zeros((2, 4)))


@pytest.mark.parametrize("box, why", [
    (((0.0, 0.0, 0.0), (np.nan, 10.0, 10.0)), "must be finite"),
    (((0.0, 0.0, 0.0), (10.0, -5.0, 10.0)), "each minimum must be below its maximum"),
    (((0.0, 0.0, 5.0), (10.0, 10.0, 5.0)), "each minimum must be below its maximum"),
    (((0.0, 0.0), (10.0, 10.0)), "must have shape (2, 3)"),
    (((0.0, 0.0, -20.0), (10.0, 10.0, -1.0)), "top must be above the ground"),
])
def test_an_invalid_box_is_refused_at_construction(box, why):
    with pytest.raises(ValueError, match=r"prior_box_enu") as info:
        SteSeeker(prior_box_enu=box)
    assert why in str(info.value)


def test_a_box_missing_the_sector_falls_back_to_the_disk_then_the_box():
    """The sector up the wind outside the box (the start at the box's upwind edge): the prior is
    the disk inside the box; a box far from the centre: the box itself. Always inside it."""
    rng = np.random.default_rng(0)
    c = np.array([[0.0, 0.0, 10.0]])
    box = np.array([[[0.0, -10.0, 0.0], [30.0, 10.0, 20.0]]])  # the wind from the west: upwind is e < 0
    parts = draw_prior(rng, c, 500, radius_m=60.0, height_m=15.0, ground_alt_m=0.0, log_amp=(-3.0, 3.0),
                       wind_from_deg=270.0, wind_std_rad=0.0, upwind_half_rad=np.deg2rad(30.0), box=box)
    assert _inside(parts, box).all() and np.ptp(parts[0, :, 0]) > 20.0
    far = np.array([[[100.0, 100.0, 0.0], [110.0, 120.0, 20.0]]])
    parts = draw_prior(rng, c, 200, radius_m=60.0, height_m=15.0, ground_alt_m=0.0, log_amp=(-3.0, 3.0),
                       wind_from_deg=None, wind_std_rad=0.0, box=far)
    assert _inside(parts, far).all()
    assert check_box(None) is None


def _bench():
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_seekers.py"
    spec = importlib.util.spec_from_file_location("bench_seekers_box", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_benchmarks_search_boxes_hold_release_and_start_without_centring_the_release():
    bench = _bench()
    rng = np.random.default_rng(5)
    source = np.array([0.0, 0.0, 15.0])
    starts = source + np.stack([rng.uniform(10.0, 50.0, 200), rng.uniform(-8.0, 8.0, 200),
                                rng.uniform(-10.0, 10.0, 200)], axis=1)
    boxes = bench.search_boxes(source, starts, 60.0, rng, margin_m=5.0)
    for pt in (np.broadcast_to(source, starts.shape), starts):
        assert np.all(pt[:, :2] >= boxes[:, 0, :2] + 5.0 - 1e-9) and np.all(pt[:, :2] <= boxes[:, 1, :2] - 5.0 + 1e-9)
    side = boxes[:, 1, :2] - boxes[:, 0, :2]
    assert np.allclose(side, np.maximum(60.0, np.abs(starts[:, :2] - source[:2]) + 10.0))
    where = (source[0] - boxes[:, 0, 0]) / side[:, 0]  # the release's place across its box
    assert where.min() < 0.2 and where.max() > 0.5 and np.std(where) > 0.05
    assert np.all(boxes[:, 0, 2] == 2.0) and np.all(boxes[:, 1, 2] == 80.0)
