"""The region rule that confirms a seek's convergence from the seeker's own 95 % region
(estimator.seek_confirm): it declares on a tight region with the formation on it, never on a wide
one, and the offline scan is the same maths as the online rule."""
from __future__ import annotations

import numpy as np
import pytest

from estimator import ConvergenceMonitor
from estimator.estimate import SourceEstimate
from estimator.seek_confirm import RegionConfirmation, SeekConvergenceMonitor, region_scan, seeker_estimate

SOURCE = np.array([3.0, -2.0, 10.0])


def _est(region_m, offset=(0.0, 0.0, 0.0)):
    return SourceEstimate(SOURCE + np.asarray(offset, dtype=float), region_m, "a fit")


def test_declares_after_hold_iterations_on_a_tight_region_with_the_formation_on_it():
    rule = RegionConfirmation(tol_m=0.5, hold=3)
    near = SOURCE + [0.1, 0.0, 0.0]
    got = [rule.update(near, _est(0.2), formation_centre_enu=SOURCE + [0.0, 0.3, 0.0]) for _ in range(3)]
    assert got == [False, False, True]
    assert rule.passed


def test_never_declares_on_a_wide_region_however_steady():
    rule = RegionConfirmation(tol_m=0.5, hold=3)
    assert not any(rule.update(SOURCE, _est(0.51), formation_centre_enu=SOURCE) for _ in range(50))
    mon = SeekConvergenceMonitor(window=12, tol_m=0.5, hold=3)
    # a steady estimate with a wide region while the formation still flies (the window test cannot pass)
    flying = [mon.update(SOURCE + [2.0 * k, 0.0, 0.0], True, _est(2.0), SOURCE) for k in range(30)]
    assert not any(flying) and mon.declared_by is None


def test_formation_off_the_estimate_or_no_region_does_not_declare():
    rule = RegionConfirmation(tol_m=0.5, hold=3)
    far = SOURCE + [0.0, 0.6, 0.0]
    assert not any(rule.update(SOURCE, _est(0.1), formation_centre_enu=far) for _ in range(10))  # readings elsewhere
    assert not any(rule.update(far, _est(0.1), formation_centre_enu=SOURCE) for _ in range(10))  # centre leaving
    assert not any(rule.update(SOURCE, SourceEstimate(SOURCE, None, "centres")) for _ in range(10))
    assert not any(rule.update(SOURCE, None) for _ in range(10))


def test_a_break_restarts_the_count_and_a_moving_estimate_does_not_stand():
    rule = RegionConfirmation(tol_m=0.5, hold=3)
    seq = [_est(0.2), _est(0.2), None, _est(0.2), _est(0.2), _est(0.2)]
    assert [rule.update(SOURCE, e) for e in seq] == [False, False, False, False, False, True]
    rule.reset()
    jumping = [_est(0.2, (0.0, 0.0, 0.0)), _est(0.2, (0.45, 0.0, 0.0)), _est(0.2, (0.0, 0.45, 0.0))]
    assert not any(rule.update(e.enu, e) for e in jumping)  # each within tol of the centre, not of the others
    rule.reset()
    assert [rule.update(SOURCE, _est(0.2), signal=s) for s in (True, False, True, True)] == [False] * 4
    no_sig = RegionConfirmation(tol_m=0.5, hold=3, use_signal=False)
    assert [no_sig.update(SOURCE, _est(0.2), signal=False) for _ in range(3)] == [False, False, True]


@pytest.mark.parametrize("kwargs", [{"tol_m": 0.0}, {"tol_m": np.nan}, {"hold": 1}, {"hold": 2.5}])
def test_bad_parameters_are_refused(kwargs):
    with pytest.raises(ValueError):
        RegionConfirmation(**kwargs)


def test_scan_is_the_online_rule():
    rng = np.random.default_rng(7)
    t = 200
    centres = SOURCE + rng.normal(0.0, 0.15, (t, 3))
    formation = centres + rng.normal(0.0, 0.1, (t, 3))
    estimates = SOURCE + rng.normal(0.0, 0.08, (t, 3))
    regions = rng.uniform(0.1, 0.7, t)
    regions[rng.random(t) < 0.1] = np.nan  # iterations without an estimate
    estimates[np.isnan(regions)] = np.nan
    signal = rng.random(t) < 0.9
    rule = RegionConfirmation(tol_m=0.5, hold=3)
    online = []
    for i in range(t):
        e = None if np.isnan(regions[i]) else SourceEstimate(estimates[i], regions[i], "a fit")
        online.append(rule.update(centres[i], e, formation[i], bool(signal[i])))
    passes = np.flatnonzero(online)
    assert passes.size > 0  # the sequence does exercise the rule
    first = region_scan(centres[:, None], formation[:, None], estimates[:, None], regions[:, None],
                        signal[:, None], tol_m=0.5, hold=3)
    assert first.tolist() == [int(passes[0])]
    assert region_scan(centres[:5, None], formation[:5, None], estimates[:5, None], np.full((5, 1), 0.9),
                       tol_m=0.5).tolist() == [-1]


def test_seek_monitor_says_which_test_passed_and_keeps_the_window_test():
    mon = SeekConvergenceMonitor(window=12, tol_m=0.5, min_signal_fraction=1.0)
    plain = ConvergenceMonitor(window=12, tol_m=0.5, min_signal_fraction=1.0)
    for _ in range(11):  # without an estimate only the window test can pass: after 12 steady centres
        assert mon.update(SOURCE, True) == plain.update(SOURCE, True) is False
    assert mon.update(SOURCE, True) and mon.declared_by == "window"
    mon.reset()
    assert mon.declared_by is None and mon.iterations == 0
    mon.update(SOURCE + [20.0, 0.0, 0.0], True)  # far away: in the window, not in the hold
    got = [mon.update(SOURCE + [0.1 * k, 0.0, 0.0], True, _est(0.2), SOURCE) for k in range(3)]
    assert got == [False, False, True] and mon.declared_by == "region"
    assert mon.iterations == 4  # the window test saw the centres too
    assert mon.spread_m == pytest.approx(np.sqrt(2.0 / 3.0) * 0.1)  # the hold's three centres only


def test_seeker_estimate_is_the_seekers_own_or_none():
    class WithModel:
        def source_estimate(self, k=0):
            return _est(0.3)

    assert seeker_estimate(WithModel()).region95_m == 0.3
    assert seeker_estimate(object()) is None and seeker_estimate(None) is None


def test_offline_simulate_applies_the_region_rule_to_the_seekers_own_estimates(capsys):
    """``swarmseek simulate`` (stop and go) ends a model run where the rule passes, before the window
    test, and reports the seeker's own estimate there; the newton seeker has none: window test only."""
    import json

    from mission.cli import main as cli_main

    common = ["simulate", "--n", "6", "--field", "sigma2", "--noise", "0.005", "--seed", "0", "--stop-at-convergence",
              "--json"]
    assert cli_main(common + ["--seeker", "model", "--gamma", "20", "--iterations", "60"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["converged_by"] == "region"
    assert out["converged_at_iteration"] < out["window_converged_at_iteration"]
    assert out["estimate_error_m"] == out["seeker_estimate_error_m"] <= out["tol_m"]
    assert out["final_iteration"] == out["converged_at_iteration"] and out["estimate_spread_m"] is None
    assert cli_main(common + ["--seeker", "newton", "--gamma", "20", "--iterations", "120"]) == 0
    newton = json.loads(capsys.readouterr().out)
    assert newton["converged_by"] == "window" and newton["seeker_estimate_error_m"] is None
    assert newton["converged_at_iteration"] == newton["window_converged_at_iteration"]


def test_hold_zero_turns_the_region_rule_off_and_the_window_still_decides():
    mon = SeekConvergenceMonitor(window=12, tol_m=0.5, hold=0)
    steady = [mon.update(SOURCE, True, _est(0.1), SOURCE) for _ in range(12)]
    assert steady[:-1] == [False] * 11 and steady[-1] and mon.declared_by == "window"
    on = SeekConvergenceMonitor(window=12, tol_m=0.5, hold=3)
    assert [on.update(SOURCE, True, _est(0.1), SOURCE) for _ in range(3)][-1] and on.declared_by == "region"


@pytest.mark.parametrize("hold", [1, -1])
def test_a_hold_below_two_that_is_not_zero_is_refused(hold):
    with pytest.raises(ValueError, match="hold must be an integer >= 2"):
        SeekConvergenceMonitor(window=12, tol_m=0.5, hold=hold)
