"""``swarmseek run --fence-side M``: the embedded plan's fence as a plan's search area
(:func:`mission.sim.embedded.search_fence_en_m`), and ``--prior-box fence`` bounds ``ste`` by it."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from mission.cli.cmd_run import _check_args, _mission_setup, configure
from mission.flight.seeking import ste_options
from mission.safety.fence import Geofence
from mission.sim.embedded import search_fence_en_m


def _inside(polygon, pt, margin_m: float) -> bool:
    en = np.asarray(polygon)
    return bool(np.all(pt[:2] >= en.min(axis=0) + margin_m - 1e-9) and np.all(pt[:2] <= en.max(axis=0) - margin_m + 1e-9))


def test_the_fence_holds_its_points_at_random_places_and_grows_where_it_must():
    pts = [np.array([10.0, -5.0]), np.array([35.0, -3.0]), np.zeros(2)]
    places = []
    for seed in range(40):
        poly = search_fence_en_m(60.0, pts, 9.0, seed)
        en = np.asarray(poly)
        assert np.allclose(np.ptp(en, axis=0), 60.0) and len(poly) == 4
        assert all(_inside(poly, p, 9.0) for p in pts)
        places.append(10.0 - en[:, 0].min())
    assert np.ptp(places) > 5.0  # the source is not at one place in its fence
    wide = np.asarray(search_fence_en_m(20.0, pts, 9.0, 0))
    assert np.isclose(np.ptp(wide[:, 0]), 35.0 + 18.0) and np.isclose(np.ptp(wide[:, 1]), 5.0 + 18.0)


def test_run_fence_side_and_prior_box_reach_the_plan_and_the_seeker():
    ap = argparse.ArgumentParser()
    configure(ap)
    args = ap.parse_args(["--field", "intermittent", "--fence-side", "60", "--prior-box", "fence", "--seed", "3"])
    assert _check_args(args) is None
    plan, _, _, source, start, _ = _mission_setup(args)
    fence = plan.geofence.polygon_en_m
    for pt in (source, start, np.zeros(3)):
        assert _inside(fence, pt, 4.0)
    Geofence(fence, plan.geofence.min_alt_m, plan.geofence.max_alt_m)  # the safety envelope accepts it
    assert plan.seeking.seeker == "ste" and plan.seeking.prior_box == "fence"
    box = np.asarray(ste_options(plan.seeking, plan.geofence)["prior_box_enu"])
    assert np.all(box[0] <= source) and np.all(source <= box[1]) and np.all(box[0] <= start) and np.all(start <= box[1])


@pytest.mark.parametrize("argv", [["--fence-side", "0"], ["--fence-side", "nan"], ["--prior-box", "box"]])
def test_bad_fence_options_are_usage_errors(argv, capsys):
    from mission.cli import main as cli_main

    with pytest.raises(SystemExit) as info:  # argparse: the usage, then one error line
        cli_main(["run", "--field", "intermittent", *argv])
    assert info.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("swarmseek run: error: argument --") and ("--fence-side" in last or "--prior-box" in last)
