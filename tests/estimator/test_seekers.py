"""Seekers (estimator.seekers): the interface, the quadratic fit, each seeker on the paper's fields,
the time model, the plan key and the CLI flags."""
from __future__ import annotations

import re

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

import formation
from estimator import estimator_weights, seek_step
from estimator.seek_quadratic import fit_quadratic
from estimator.seekers import SEEKERS, GradientSeeker, ModelSeeker, NewtonSeeker, cap_move, make_seeker
from experiments.offline_seek import StopAndGo, simulate_seeker
from sitl_mock.fields_gaussian import sigma1, sigma2

_OFF = formation.cvt_sphere(8, 4.0, seed=0)


def _starts(k: int, seed: int = 0, lo: float = 10.0, hi: float = 30.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(k, 3))
    u[:, 2] *= 0.2
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * rng.uniform(lo, hi, k)[:, None]


def test_quadratic_fit_is_exact_for_a_quadratic_and_the_log_fit_for_a_gaussian():
    rng = np.random.default_rng(3)
    c = np.array([[2.0, -1.0, 0.5]])
    pos = c[:, None, :] + rng.normal(scale=3.0, size=(1, 30, 3))
    h = np.array([[-0.4, 0.1, 0.0], [0.1, -0.3, 0.05], [0.0, 0.05, -0.2]])
    g = np.array([0.3, -0.2, 0.1])
    d = pos[0] - c[0]
    vals = (5.0 + d @ g + 0.5 * np.einsum("mi,ij,mj->m", d, h, d))[None]
    fit = fit_quadratic(pos, vals, np.ones((1, 30), bool), c, log=False)
    np.testing.assert_allclose(fit.hessian[0], h, atol=1e-5)
    np.testing.assert_allclose(fit.grad[0], g, atol=1e-6)
    np.testing.assert_allclose(fit.newton[0], -np.linalg.solve(h, g), atol=1e-4)
    field = sigma2((3.0, -4.0, 12.0))
    fit = fit_quadratic(pos, field.value(pos), np.ones((1, 30), bool), c, log=True)
    np.testing.assert_allclose(c[0] + fit.newton[0], field.source_enu(), atol=1e-3)
    np.testing.assert_allclose(fit.hessian[0], -2.0 * field.S, atol=1e-6)


def test_one_sphere_of_readings_shows_no_curvature():
    """8 readings on one sphere: 10 coefficients, the trace of H unobservable -> not concave."""
    c = np.array([[0.0, 0.0, 0.0]])
    pos = (c[:, None, :] + _OFF)
    fit = fit_quadratic(pos, sigma2((10.0, 0.0, 0.0)).value(pos), np.ones((1, 8), bool), c, log=True)
    assert not fit.concave[0]
    assert np.isinf(fit.newton_std_m[0])


def test_gradient_seeker_is_the_papers_step():
    """c + eps g with Theorem 2 (centred) about the centroid; cap_move(gamma) = seek_step."""
    field = sigma2()
    c = np.array([[12.0, -7.0, 3.0]])
    pos = c[:, None, :] + _OFF
    vals = field.value(pos)
    g = vals[0] @ estimator_weights(_OFF - _OFF.mean(axis=0), "cvt")[0]
    new = cap_move(c, GradientSeeker(eps=30.0).propose(c, pos, vals), 1.0)
    np.testing.assert_allclose(new[0], seek_step(c[0], g, 30.0, 1.0), atol=1e-12)


@pytest.mark.parametrize("name", ["newton", "model"])
def test_trust_region_seekers_find_sigma2(name):
    """Noise-free sigma_2, 20 starts 10-30 m away: every run ends within 0.5 m of the source."""
    field = sigma2((0.0, 0.0, 15.0))
    run = simulate_seeker(_OFF, field, _starts(20) + field.source_enu(), make_seeker(name), gamma_m=20.0,
                          iterations=60, seed=1)
    assert np.all(run.distance_m()[-1] < 0.5)


def test_model_seeker_is_exact_in_few_iterations_on_gaussians():
    """log of a Gaussian is quadratic: noise-free, within 1e-3 m after at most 8 iterations on both fields."""
    for field in (sigma1((0.0, 0.0, 15.0)), sigma2((0.0, 0.0, 15.0))):
        run = simulate_seeker(_OFF, field, _starts(20, seed=2) + field.source_enu(), ModelSeeker(),
                              gamma_m=20.0, iterations=8, seed=3)
        assert np.all(run.distance_m()[-1] < 1e-3)


def test_model_seeker_beats_gradient_with_noise_on_sigma2():
    """Realistic noise (0.01): the model gets within 1 m in fewer mission seconds than the
    paper's step (eps as swarmseek run, gamma 1 m), and ends as close."""
    field = sigma2((0.0, 0.0, 15.0))
    starts = _starts(60, seed=4, lo=15, hi=30) + field.source_enu()
    model = StopAndGo()

    def first_in_s(run):
        d = run.distance_m()
        t = np.concatenate([np.zeros((1, d.shape[1])), np.cumsum(model.iteration_s(run.moves()), axis=0)])
        inside = d < 1.0
        return np.where(inside.any(axis=0), t[np.argmax(inside, axis=0), np.arange(d.shape[1])], np.inf), d[-1]

    eps = 1.0 / (2.0 * np.max(np.linalg.eigvalsh(field.S)))
    t_g, d_g = first_in_s(simulate_seeker(_OFF, field, starts, GradientSeeker(eps=eps), gamma_m=1.0,
                                          iterations=80, noise_std=0.01, seed=5))
    t_m, d_m = first_in_s(simulate_seeker(_OFF, field, starts, ModelSeeker(), gamma_m=20.0,
                                          iterations=80, noise_std=0.01, seed=5))
    assert np.median(t_m) < 0.6 * np.median(t_g)
    assert np.median(d_m) <= np.median(d_g) + 0.1


def test_newton_seeker_variable_formation_size_and_reset():
    """The window takes iterations with different numbers of readings (a vehicle lost); reset forgets."""
    field = sigma2()
    s = NewtonSeeker()
    c = np.array([[10.0, 5.0, 0.0]])
    s.propose(c, (c[:, None, :] + _OFF), field.value(c[:, None, :] + _OFF))
    c2 = c + [[-2.0, 0.0, 0.0]]
    out = s.propose(c2, (c2[:, None, :] + _OFF[:6]), field.value(c2[:, None, :] + _OFF[:6]))
    assert out.shape == (1, 3) and np.all(np.isfinite(out))
    s.reset()
    assert s.radius_m is None and not s._buf


def test_seekers_reject_bad_input():
    s = ModelSeeker()
    with pytest.raises(ValueError, match="finite"):
        s.propose([[0.0, 0.0, np.nan]], np.zeros((1, 8, 3)), np.zeros((1, 8)))
    with pytest.raises(ValueError, match="expected centre"):
        s.propose([[0.0, 0.0, 0.0]], np.zeros((1, 8, 3)), np.zeros((1, 7)))
    with pytest.raises(ValueError, match="unknown seeker"):
        make_seeker("simplex")
    with pytest.raises(ValueError, match="radius"):
        ModelSeeker(radius_m=0.0)
    assert SEEKERS == ("gradient", "newton", "model", "plume", "ste")


def test_cap_move_keeps_direction_and_length():
    c = np.zeros((2, 3))
    new = cap_move(c, [[30.0, 40.0, 0.0], [0.3, 0.4, 0.0]], 5.0)
    np.testing.assert_allclose(new, [[3.0, 4.0, 0.0], [0.3, 0.4, 0.0]])


def test_time_model_stop_and_go():
    """No move: the 2 Hz floor; 1 m: 1.6 s, 10 m: 5 s (lock-step mission iteration records)."""
    m = StopAndGo()
    t = m.iteration_s(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 0.0, 4.0]]))
    assert t[0] == pytest.approx(0.5)
    assert t[1] == pytest.approx(1.6, abs=0.1)
    assert t[2] == pytest.approx(5.0, abs=0.2)
    assert t[3] > 4.0  # vertical moves at 1 m/s


def test_bench_measures_and_wilson():
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import bench_seekers

    lo, hi = bench_seekers.wilson(95, 100)
    assert 0.88 < lo < 0.95 < hi < 0.99
    field = sigma2((0.0, 0.0, 15.0))
    starts = _starts(10, seed=6) + field.source_enu()
    run = simulate_seeker(_OFF, field, starts, ModelSeeker(), gamma_m=20.0, iterations=20, seed=7)
    row = bench_seekers.measure(run, np.linalg.norm(starts - field.source_enu(), axis=1), 8, StopAndGo())
    assert row["success"] == 1.0
    assert 1.0 < row["ratio_median"] < 4.0
    assert row["readings_median"] % 8 == 0


def test_bench_start_range_option(capsys):
    """``--start-m lo,hi``: the start distances drawn in that range; a bad range exits 2 with one line."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_seekers

    assert bench_seekers._start_range("20,40") == (20.0, 40.0)
    starts, dist = bench_seekers._starts(np.zeros(3), 200, np.random.default_rng(1), (1.0, 0.0), (20.0, 40.0))
    assert dist.min() >= 20.0 and dist.max() <= 40.0
    assert np.allclose(np.linalg.norm(starts, axis=1), dist)
    assert np.all(starts[:, 0] > 0)  # downwind
    for bad in ("40,20", "0,10", "20", "a,b", "nan,40"):
        with pytest.raises(SystemExit) as exc:
            bench_seekers.main(["--start-m", bad, "--trials", "1"])
        assert exc.value.code == 2
        assert "--start-m" in capsys.readouterr().err


def test_bench_field_args_option(capsys):
    """``--field-args``: the field's parameters (a stability class also given to ste, as a plan would);
    bad ones exit 2 with one line before any trial runs."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import bench_seekers

    assert bench_seekers.field_args("wind_speed_m_s=4,stability=D") == {"wind_speed_m_s": 4.0, "stability": "D"}
    row = bench_seekers.run_cell("ste-wind", "plume", "realistic", 2, 2, 0, field_args={"wind_speed_m_s": 4.0,
                                                                                        "stability": "D"})
    assert row["field_args"] == {"wind_speed_m_s": 4.0, "stability": "D"}
    assert "| ste-wind | plume (wind_speed_m_s=4,stability=D) |" in bench_seekers._fmt(row)
    seeker, _ = bench_seekers._seeker("ste", bench_seekers._field_and_noise("plume", np.zeros(3), "0")[0],
                                      stability="D")
    assert seeker.model["stability"] == "D"
    for bad, why in (("stability", "is not NAME=VALUE"), ("stability=Q", "unknown stability class 'Q'"),
                     ("wind_speed_m_s=-1", "wind_speed_m_s must be a finite number > 0"),
                     ("wind_speed=3", "has no parameter wind_speed")):
        with pytest.raises(SystemExit) as exc:
            bench_seekers.main(["--fields", "plume", "--field-args", bad, "--trials", "1"])
        assert exc.value.code == 2
        assert why in capsys.readouterr().err



def test_bench_ste_args_option(capsys):
    """``--ste-args``: integers stay integers, other numbers are floats, and a malformed item exits 2
    with one line before any trial runs (the same parser as ``--field-args``)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import bench_seekers

    assert bench_seekers._ste_kwargs("exploit_m=3,radius_gain=0.25,mode=x") == {
        "exploit_m": 3, "radius_gain": 0.25, "mode": "x"}
    assert bench_seekers._ste_kwargs(None) == {}
    with pytest.raises(SystemExit) as exc:
        bench_seekers.main(["--fields", "plume", "--seekers", "ste", "--ste-args", "exploit_m", "--trials", "1"])
    assert exc.value.code == 2
    assert "--ste-args: 'exploit_m' is not NAME=VALUE" in capsys.readouterr().err

def test_plan_key_and_cli_flags(tmp_path):
    from mission.cli.cmd_run import _resolve_seeker, configure
    from mission.core.plan import load_plan
    from mission.core.plan_types import PlanError

    ap = argparse.ArgumentParser()
    configure(ap)
    assert _resolve_seeker(ap.parse_args([])) == "model"
    assert ap.parse_args(["--seeker", "gradient"]).seeker == "gradient"
    with pytest.raises(SystemExit) as exc:
        ap.parse_args(["--seeker", "simplex"])
    assert exc.value.code == 2
    plan_text = (Path(__file__).resolve().parents[2] / "mission" / "examples" / "sitl_plan.toml").read_text()
    assert "[seeking]" in plan_text
    plan_text = re.sub(r"^seeker = .*\n", "", plan_text, count=1, flags=re.M)  # the sample names the model seeker
    good = tmp_path / "plan.toml"
    good.write_text(plan_text.replace("[seeking]", '[seeking]\nseeker = "newton"', 1))
    assert load_plan(good).seeking.seeker == "newton"
    bad = tmp_path / "bad.toml"
    bad.write_text(plan_text.replace("[seeking]", '[seeking]\nseeker = "simplex"', 1))
    with pytest.raises(PlanError, match="seeker"):
        load_plan(bad)
