"""Checks of the paper's experiments: step sizes, stability and the convergence test.

What ``eps = 1``, ``gamma = 0.1`` imply for sigma_1 and sigma_2 (:func:`physics_checks`: step
sizes, iterations per decade, the linearised estimator map of :func:`effective_rate`) and how
the convergence test fares on the sigma_1 runs (:func:`convergence_sigma1`) and on noisy
sigma_2 runs (:func:`convergence_sigma2`). Written to ``physics.json`` by
:mod:`experiments.paper`.
"""
from __future__ import annotations

import math

import numpy as np

from estimator import convergence_scan, estimator_weights, gradient_batch
from experiments.offline import simulate
from experiments.paper_setup import (
    EPS,
    GAMMA,
    NOISE_SEED,
    SIGMA1_START_ENU,
    SIGMA2_START_ENU,
    PaperConfig,
    cvt_formation,
    paper_formation,
)
from sitl_mock.fields_gaussian import S1, S2, sigma1, sigma2

__all__ = ["effective_rate", "physics_checks", "first_below", "convergence_sigma1",
           "convergence_sigma2"]


def effective_rate(radius_m: float) -> dict:
    """Linearised seeking map near the source of sigma_1 for N = 7 CVT of radius D:
    eigenvalues of I + eps * d g_hat / d c (|.| < 1 means locally convergent)."""
    off = cvt_formation(7, radius_m)
    w = estimator_weights(off, "cvt", centred=False)  # the paper's Remark
    f = sigma1()
    h = 1e-5
    jac = np.empty((3, 3))
    for k in range(3):
        dc = np.zeros(3)
        dc[k] = h
        gp = gradient_batch(None, f.value(dc + off), weights=w)
        gm = gradient_batch(None, f.value(-dc + off), weights=w)
        jac[:, k] = (gp - gm) / (2 * h)
    fixed = np.linalg.solve(jac, -gradient_batch(None, f.value(off), weights=w))
    eig = np.linalg.eigvals(np.eye(3) + EPS * jac)
    return {"radius_m": radius_m, "eigenvalues": sorted(np.real(eig).tolist()),
            "predicted_fixed_point_enu": fixed.tolist()}


def physics_checks(cfg: PaperConfig, s1_runs: dict) -> dict:
    """Step sizes, iteration counts and stability: what eps = 1, gamma = 0.1 imply."""
    out = {}
    for name, field, s_mat, start in (("sigma1", sigma1(), S1, SIGMA1_START_ENU),
                                      ("sigma2", sigma2(), S2, SIGMA2_START_ENU)):
        lam = np.linalg.eigvalsh(s_mat)
        amp = float(field.value(field.source_enu()))
        g0 = float(np.linalg.norm(field.gradient(np.asarray(start))))
        slow = 1.0 - 2 * EPS * amp * lam[0]
        out[name] = {
            "start_enu": list(start), "start_distance_m": float(np.linalg.norm(start)),
            "start_value": float(field.value(np.asarray(start))), "start_grad_norm": g0,
            "start_step_m": min(EPS * g0, GAMMA),
            "S_eigenvalues_per_m2": lam.tolist(),
            "exact_gradient_linear_factors": (1.0 - 2 * EPS * amp * lam).tolist(),
            "iterations_per_decade_near_source": math.log(10) / -math.log(abs(slow)),
        }
    # sigma_2 noise-free, N = 8 CVT, D = 1: how many iterations the run needs.
    res = simulate(cvt_formation(8, cfg.fig4_radius_m), sigma2(), SIGMA2_START_ENU, eps=EPS,
                   gamma=GAMMA, iterations=cfg.iterations_checks, method="cvt", sigma_c="remark")
    d = res.distance_to_source_m()[:, 0]
    steps = np.linalg.norm(np.diff(res.centres[:, 0], axis=0), axis=-1)
    out["sigma2"].update({
        "noise_free_iterations_to": {f"{t} m": first_below(d, t) for t in (10.0, 1.0, 0.1)},
        "max_step_m": float(steps.max()), "iterations_at_gamma": int(np.sum(steps > 0.999 * GAMMA)),
    })
    res1 = s1_runs[4.0][0]
    d1 = res1.distance_to_source_m()[:, 0]
    steps1 = np.linalg.norm(np.diff(res1.centres[:, 0], axis=0), axis=-1)
    out["sigma1"].update({
        "D4_iterations_to": {f"{t} m": first_below(d1, t) for t in (10.0, 1.0)},
        "D4_iterations_at_gamma": int(np.sum(steps1 > 0.999 * GAMMA)),
        "linearised_estimator_map": [effective_rate(r) for r in (1.0, 4.0, 7.0)],
    })
    return out


def first_below(dist: np.ndarray, threshold_m: float):
    """First index where ``dist`` is below ``threshold_m`` (None if never)."""
    idx = np.flatnonzero(dist < threshold_m)
    return int(idx[0]) if idx.size else None


def convergence_sigma1(s1_runs: dict) -> dict:
    """Apply the convergence test (defaults) to the runs; report when and how close."""
    out = {}
    for radius_m, (res, _) in s1_runs.items():
        first, est, spread = convergence_scan(res.centres)
        out[f"sigma1_D{radius_m:g}"] = {
            "first_iteration": int(first[0]),
            "estimate_error_m": float(np.linalg.norm(est[0])) if first[0] >= 0 else None,
            "final_distance_m": float(res.distance_to_source_m()[-1, 0])}
    return out


def convergence_sigma2(cfg: PaperConfig) -> dict:
    """The convergence test (defaults) on sigma_2 runs: noise-free and noise 0.1, D = 1 and 4."""
    out = {}
    for kind in ("symmetric", "cvt"):
        for label, std, radius_m in (("noise-free", 0.0, cfg.fig4_radius_m),
                                     ("noise 0.1", 0.1, cfg.fig4_radius_m),
                                     ("noise 0.1", 0.1, 4.0)):
            res = simulate(paper_formation(kind, 8, radius_m), sigma2(), SIGMA2_START_ENU, eps=EPS,
                           gamma=GAMMA, iterations=cfg.iterations_checks,
                           trials=cfg.trials, noise_std=std, method=kind, seed=NOISE_SEED,
                           sigma_c="remark")
            first, est, _ = convergence_scan(res.centres)
            ok = first >= 0
            err = np.linalg.norm(est[ok], axis=-1)
            out[f"sigma2_{kind}_{label}_D{radius_m:g}"] = {
                "converged_fraction": float(ok.mean()),
                "median_first_iteration": float(np.median(first[ok])) if ok.any() else None,
                "estimate_error_m_median": float(np.median(err)) if ok.any() else None,
                "estimate_error_m_max": float(err.max()) if ok.any() else None,
            }
    return out
