"""``swarmseek simulate`` on the plume fields: ``ste`` is the default there (as in ``run`` and a
plan), with ``run``'s step and a start down the wind; every seeker's stop says what it knows of
its own uncertainty (a 95 % region, or that it keeps no estimate of its own)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from experiments.cmd_simulate import PAPER_GAMMA_M, PLUME_SOURCE_ENU, PLUME_START_DOWNWIND_M, SEEKER_GAMMA_M
from mission.cli import main as cli_main


def _json(argv: list[str], capsys) -> dict:
    assert cli_main(["simulate", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("field", ["plume", "intermittent"])
def test_a_plume_field_defaults_to_ste_with_runs_step_and_a_start_down_the_wind(field, capsys):
    out = _json(["--field", field, "--iterations", "20"], capsys)
    assert out["field"] == field and out["seeker"] == "ste" and out["gamma_m"] == SEEKER_GAMMA_M
    # the fields blow from 270 deg (toward the east): the start is 25 m east of the release, 2 m lower
    expected = np.asarray(PLUME_SOURCE_ENU) + (PLUME_START_DOWNWIND_M, 0.0, -2.0)
    np.testing.assert_allclose(out["start_enu"], expected, atol=1e-9)
    np.testing.assert_allclose(out["source_enu"], PLUME_SOURCE_ENU)
    assert np.isfinite(out["region95_m"]) and out["region95_m"] > 0  # the posterior's, never a bare estimate


def test_the_paper_fields_keep_the_papers_gradient_run(capsys):
    out = _json(["--iterations", "5"], capsys)
    assert out["field"] == "sigma2" and out["seeker"] == "gradient" and out["gamma_m"] == PAPER_GAMMA_M


def test_ste_finds_the_intermittent_release_given_the_wind(capsys):
    """The hit/miss likelihood on the puff plume (a plan's ``plume_mode = "intermittent"``): this
    start converges, and the release lies inside the reported 95 % region."""
    out = _json(["--field", "intermittent", "--seek-wind-from", "270", "--noise", "0.01", "--iterations", "300",
                 "--stop-at-convergence"], capsys)
    assert out["converged"] and out["posterior_arrival"]
    assert out["posterior_error_m"] <= out["region95_m"] <= 1.0


def test_every_seekers_stop_says_what_it_knows_of_its_uncertainty(capsys):
    assert cli_main(["simulate", "--seeker", "model", "--radius", "4", "--noise", "0.001", "--iterations", "300",
                     "--stop-at-convergence"]) == 0
    text = capsys.readouterr().out
    assert "the seeker's own estimate there [" in text and ", 95 % region 0.0" in text
    assert cli_main(["simulate", "--iterations", "2000", "--stop-at-convergence"]) == 0
    text = capsys.readouterr().out
    assert "the gradient seeker keeps no estimate of its own: the window's spread is the estimate's uncertainty" in text
    out = _json(["--seeker", "model", "--radius", "4", "--noise", "0.001", "--iterations", "300",
                 "--stop-at-convergence"], capsys)
    assert out["seeker_region95_m"] is not None and out["seeker_region95_m"] < out["tol_m"]
    assert np.linalg.norm(np.subtract(out["seeker_estimate_enu"], out["source_enu"])) == pytest.approx(
        out["seeker_estimate_error_m"])
