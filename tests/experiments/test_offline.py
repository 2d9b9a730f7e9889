"""Vectorised offline simulation: agrees with a plain loop, deterministic, validates inputs;
and the ``swarmseek simulate`` command."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import minimize

import formation
from estimator import GeometryError, gradient, seek_step
from mission.cli import main as cli_main
from sitl_mock.fields_gaussian import GaussianField, SumField, sigma1, sigma2
from experiments.offline import simulate


def _plain_loop(offsets_k, field, start, eps, gamma, readings, method, sigma_c_exact):
    """One trial, one reading set at a time, with the public single-shot API."""
    c = np.asarray(start, dtype=float)
    centres = [c]
    for vals in readings:
        sc = float(field.value(c)) if sigma_c_exact else None
        g = gradient(c + offsets_k, vals, c, method=method, sigma_c=sc)
        c = seek_step(c, g, eps, gamma)
        centres.append(c)
    return np.array(centres)


@pytest.mark.parametrize(
    ("kind", "method", "noise", "rotate", "sigma_c"),
    [
        ("cvt", "cvt", 0.0, False, "mean"),
        ("cvt", "cvt", 0.05, True, "exact"),
        ("symmetric", "symmetric", np.array([0.5, 0.1, 0.1, 0.1, 0.1, 0.1]), True, "mean"),
        ("symmetric", "cvt", 0.1, False, "mean"),
    ],
)
def test_vectorised_simulation_agrees_with_a_plain_loop(kind, method, noise, rotate, sigma_c):
    offsets = (formation.cvt_sphere(7, 2.0, seed=0) if kind == "cvt"
               else formation.symmetric_cylinder(6, 2.0))
    field = sigma1((1.0, -2.0, 3.0))
    starts = np.array([[10.0, 30.0, 5.0], [-5.0, 20.0, -3.0], [3.0, -25.0, 8.0]])
    res = simulate(offsets, field, starts, eps=0.5, gamma=0.2, iterations=60, trials=3,
                   noise_std=noise, method=method, sigma_c=sigma_c, rotate=rotate, seed=3)
    assert res.centres.shape == (61, 3, 3) and res.readings.shape == (60, 3, len(offsets))
    for k in range(3):
        clean = field.value(res.centres[:-1, k, None, :] + res.offsets[k])
        if np.all(np.asarray(noise) == 0):
            np.testing.assert_allclose(res.readings[:, k], clean)
        loop = _plain_loop(res.offsets[k], field, starts[k], 0.5, 0.2, res.readings[:, k], method,
                           sigma_c == "exact")
        np.testing.assert_allclose(res.centres[:, k], loop, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.grad_true[:, k], field.gradient(res.centres[:-1, k]))


def test_noise_has_the_requested_per_robot_std():
    offsets = formation.symmetric_cylinder(4, 1.0)
    std = np.array([0.5, 0.1, 0.0, 0.2])
    res = simulate(offsets, sigma2(), (30.0, 30.0, 30.0), iterations=4000, noise_std=std, seed=1)
    clean = sigma2().value(res.centres[:-1, 0, None, :] + offsets)
    np.testing.assert_allclose((res.readings[:, 0] - clean).std(axis=0), std, rtol=0.05, atol=1e-12)


def test_rotations_are_rigid_and_per_trial():
    offsets = formation.cvt_sphere(8, 3.0, seed=0)
    res = simulate(offsets, sigma2(), (5.0, 5.0, 5.0), iterations=2, trials=5, rotate=True, seed=9)
    d0 = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)
    for k in range(5):
        dk = np.linalg.norm(res.offsets[k][:, None] - res.offsets[k][None], axis=-1)
        np.testing.assert_allclose(dk, d0, atol=1e-12)
    assert not np.allclose(res.offsets[0], res.offsets[1])


def test_deterministic_for_a_seed_and_seed_matters():
    offsets = formation.cvt_sphere(8, 1.0, seed=0)
    kw = dict(iterations=50, trials=4, noise_std=0.1, rotate=True)
    a = simulate(offsets, sigma2(), (20.0, -20.0, 5.0), seed=5, **kw)
    b = simulate(offsets, sigma2(), (20.0, -20.0, 5.0), seed=5, **kw)
    c = simulate(offsets, sigma2(), (20.0, -20.0, 5.0), seed=6, **kw)
    np.testing.assert_array_equal(a.centres, b.centres)
    assert not np.allclose(a.centres, c.centres)


def test_any_field_with_the_protocol_works():
    field = SumField([GaussianField(1.0, np.eye(3) * 0.01, (5.0, 0.0, 0.0)),
                      GaussianField(0.5, np.eye(3) * 0.02, (-5.0, 0.0, 0.0))])
    res = simulate(formation.cvt_sphere(6, 1.0, seed=0), field, (12.0, 3.0, 0.0), iterations=2000,
                   gamma=0.2, eps=20.0)
    # the true maximum, found independently (SumField.source_enu's own ascent is not used here)
    best = minimize(lambda x: -field.value(x), np.zeros(3), jac=lambda x: -field.gradient(x),
                    tol=1e-12).x
    assert np.linalg.norm(res.centres[-1, 0] - best) < 0.1


def test_distance_and_error_helpers():
    res = simulate(formation.symmetric_cylinder(8, 1.0), sigma2(), (3.0, 4.0, 0.0), iterations=5)
    np.testing.assert_allclose(res.distance_to_source_m()[0], [5.0])
    np.testing.assert_allclose(res.error_norm(),
                               np.linalg.norm(res.grad_est - res.grad_true, axis=-1))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"offsets": np.ones((8, 2))}, ValueError, r"offsets must have shape \(N, 3\)"),
        ({"iterations": 0}, ValueError, "iterations must be an integer >= 1"),
        ({"trials": 0}, ValueError, "trials must be an integer >= 1"),
        ({"noise_std": np.ones(3)}, ValueError, r"noise_std must be a scalar or have shape \(8,\)"),
        ({"noise_std": -0.1}, ValueError, "noise_std must be finite and >= 0"),
        ({"start": (1.0, 2.0)}, ValueError, "start must be a finite"),
        ({"sigma_c": "median"}, ValueError, "sigma_c must be one of"),
        ({"method": "best"}, ValueError, "unknown method 'best'"),
        ({"offsets": np.c_[np.ones((8, 2)), np.zeros(8)]}, GeometryError, "degenerate"),
    ],
)
def test_bad_arguments_raise(kwargs, error, match):
    args = dict(offsets=formation.cvt_sphere(8, 1.0, seed=0), field=sigma2(), start=(1.0, 1.0, 1.0))
    args.update(kwargs)
    with pytest.raises(error, match=match):
        simulate(args.pop("offsets"), args.pop("field"), args.pop("start"), **args)


def test_simulate_command_json(capsys):
    rc = cli_main(["simulate", "--field", "sigma1", "--n", "7", "--radius", "4", "--iterations",
                   "1500", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert out["converged"] and out["estimate_error_m"] < 1.0
    assert out["start_enu"] == [10.0, 50.0, 10.0] and out["final_distance_m"] < 1.0


def test_simulate_command_text_and_noise(capsys):
    rc = cli_main(["simulate", "--formation", "symmetric", "--noise", "0.1", "--radius", "4",
                   "--start", "10,-10,3", "--iterations", "300", "--seed", "3"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "symmetric formation" in out and "m from the true source" in out


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--formation", "symmetric", "--n", "7"], "even number of robots"),
        (["--window", "4"], "window must be an integer >= 8"),
    ],
)
def test_simulate_command_reports_bad_arguments(capsys, argv, match):
    assert cli_main(["simulate", "--iterations", "10", *argv]) == 2
    assert match in capsys.readouterr().err
