"""A plan that names no seeker gets the best measured one for its field, with that seeker's step and sampling."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mission.core.plan import parse_plan
from estimator.seekers import best_seeker

SAMPLE = Path(__file__).resolve().parents[3] / "mission" / "examples" / "sitl_plan.toml"


def _doc_without(*keys: str) -> dict:
    doc = tomllib.loads(SAMPLE.read_text())
    for key in keys:
        doc["seeking"].pop(key, None)
    return doc


@pytest.mark.parametrize("field, seeker, plume_mode", [
    (None, "model", "steady"),
    ({"type": "sigma2"}, "model", "steady"),
    ({"type": "sigma1"}, "model", "steady"),
    ({"type": "plume"}, "ste", "steady"),
    ({"type": "intermittent"}, "ste", "intermittent"),
])
def test_no_seeker_named_means_the_best_measured_for_the_field(field, seeker, plume_mode):
    doc = _doc_without("seeker", "gamma_m", "eps")
    doc.pop("field", None)
    if field is not None:
        doc["field"] = field
    sk = parse_plan(doc).seeking
    assert (sk.seeker, sk.gamma_m, sk.sampling, sk.plume_mode) == (seeker, 20.0, "moving", plume_mode)
    assert best_seeker(field and field["type"]) == seeker


def test_the_papers_seeker_keeps_the_papers_step_and_samples_at_rest():
    doc = _doc_without("gamma_m", "eps")
    doc["seeking"]["seeker"] = "gradient"
    sk = parse_plan(doc).seeking
    assert (sk.seeker, sk.gamma_m, sk.eps, sk.sampling) == ("gradient", 0.1, 1.0, "stop_and_go")


@pytest.mark.parametrize("seeker, sampling", [("plume", "stop_and_go"), ("newton", "moving"), ("ste", "moving")])
def test_a_named_seeker_gets_its_own_sampling_and_a_large_step(seeker, sampling):
    doc = _doc_without("gamma_m")
    doc["seeking"]["seeker"] = seeker
    sk = parse_plan(doc).seeking
    assert (sk.sampling, sk.gamma_m) == (sampling, 20.0)


def test_given_values_win_over_the_defaults():
    doc = _doc_without()
    doc["seeking"].update(seeker="model", gamma_m=3.0, sampling="stop_and_go")
    sk = parse_plan(doc).seeking
    assert (sk.seeker, sk.gamma_m, sk.sampling) == ("model", 3.0, "stop_and_go")


def test_the_field_type_default_does_not_hide_a_bad_field():
    doc = _doc_without("seeker")
    doc["field"] = {"type": "lava"}
    with pytest.raises(ValueError, match=r"field\.type"):
        parse_plan(doc)
