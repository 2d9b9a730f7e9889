"""Several sources: the field is the sum of one field per source (one background), with a local
maximum at each source; the strongest source is the one to find."""
from __future__ import annotations

import numpy as np
import pytest

from sitl_mock.fields_filament import FilamentPlume
from sitl_mock.fields_gaussian import GaussianField, SumField
from sitl_mock.fields_plume import GaussianPlume
from sitl_mock.fields_config import make_field

SOURCES = [(0.0, 0.0, 15.0), (5.0, 40.0, 12.0), (-30.0, -25.0, 18.0)]  # crosswind of each other (west wind)


@pytest.mark.parametrize("name", ["sigma2", "plume", "intermittent"])
def test_sum_of_one_field_per_source_with_one_background(name):
    kw = {"wind_from_deg": 270.0} if name != "sigma2" else {}
    multi = make_field(name, SOURCES[0], extra_sources=SOURCES[1:], strengths=[1.0, 2.0, 0.5], **kw)
    assert isinstance(multi, SumField) and len(multi.parts) == 3
    assert multi.time_dependent == (name == "intermittent")
    pts = np.random.default_rng(0).uniform(-40, 60, (200, 3))
    seeds = [{"seed": i} if name == "intermittent" else {} for i in range(3)]  # source i: seed + i
    singles = [make_field(name, s, **kw, **sd) for s, sd in zip(SOURCES, seeds)]
    bg = 0.0 if name == "sigma2" else singles[0].background
    expected = sum(w * (f.value(pts, 3.0) - bg) for w, f in zip([1.0, 2.0, 0.5], singles)) + bg
    assert np.allclose(multi.value(pts, 3.0), expected, rtol=1e-12, atol=1e-15)
    grads = sum(w * f.gradient(pts) for w, f in zip([1.0, 2.0, 0.5], singles))
    assert np.allclose(multi.gradient(pts), grads, rtol=1e-6, atol=1e-12)
    if name == "intermittent":  # independent puffs per source
        assert len({p.seed for p in multi.parts}) == 3


@pytest.mark.parametrize("name", ["sigma1", "plume"])
def test_local_maximum_near_each_source(name):
    kw = {"wind_from_deg": 270.0} if name == "plume" else {}
    srcs = SOURCES if name == "plume" else [(0.0, 0.0, 0.0), (60.0, 0.0, 0.0)]  # sigma1 is wide in E
    multi = make_field(name, srcs[0], extra_sources=srcs[1:], **kw)
    g = np.linspace(-1.5, 1.5, 31)
    box = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    for s in srcs:
        v = multi.value(np.asarray(s) + box)
        best = box[int(np.argmax(v))]
        assert np.linalg.norm(best) <= 0.11, (s, best)  # the grid point at the source (0.1 m grid)
        assert v.max() > multi.value(np.asarray(s) + [0.0, 0.0, 1.5]) and np.argmax(v) not in (0, len(v) - 1)


def test_source_is_the_strongest_release_and_sources_lists_all():
    multi = make_field("plume", SOURCES[0], extra_sources=SOURCES[1:], strengths=[1.0, 3.0, 2.0])
    assert np.allclose(multi.source_enu(), SOURCES[1])
    assert np.allclose(multi.sources_enu(), SOURCES)
    paper = SumField([GaussianField(1.0, np.eye(3) * 0.01, np.zeros(3)),
                      GaussianField(2.0, np.eye(3) * 0.01, np.array([100.0, 0.0, 0.0]))])
    assert np.allclose(paper.source_enu(), [100.0, 0.0, 0.0], atol=1e-4)
    assert isinstance(multi.parts[0], GaussianPlume)
    assert isinstance(make_field("intermittent", (0, 0, 5), extra_sources=[(9, 9, 5)]).parts[1], FilamentPlume)


def test_multi_source_errors():
    with pytest.raises(ValueError, match="strengths"):
        make_field("plume", (0, 0, 10), extra_sources=[(5, 5, 10)], strengths=[1.0])
    with pytest.raises(ValueError, match="strengths"):
        make_field("sigma2", extra_sources=[(5, 5, 10)], strengths=[1.0, -2.0])
    with pytest.raises(ValueError, match="3 finite numbers"):
        make_field("sigma2", extra_sources=[(5, 5)])
    with pytest.raises(ValueError, match="unknown field"):
        make_field("sigma3")
    with pytest.raises(ValueError, match="at least one"):
        SumField([])
